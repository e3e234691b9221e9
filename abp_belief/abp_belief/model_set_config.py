"""The model-set parameters, as one ROS-free table every node that needs a model set
declares (belief, planner, aspect matcher, sim bridge): they must agree, so the names,
ranges and meanings exist once. `abp_bringup/config/abp.yaml` sets them once for the
whole graph under `/**:`.

`POPULATION_SPECS` choose the models, `TRANSITION_RULES_SPEC` the hand-written table of a
generated set; `NOISE_SPECS` are the observation and transition
noise of the ATGs (docs/MODEL.md). Nodes declare them with
`abp_common.parameters.declare_all` and build the set with `model_set_from_values`.
"""

from dataclasses import fields

from abp_common.param_spec import INT, STRING, ParamSpec, probability

from . import population
from .cube import TRANSITION_RULES
from .modelset import TransitionParams
from .observation import ObservationParams

POPULATION_SPECS = (
    ParamSpec('model_file', STRING, '', 'Model-set file written by `models --out` (or '
              '`learn_atg`); empty = generate from model_set/model_set_size/n_tags/seed.',
              read_only=True),
    ParamSpec('model_set', STRING, 'robot', 'Generated model set: robot (18 visual cubes + '
              '2x6 eccentric twins), random (model_set_size visual cubes, uniform mass), full '
              '(every visual cube x 7 mass variants), visual (every visual cube, uniform '
              'mass).', read_only=True, choices=population.MODEL_SETS),
    ParamSpec('model_set_size', INT, 30, 'Number of visual cubes for model_set=random.',
              (1, 100000), read_only=True),
    ParamSpec('n_tags', INT, 7, 'Number of distinct tags (ArUco ids 0..n_tags-1).', (6, 50),
              read_only=True),
    ParamSpec('seed', INT, 0, 'Seed for the random and robot model sets.', (0, 2**31 - 1),
              read_only=True),
)
# The ATG tables of a generated set; the sim bridge's worlds never read them.
TRANSITION_RULES_SPEC = ParamSpec(
    'transition_rules', STRING, 'corrected', 'Hand-written ATG table of a generated set '
    "(docs/MODEL.md): corrected (the paper's table with the cells the MuJoCo outcome survey "
    'showed wrong rewritten from the physics) or paper (as the paper wrote it; the rules '
    "world's physics). A model_file carries its own tables.", read_only=True,
    choices=TRANSITION_RULES)
NOISE_SPECS = tuple(
    probability(f.name, f.default, f'Model noise: {f.name.replace("_", " ")} (see '
                'docs/MODEL.md).', upper=0.5, read_only=True)
    for f in fields(ObservationParams) + tuple(
        f for f in fields(TransitionParams) if f.name in TransitionParams.noise_names()))
MODEL_SET_SPECS = POPULATION_SPECS + (TRANSITION_RULES_SPEC,) + NOISE_SPECS
# Parameters that define the model set: changing them needs a restart.
MODEL_SET_PARAMETERS = tuple(p.name for p in MODEL_SET_SPECS)


def model_set_from_values(values):
    """The model set a {name: value} mapping of MODEL_SET_SPECS describes.

    Raises ValueError or model_file.ModelFileError with a message naming the bad value.
    """
    return population.model_set_from_config(
        model_set=values['model_set'], model_set_size=values['model_set_size'],
        n_tags=values['n_tags'], seed=values['seed'], model_file=values['model_file'],
        observation_params=ObservationParams(
            **{f.name: values[f.name] for f in fields(ObservationParams)}),
        transition_params=TransitionParams(
            rules=values['transition_rules'],
            **{name: values[name] for name in TransitionParams.noise_names()}))


__all__ = ['MODEL_SET_PARAMETERS', 'MODEL_SET_SPECS', 'NOISE_SPECS', 'POPULATION_SPECS',
           'TRANSITION_RULES_SPEC', 'model_set_from_values']
