"""ROS parameters that choose a model set, shared by every node that needs one.

The belief node, the planner, the aspect matcher and the sim bridge must agree
on the model set; declaring the same parameters in one place keeps their
names, ranges and meaning identical. This is ROS wiring (it touches the node's
parameters); the model sets themselves come from the plain `population` and
`io` modules.
"""

from dataclasses import fields

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from . import population
from .modelset import TransitionParams
from .observation import ObservationParams

# Parameters that define the model set: changing them needs a restart.
MODEL_SET_PARAMETERS = ('model_file', 'model_set', 'model_set_size', 'n_tags', 'seed') + tuple(
    f.name for f in fields(ObservationParams) + fields(TransitionParams))


def probability_range(upper=0.5):
    return [FloatingPointRange(from_value=0.0, to_value=upper, step=0.0)]


def integer_range(low, high):
    return [IntegerRange(from_value=low, to_value=high, step=1)]


def declare_model_set_parameters(node):
    """Declare the model-set parameters on `node` (all read-only after start)."""
    def declare(name, default, description, **ranges):
        node.declare_parameter(name, default, ParameterDescriptor(
            description=description, read_only=True, **ranges))

    declare('model_file', '', 'Model-set file written by `models --out`; empty = generate '
            'from model_set/model_set_size/n_tags/seed.')
    declare('model_set', 'robot', 'Generated model set: robot (18 visual cubes + 2x6 '
            'eccentric twins), random (model_set_size visual cubes, uniform mass), full '
            '(every visual cube x 7 mass variants), visual (every visual cube, uniform mass).')
    declare('model_set_size', 30, 'Number of visual cubes for model_set=random.',
            integer_range=integer_range(1, 100000))
    declare('n_tags', 7, 'Number of distinct tags (ArUco ids 0..n_tags-1).',
            integer_range=integer_range(6, 50))
    declare('seed', 0, 'Seed for the random and robot model sets.',
            integer_range=integer_range(0, 2**31 - 1))
    for field in fields(ObservationParams) + fields(TransitionParams):
        declare(field.name, float(field.default),
                f"Model noise: {field.name.replace('_', ' ')} (see docs/MODEL.md).",
                floating_point_range=probability_range())


def load_model_set(node):
    """The model set the declared parameters describe.

    Raises ValueError or model_io.ModelFileError with a message naming the bad value.
    """
    def param(name):
        return node.get_parameter(name).value

    return population.model_set_from_config(
        model_set=param('model_set'), model_set_size=param('model_set_size'),
        n_tags=param('n_tags'), seed=param('seed'), model_file=param('model_file'),
        observation_params=ObservationParams(
            **{f.name: param(f.name) for f in fields(ObservationParams)}),
        transition_params=TransitionParams(
            **{f.name: param(f.name) for f in fields(TransitionParams)}))
