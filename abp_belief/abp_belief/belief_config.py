"""The belief node's own parameters as a ROS-free table (the model-set parameters are
`model_set_config.MODEL_SET_SPECS`). The node declares both with
`abp_common.parameters.declare_all`."""

from abp_common.param_spec import BOOL, DOUBLE, INT, STRING, ParamSpec
from abp_description.robot_profile import PROFILE_SPEC

BELIEF_SPECS = (
    ParamSpec('top_k', INT, 10, 'Number of objects and aspect nodes listed in /abp/belief.',
              (1, 1000)),
    ParamSpec('node_floor', DOUBLE, 1e-12, 'Nodes below this fraction of the most probable '
              'node are left out of the sparse belief in /abp/belief (the planner plans on the '
              'rest).', (0.0, 1e-3)),
    ParamSpec('correct_once_per_action', BOOL, True, 'Use only the first observation after '
              'each executed action (true), or every observation message (false).'),
    ParamSpec('max_tracks', INT, 16, 'Most object tracks (cubes) with a belief of their '
              'own at once. An observation or action of a further track is refused (logged, '
              'counted in /diagnostics) until a reset (of all, or of a track) makes room.',
              (1, 100)),
    ParamSpec('base_frame', STRING, '', 'Frame of the aspect observations (the '
              "aspect matcher's base_frame); observations in another frame are rejected. "
              "Empty: the robot profile's base frame."),
    PROFILE_SPEC,
)

# Keys of the belief node's own state in its /diagnostics status (the planner quotes them).
BELIEF_STEP_KEY = 'belief step'
EVIDENCE_GATE_KEY = 'evidence gate'

__all__ = ['BELIEF_SPECS', 'BELIEF_STEP_KEY', 'EVIDENCE_GATE_KEY']
