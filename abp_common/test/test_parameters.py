"""declare_all on a real rclpy node: descriptors, int-for-double, refusals, unset arrays."""

import pytest
import rclpy
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from abp_common.param_spec import DOUBLE, DOUBLE_ARRAY, INT_ARRAY, STRING, ParamSpec
from abp_common.parameters import declare_all, read_all

SPECS = (
    ParamSpec('speedup', DOUBLE, 1.0, 'Sim time per wall time.', (0.0, 100.0)),
    ParamSpec('mode', STRING, 'abp', 'Planner mode.', choices=('abp', 'random'),
              read_only=True),
    ParamSpec('face_tags', INT_ARRAY, None, 'Explicit cube.'),
    ParamSpec('noise', DOUBLE_ARRAY, [0.0, 0.0], 'Noise.'),
)


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.shutdown(context=ctx)


def make(context, **overrides):
    params = [Parameter(k, value=v) for k, v in overrides.items()]
    return Node('spec_test', context=context, parameter_overrides=params,
                start_parameter_services=False)


def test_declares_with_descriptors_and_reads_back(context):
    node = make(context, speedup=10, noise=[1, 2])  # integers, as `-p speedup:=10` gives
    values = declare_all(node, SPECS)
    assert values == {'speedup': 10.0, 'mode': 'abp', 'face_tags': None, 'noise': [1.0, 2.0]}
    described = node.describe_parameter('speedup')
    assert described.floating_point_range[0].to_value == 100.0
    assert node.describe_parameter('mode').read_only
    assert 'One of: abp, random' in node.describe_parameter('mode').description
    assert read_all(node, SPECS) == values
    node.destroy_node()


def test_out_of_range_and_bad_choice_are_refused(context):
    with pytest.raises(InvalidParameterValueException):
        declare_all(make(context, speedup=1000.0), SPECS)
    with pytest.raises(ValueError, match="mode must be one of abp, random, got 'cost'"):
        declare_all(make(context, mode='cost'), SPECS)
