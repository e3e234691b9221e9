"""The ROS-free parameter table: checks, defaults and spec validation."""

import pytest

from abp_common.names import absolute, skill_action, trajectory_topic
from abp_common.param_spec import (
    DOUBLE,
    INT,
    INT_ARRAY,
    STRING,
    ParamSpec,
    check_all,
    defaults,
    probability,
)

SPECS = (
    ParamSpec('rate', DOUBLE, 50.0, 'Tick rate.', (1.0, 1000.0)),
    ParamSpec('count', INT, 3, 'Count.', (0, 10)),
    ParamSpec('mode', STRING, 'abp', 'Mode.', choices=('abp', 'random')),
    ParamSpec('tags', INT_ARRAY, None, 'Tags.'),
    probability('p_miss', 0.1, 'Miss probability.', upper=0.5),
)


def test_defaults_and_unset_arrays():
    assert defaults(SPECS) == {'rate': 50.0, 'count': 3, 'mode': 'abp', 'tags': [],
                               'p_miss': 0.1}


@pytest.mark.parametrize('name, value, message', [
    ('rate', 0.5, r'rate must be in \[1.0, 1000.0\], got 0.5'),
    ('count', 11, r'count must be in \[0, 10\]'),
    ('mode', 'cost', r"mode must be one of abp, random, got 'cost'"),
    ('p_miss', 0.6, r'p_miss must be in \[0.0, 0.5\]'),
    ('rate', float('nan'), r'rate must be a finite number'),
])
def test_bad_values_name_the_parameter(name, value, message):
    with pytest.raises(ValueError, match=message):
        check_all(SPECS, {name: value})


def test_good_values_and_unknown_names_pass():
    check_all(SPECS, {'rate': 1.0, 'count': 10, 'mode': 'random', 'tags': None, 'other': 1})


def test_a_range_needs_a_number():
    with pytest.raises(ValueError, match='needs an int or double'):
        ParamSpec('name', STRING, 'x', 'Text.', (0, 1))


def test_names_are_relative_and_resolve_under_a_namespace():
    assert absolute('abp/belief') == '/abp/belief'
    assert absolute('abp/belief', 'robot1') == '/robot1/abp/belief'
    assert absolute('abp/belief', '/robot1/') == '/robot1/abp/belief'
    assert absolute('/clock', 'robot1') == '/clock'
    assert trajectory_topic('head_controller') == 'head_controller/joint_trajectory'
    assert skill_action('push') == 'abp/skills/push'
    with pytest.raises(ValueError, match='unknown skill'):
        skill_action('jump')
