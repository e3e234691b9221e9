"""The action side of a simulated joint_trajectory_controller: what happens to a
control_msgs/FollowJointTrajectory goal, as Jazzy's controller decides it (plain Python,
no rclpy; the sim bridge node wires it to the action server).

Per controller at most one goal is active. A new goal preempts the active one (aborted,
INVALID_GOAL, "Current goal preempted by new incoming action."). Each simulation tick,
`GoalMonitor.update` compares the measured joints with the trajectory's desired ones:

- while the trajectory runs, a joint further than its path tolerance from the desired
  position aborts the goal (PATH_TOLERANCE_VIOLATED) and the controller holds;
- once the trajectory has ended, the goal succeeds (SUCCESSFUL) when every joint is within
  its goal tolerance (position, and velocity: the controller's stopped_velocity_tolerance
  unless the goal says otherwise); if that has not happened `goal_time_tolerance` after the
  end (0: wait for ever, as the controller does), the goal aborts
  (GOAL_TOLERANCE_VIOLATED) and the controller holds;
- a cancel ends the goal canceled and the controller holds where the joints are.

Tolerances follow control_msgs/JointTolerance: 0 keeps the default, -1 erases it.
"""

from dataclasses import dataclass, field

import numpy as np

# control_msgs/action/FollowJointTrajectory result codes.
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

# Jazzy joint_trajectory_controller defaults (constraints.*): no path or goal position
# tolerance, stopped_velocity_tolerance 0.01, goal_time 0 (wait for ever).
DEFAULT_STOPPED_VELOCITY_TOLERANCE = 0.01


def merged_tolerance(default, asked):
    """A JointTolerance field over the controller's default: 0 keeps it, < 0 erases it."""
    if asked == 0.0:
        return default
    return 0.0 if asked < 0.0 else float(asked)


def tolerances(joint_names, requested, default):
    """Per-joint tolerances (controller order) from a list of (name, value) of a goal; an
    unknown joint name is refused (ValueError)."""
    out = np.full(len(joint_names), float(default))
    for name, value in requested:
        if name not in joint_names:
            raise ValueError(f'tolerance for joint {name!r}, which this controller does not '
                             f'have ({", ".join(joint_names)})')
        if not np.isfinite(value):
            raise ValueError(f'tolerance for joint {name!r} is not finite')
        out[joint_names.index(name)] = merged_tolerance(default, float(value))
    return out


@dataclass
class GoalEnd:
    """How a goal ended: `status` is 'succeeded', 'aborted' or 'canceled'."""
    goal_id: object
    status: str
    error_code: int
    error_string: str


@dataclass
class _ActiveGoal:
    goal_id: object
    end_time: float
    path_position: np.ndarray       # 0 = not checked
    goal_position: np.ndarray       # 0 = not checked
    goal_velocity: np.ndarray       # 0 = not checked
    goal_time_tolerance: float      # 0 = wait for ever
    ended: list = field(default_factory=list)


class GoalMonitor:
    """The active FollowJointTrajectory goal of one controller and its verdict."""

    def __init__(self, joint_names, stopped_velocity_tolerance=DEFAULT_STOPPED_VELOCITY_TOLERANCE):
        self.joint_names = tuple(joint_names)
        self.stopped_velocity_tolerance = float(stopped_velocity_tolerance)
        self._goal = None

    @property
    def active_goal(self):
        return None if self._goal is None else self._goal.goal_id

    def start(self, goal_id, end_time, path_tolerance=(), goal_tolerance=(),
              velocity_tolerance=(), goal_time_tolerance=0.0):
        """Track a newly accepted goal (its trajectory already given to the follower, which
        ends at `end_time`). Tolerances: lists of (joint name, value). Returns the GoalEnd
        of the goal it preempts, or None."""
        names = list(self.joint_names)
        goal = _ActiveGoal(
            goal_id, float(end_time),
            tolerances(names, path_tolerance, 0.0),
            tolerances(names, goal_tolerance, 0.0),
            tolerances(names, velocity_tolerance, self.stopped_velocity_tolerance),
            max(0.0, float(goal_time_tolerance)))
        preempted = self._end(INVALID_GOAL, 'Current goal preempted by new incoming action.',
                              'aborted')
        self._goal = goal
        return preempted

    def cancel(self, goal_id):
        """End `goal_id` canceled if it is the active goal (the caller then holds the
        controller where it is); returns the GoalEnd or None."""
        if self._goal is None or self._goal.goal_id != goal_id:
            return None
        return self._end(SUCCESSFUL, 'Goal canceled', 'canceled')

    def update(self, t, q, qd, desired, trajectory_end):
        """Judge the active goal at time `t` from the measured `q`, `qd` and the desired
        positions (controller order). `trajectory_end`: when the follower's current
        trajectory ends (None when it holds). Returns a GoalEnd when the goal ends (the
        caller holds the controller if it aborted), else None."""
        goal = self._goal
        if goal is None:
            return None
        error = np.abs(np.asarray(desired, dtype=float) - np.asarray(q, dtype=float))
        end = goal.end_time if trajectory_end is None else trajectory_end
        if t < end:
            bad = (goal.path_position > 0) & (error > goal.path_position)
            if np.any(bad):
                return self._end(PATH_TOLERANCE_VIOLATED,
                                 'Aborted due to path tolerance violation: '
                                 + self._describe(bad, error, goal.path_position), 'aborted')
            return None
        speed = np.abs(np.asarray(qd, dtype=float))
        outside = ((goal.goal_position > 0) & (error > goal.goal_position)) \
            | ((goal.goal_velocity > 0) & (speed > goal.goal_velocity))
        if not np.any(outside):
            return self._end(SUCCESSFUL, 'Goal successfully reached!', 'succeeded')
        late = t - end
        if goal.goal_time_tolerance > 0 and late > goal.goal_time_tolerance:
            too_far = (goal.goal_position > 0) & (error > goal.goal_position)
            # Name what is out: the position where it is, else the velocity.
            where = (self._describe(too_far, error, goal.goal_position) if np.any(too_far)
                     else self._describe(outside, speed, goal.goal_velocity, 'velocity'))
            return self._end(GOAL_TOLERANCE_VIOLATED,
                             f'Aborted due to goal_time_tolerance exceeding by '
                             f'{late - goal.goal_time_tolerance:.6f} seconds: {where}',
                             'aborted')
        return None

    def _describe(self, bad, value, limit, quantity='position'):
        i = int(np.flatnonzero(bad)[0])
        if quantity == 'position':
            return (f'{self.joint_names[i]} {value[i]:.4f} from its desired position '
                    f'(tolerance {limit[i]:.4f})')
        return (f'{self.joint_names[i]} still moving at {value[i]:.4f} '
                f'(velocity tolerance {limit[i]:.4f})')

    def _end(self, code, text, status):
        goal, self._goal = self._goal, None
        if goal is None:
            return None
        return GoalEnd(goal.goal_id, status, code, text)


__all__ = ['GOAL_TOLERANCE_VIOLATED', 'GoalEnd', 'GoalMonitor', 'INVALID_GOAL',
           'PATH_TOLERANCE_VIOLATED', 'SUCCESSFUL', 'tolerances']
