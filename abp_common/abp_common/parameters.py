"""Declare a `param_spec` table on a node, and read it back (ROS wiring, no science).

Descriptors carry the description and the range, so `ros2 param describe` shows them
and rclpy itself refuses an out-of-range value at start or at `ros2 param set`.
"""

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from .param_spec import (
    BOOL,
    BOOL_ARRAY,
    DOUBLE,
    DOUBLE_ARRAY,
    INT,
    INT_ARRAY,
    STRING,
    STRING_ARRAY,
)

# An array spec without a default is declared by type only: it reads as unset (None).
_TYPE = {BOOL: Parameter.Type.BOOL, INT: Parameter.Type.INTEGER, DOUBLE: Parameter.Type.DOUBLE,
         STRING: Parameter.Type.STRING, BOOL_ARRAY: Parameter.Type.BOOL_ARRAY,
         INT_ARRAY: Parameter.Type.INTEGER_ARRAY, DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
         STRING_ARRAY: Parameter.Type.STRING_ARRAY}


def descriptor(spec, note=''):
    """The ParameterDescriptor of one spec."""
    kw = {}
    if spec.range is not None and spec.kind == INT:
        kw['integer_range'] = [IntegerRange(from_value=int(spec.range[0]),
                                            to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None and spec.kind == DOUBLE:
        kw['floating_point_range'] = [FloatingPointRange(
            from_value=float(spec.range[0]), to_value=float(spec.range[1]), step=0.0)]
    text = spec.description + note
    if spec.choices and spec.kind == STRING:
        text += f' One of: {", ".join(spec.choices)}.'
    return ParameterDescriptor(description=text, read_only=spec.read_only, **kw)


def _declare(node, spec, value, described):
    """declare_parameter, taking an integer given for a double (`-p speedup:=10`, YAML
    `alpha: 1`: users write numbers) as that double, and for a string (`-p source:=0`) as
    its digits, rather than refusing its type."""
    try:
        return node.declare_parameter(spec.name, value, described)
    except rclpy.exceptions.InvalidParameterTypeException:
        if spec.kind not in (DOUBLE, DOUBLE_ARRAY, STRING):
            raise
        given = _given_value(node, spec.name)
        integer = isinstance(given, int) and not isinstance(given, bool)
        if spec.kind == STRING and integer:
            # `-p source:=0` (a device index) arrives as an integer: the string it means.
            as_double = str(given)
        elif spec.kind == DOUBLE and integer:
            as_double = float(given)
        elif (spec.kind == DOUBLE_ARRAY and given is not None and len(given)
              and all(isinstance(v, int) and not isinstance(v, bool) for v in given)):
            as_double = [float(v) for v in given]
        else:
            raise
        return node.declare_parameter(spec.name, as_double, described, ignore_override=True)


def _given_value(node, name):
    """The value given for `name` at start. rclpy has no public getter for the values
    given at start: declaring the parameter untyped for a moment reads it."""
    node.declare_parameter(name, None, ParameterDescriptor(dynamic_typing=True))
    try:
        return node.get_parameter(name).value
    finally:
        node.undeclare_parameter(name)


def declare_all(node, specs, note=None):
    """Declare every spec on `node`; `note(spec)` may append to a description.

    Raises ValueError naming the parameter when a given value breaks its choices (the
    ranges rclpy checks itself, raising InvalidParameterValueException)."""
    for spec in specs:
        value = _TYPE[spec.kind] if spec.default is None else spec.default
        _declare(node, spec, value, descriptor(spec, note(spec) if note else ''))
    values = read_all(node, specs)
    for spec in specs:
        spec.check(values[spec.name])
    return values


def read_all(node, specs):
    """{name: value} of the declared specs; an unset array parameter reads as None."""
    out = {}
    for spec in specs:
        try:
            out[spec.name] = node.get_parameter(spec.name).value
        except rclpy.exceptions.ParameterUninitializedException:
            out[spec.name] = None
    return out


__all__ = ['declare_all', 'descriptor', 'read_all']
