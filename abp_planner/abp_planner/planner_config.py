"""The planner node's own parameters as a ROS-free table (the model-set parameters are
`abp_belief.model_set_config.MODEL_SET_SPECS`). The node declares both with
`abp_common.parameters.declare_all` and reads them again at each Recognize goal, so a
`ros2 param set` applies to the next episode. Add a parameter by adding a row here."""

from abp_common.param_spec import BOOL, DOUBLE, INT, STRING, ParamSpec
from abp_description.robot_profile import PROFILE_SPEC

from .planner import PLANNER_NAMES
from .stopping import DEFAULT_TARGET_ERROR, STOP_RULES

PLANNER_SPECS = (
    ParamSpec('planner_mode', STRING, 'cost', 'Default planner of a Recognize goal (cost: '
              'information gain per second of action time, the one that met every accuracy '
              'and latency goal in docs/BENCHMARKS.md).', choices=PLANNER_NAMES),
    ParamSpec('planning_budget_s', DOUBLE, 0.1, 'Wall time a multi-ply planner (abp2, abp3, '
              'cost) may search per decision; it deepens until the budget is spent and '
              'returns the deepest finished search. 0 = unbounded.', (0.0, 60.0)),
    ParamSpec('stopping_rule', STRING, 'error', 'Default stopping rule of a Recognize goal: '
              'error (P(wrong object | evidence) <= target_error), posterior (top posterior > '
              'posterior_threshold) or fixed (run max_actions).', choices=STOP_RULES),
    ParamSpec('target_error', DOUBLE, DEFAULT_TARGET_ERROR, 'Default target probability of '
              'naming the wrong object (stopping_rule error).', (1e-9, 0.5)),
    ParamSpec('fault_margin', BOOL, False, 'stopping_rule error: the decision must also '
              'survive removing one false tag from the evidence (about 1.5 more actions).'),
    ParamSpec('alpha', DOUBLE, 0.1, 'Alg. 3 threshold on predicted aspect nodes, relative to '
              'the max.', (0.0, 1.0)),
    ParamSpec('max_actions', INT, 30, 'Default action budget of a Recognize goal.', (1, 1000)),
    ParamSpec('posterior_threshold', DOUBLE, 0.95, 'Default stopping posterior of a Recognize '
              'goal (stopping_rule posterior).', (0.5, 0.999999)),
    ParamSpec('skill_timeout', DOUBLE, 180.0, 'Seconds a skill may take before it is '
              'cancelled.', (1.0, 3600.0)),
    ParamSpec('observation_timeout', DOUBLE, 20.0, 'Seconds to wait for a fresh observation '
              'after an action before planning on the predicted belief.', (0.1, 600.0)),
    ParamSpec('node_return_timeout', DOUBLE, 60.0, 'Seconds an episode stays paused for a '
              'node it needs (belief, perception, skill servers) to come back before the '
              'Recognize goal is aborted naming it.', (0.0, 3600.0)),
    ParamSpec('skill_failure_limit', INT, 2, 'Failures of one skill in an episode after '
              'which the planner stops choosing it for the rest of the episode (it comes back '
              'only when nothing else is feasible). A failed skill is always left out of the '
              'next decision.', (1, 1000)),
    ParamSpec('scene_gather_s', DOUBLE, 1.0, 'Goals with a task (several cubes): after the '
              'first observation of an episode, seconds to wait for each further cube in '
              'view to be observed before the first decision (cubes seen later join at the '
              'next decision).', (0.0, 60.0)),
    ParamSpec('use_feasibility', BOOL, True, 'Ask abp/skills/check_feasibility before each '
              'decision; infeasible actions fall through to the next best.'),
    ParamSpec('planner_seed', INT, 0, 'Seed of the random planner.', (0, 2**31 - 1)),
    PROFILE_SPEC,   # the base frame of the RViz markers
)

__all__ = ['PLANNER_SPECS']
