"""One default per parameter: where a node's parameter (its ParamSpec table) becomes a
field of a config dataclass or an argument of the class the node builds, the field's
or argument's own default is the parameter's default. Otherwise code that builds the
class without the node (tests, benchmarks, tools) runs with other values than the node
does, as the sim bridge's `world` once did (dataclass `rules`, parameter `mujoco`).

A difference that is meant is listed in INTENDED with why."""

import dataclasses
import inspect

import pytest

# The value an unset array parameter (default None) becomes in the config.
UNSET = (None, (), [])
# (class, argument): why its default differs from the parameter's on purpose.
INTENDED = {
    ('ActiveBeliefPlanner', 'planning_budget_s'):
        'None = unbounded for offline benchmarks; the node bounds a decision (0.1 s)',
    ('SimBridgeConfig', 'distractors'):
        'not the parameter: the distractor cubes built from its count',
}
# Argument (or field) name -> parameter name, where they differ.
RENAMED = {'MujocoConfig': {'shadows': 'camera_shadows', 'offsamples': 'camera_offsamples'},
           'ScriptedPerson': {'rules': 'transition_rules'},
           'OperatorWorld': {'up_face': 'cube_up_face', 'yaw_deg': 'cube_yaw'}}


def defaults_of(cls):
    """{name: default} of a dataclass's fields, or of its __init__'s keyword arguments."""
    if dataclasses.is_dataclass(cls):
        out = {}
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                out[f.name] = f.default
            elif f.default_factory is not dataclasses.MISSING:
                out[f.name] = f.default_factory()
        return out
    return {p.name: p.default for p in inspect.signature(cls.__init__).parameters.values()
            if p.default is not inspect.Parameter.empty}


def same(value, default):
    if value in UNSET and default in UNSET:
        return True
    if isinstance(value, (tuple, list)) and isinstance(default, (tuple, list)):
        return list(value) == list(default)
    return value == default


def pairs():
    from abp_belief.model_set_config import MODEL_SET_SPECS
    from abp_belief.modelset import TransitionParams
    from abp_belief.observation import ObservationParams
    from abp_perception.detector import TagDetector
    from abp_perception.matcher import AspectMatcher
    from abp_perception.node_parameters import DETECTOR_SPECS, MATCHER_SPECS
    from abp_planner.planner import ActiveBeliefPlanner
    from abp_planner.planner_config import PLANNER_SPECS
    from abp_sim_bridge import config as sim_config
    from abp_sim_bridge.mujoco_world import MujocoSettings
    from abp_sim_bridge.operator_world import OperatorWorld
    from abp_sim_bridge.rules_contact import ContactParams
    from abp_sim_bridge.rules_physics import Failures
    from abp_sim_bridge.rules_world import SimSettings
    from abp_sim_bridge.scripted_operator import ScriptedPerson
    from abp_sim_bridge.scripted_operator_node import SCRIPTED_SPECS
    from abp_skills.base_motion import BaseLimits
    from abp_skills.plan_types import SkillConfig
    from abp_skills.skill_params import skills_parameter_specs

    sim = sim_config.PARAMETERS
    return [
        (sim_config.SimBridgeConfig, sim), (sim_config.MujocoConfig, sim),
        (sim_config.CameraConfig, sim), (SimSettings, sim), (Failures, sim),
        (MujocoSettings, sim), (ContactParams, sim),
        (ScriptedPerson, SCRIPTED_SPECS), (OperatorWorld, SCRIPTED_SPECS),
        (TagDetector, DETECTOR_SPECS), (ActiveBeliefPlanner, PLANNER_SPECS),
        (ObservationParams, MODEL_SET_SPECS), (TransitionParams, MODEL_SET_SPECS),
        (SkillConfig, skills_parameter_specs(True)), (BaseLimits, skills_parameter_specs(True)),
        # The matcher's None means "from cube_size", as the parameter's 0 does.
        (AspectMatcher, [s for s in MATCHER_SPECS
                         if s.name not in ('voxel_size', 'peak_radius')]),
    ]


@pytest.mark.parametrize('cls, specs', pairs(), ids=lambda x: getattr(x, '__name__', ''))
def test_a_default_is_the_parameters_default(cls, specs):
    by_name = {spec.name: spec for spec in specs}
    renamed = RENAMED.get(cls.__name__, {})
    if cls.__name__ == 'BaseLimits':   # declared as base_<field> (skill_params)
        renamed = {name: f'base_{name}' for name in defaults_of(cls)}
    checked, wrong = 0, []
    for name, default in defaults_of(cls).items():
        spec = by_name.get(renamed.get(name, name))
        if spec is None or (cls.__name__, name) in INTENDED:
            continue
        checked += 1
        if not same(default, spec.default):
            wrong.append(f'{cls.__name__}.{name} = {default!r}, parameter {spec.name} '
                         f'defaults to {spec.default!r}')
    assert checked, f'{cls.__name__}: no field is a parameter (a stale pair)'
    assert not wrong, '\n'.join(wrong)


def test_the_sim_bridge_config_built_from_defaults_has_the_dataclass_defaults():
    from abp_sim_bridge import config as sim_config

    built = sim_config.build({})
    for cls, obj in ((sim_config.SimBridgeConfig, built),
                     (sim_config.MujocoConfig, built.mujoco)):
        for name, default in defaults_of(cls).items():
            assert same(getattr(obj, name), default), f'{cls.__name__}.{name}'
