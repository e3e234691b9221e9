"""A node's parameters as a plain table (no rclpy): name, type, default, range, meaning.

The science side of a package builds its configuration from a {name: value} mapping and
checks it against these specs; the node declares the same table with
`abp_common.parameters.declare_all`. So the names, ranges and descriptions exist once,
and the checks run (and are unit-tested) without a ROS graph.
"""

import math
from dataclasses import dataclass

BOOL, INT, DOUBLE, STRING = 'bool', 'int', 'double', 'string'
BOOL_ARRAY, INT_ARRAY, DOUBLE_ARRAY, STRING_ARRAY = 'bool[]', 'int[]', 'double[]', 'string[]'
KINDS = (BOOL, INT, DOUBLE, STRING, BOOL_ARRAY, INT_ARRAY, DOUBLE_ARRAY, STRING_ARRAY)
# The value an unset array parameter reads as.
EMPTY = {BOOL_ARRAY: [], INT_ARRAY: [], DOUBLE_ARRAY: [], STRING_ARRAY: []}


@dataclass(frozen=True)
class ParamSpec:
    name: str
    kind: str
    default: object          # None: an array parameter that starts unset (= empty)
    description: str
    range: tuple | None = None  # (low, high) inclusive, for int and double
    read_only: bool = False     # set at start only (a change needs a restart)
    choices: tuple = ()         # allowed values of a string parameter

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f'{self.name}: unknown parameter kind {self.kind!r}')
        if self.range is not None and self.kind not in (INT, DOUBLE):
            raise ValueError(f'{self.name}: a range needs an int or double parameter')

    def check(self, value):
        """Raise ValueError naming the parameter when `value` is out of its range/choices."""
        if value is None:
            return
        if self.kind == DOUBLE and not math.isfinite(float(value)):
            raise ValueError(f'{self.name} must be a finite number, got {value}')
        if self.range is not None:
            low, high = self.range
            if not low <= value <= high:
                raise ValueError(f'{self.name} must be in [{low}, {high}], got {value}')
        if self.choices and value not in self.choices:
            raise ValueError(f'{self.name} must be one of {", ".join(map(str, self.choices))}, '
                             f'got {value!r}')

    @property
    def initial(self):
        """The value the parameter is declared with."""
        return EMPTY[self.kind] if self.default is None else self.default


def defaults(specs):
    """{name: default} of a spec table."""
    return {p.name: p.initial for p in specs}


def check_all(specs, values):
    """Check every value of `values` that has a spec; raise ValueError on the first bad one."""
    by_name = {p.name: p for p in specs}
    for name, value in values.items():
        if name in by_name:
            by_name[name].check(value)


def probability(name, default, description, upper=1.0, **kw):
    """A double in [0, upper]."""
    return ParamSpec(name, DOUBLE, float(default), description, (0.0, upper), **kw)


__all__ = ['BOOL', 'BOOL_ARRAY', 'DOUBLE', 'DOUBLE_ARRAY', 'INT', 'INT_ARRAY', 'KINDS',
           'STRING', 'STRING_ARRAY', 'ParamSpec', 'check_all', 'defaults', 'probability']
