"""The skill servers' parameter table builds the SkillConfig and refuses bad values."""

from dataclasses import replace

import pytest

from abp_common.param_spec import defaults
from abp_skills.base_motion import BaseLimits
from abp_skills.plans import SkillConfig
from abp_skills.skill_params import CONFIG_SPECS, config_from_values, skills_parameter_specs


def test_defaults_give_the_default_config():
    assert config_from_values(defaults(CONFIG_SPECS)) == SkillConfig()


def test_every_config_field_is_a_parameter_with_its_type():
    specs = {s.name: s for s in skills_parameter_specs(feasibility=False)}
    assert specs['feasibility_service'].default is False and specs['feasibility_service'].read_only
    assert specs['check_stride'].kind == 'int' and specs['base_approach'].kind == 'bool'
    assert set(specs['push_hand'].choices) == {'left', 'right'}   # the profile's push arms
    assert specs['robot_profile'].default == '' and specs['robot_profile'].read_only
    assert specs['support_height'].range == (-1.0, 10.0)
    assert {f'base_{n}' for n in BaseLimits.__dataclass_fields__} <= set(specs)
    assert specs['timeout'].range == (1.0, 3600.0)


def test_overrides_and_refusals():
    values = defaults(CONFIG_SPECS)
    config = config_from_values({**values, 'lift_height': 0.1, 'base_linear_velocity': 0.2})
    assert config == replace(SkillConfig(), lift_height=0.1,
                             base=replace(BaseLimits(), linear_velocity=0.2))
    with pytest.raises(ValueError, match='push_hand'):
        config_from_values({**values, 'push_hand': 'middle'})
    with pytest.raises(ValueError, match='orbit_min_radius'):
        config_from_values({**values, 'orbit_min_radius': 2.0})
    with pytest.raises(ValueError, match='base_angular_jerk'):
        config_from_values({**values, 'base_angular_jerk': 0.0})
