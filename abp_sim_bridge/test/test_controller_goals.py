"""FollowJointTrajectory goals judged as Jazzy's joint_trajectory_controller judges them
(abp_sim_bridge.controller_goals), without ROS."""

import numpy as np
import pytest

from abp_sim_bridge.controller_goals import (
    GOAL_TOLERANCE_VIOLATED,
    INVALID_GOAL,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    GoalMonitor,
)

JOINTS = ('a', 'b')


def test_a_goal_succeeds_once_its_trajectory_ended_within_tolerance():
    m = GoalMonitor(JOINTS)
    m.start('g1', end_time=2.0, goal_tolerance=[('a', 0.05), ('b', 0.05)])
    desired = np.array([1.0, -1.0])
    # Still running: no verdict even when far off (no path tolerance asked for).
    assert m.update(1.0, [0.0, 0.0], [0.5, 0.5], desired, trajectory_end=2.0) is None
    # Ended but still outside: goal_time_tolerance 0 waits for ever, as the controller does.
    assert m.update(50.0, [0.9, -1.0], [0.0, 0.0], desired, trajectory_end=2.0) is None
    # Inside the position tolerance but still moving faster than stopped_velocity_tolerance.
    assert m.update(50.1, [0.99, -1.0], [0.02, 0.0], desired, trajectory_end=2.0) is None
    end = m.update(50.2, [0.99, -1.0], [0.0, 0.0], desired, trajectory_end=2.0)
    assert (end.goal_id, end.status, end.error_code) == ('g1', 'succeeded', SUCCESSFUL)
    assert m.active_goal is None


def test_goal_time_tolerance_and_path_tolerance_abort():
    m = GoalMonitor(JOINTS)
    m.start('late', end_time=2.0, goal_tolerance=[('a', 0.01)], goal_time_tolerance=0.5)
    assert m.update(2.4, [0.5, 0.0], [0, 0], [1.0, 0.0], trajectory_end=2.0) is None
    end = m.update(2.6, [0.5, 0.0], [0, 0], [1.0, 0.0], trajectory_end=2.0)
    assert (end.status, end.error_code) == ('aborted', GOAL_TOLERANCE_VIOLATED)
    assert 'goal_time_tolerance' in end.error_string and 'a 0.5000' in end.error_string
    m.start('path', end_time=5.0, path_tolerance=[('b', 0.1)])
    assert m.update(1.0, [0.0, 0.05], [0, 0], [0.0, 0.0], trajectory_end=5.0) is None
    end = m.update(1.1, [0.0, 0.2], [0, 0], [0.0, 0.0], trajectory_end=5.0)
    assert (end.goal_id, end.error_code) == ('path', PATH_TOLERANCE_VIOLATED)


def test_preemption_cancel_and_erased_tolerances():
    m = GoalMonitor(JOINTS)
    assert m.start('old', end_time=1.0) is None
    preempted = m.start('new', end_time=3.0, velocity_tolerance=[('a', -1), ('b', -1)])
    assert (preempted.goal_id, preempted.status, preempted.error_code) == \
        ('old', 'aborted', INVALID_GOAL)
    assert m.cancel('old') is None              # not the active goal: nothing to cancel
    # -1 erases the velocity check: a joint still moving counts as arrived.
    end = m.update(3.0, [0.0, 0.0], [1.0, 1.0], [0.0, 0.0], trajectory_end=3.0)
    assert end.status == 'succeeded'
    m.start('c', end_time=9.0)
    end = m.cancel('c')
    assert (end.goal_id, end.status) == ('c', 'canceled') and m.active_goal is None


def test_tolerances_for_unknown_joints_are_refused():
    with pytest.raises(ValueError, match='does not have'):
        GoalMonitor(JOINTS).start('g', 1.0, goal_tolerance=[('z', 0.1)])


def test_a_goal_late_only_by_its_velocity_names_the_velocity():
    m = GoalMonitor(JOINTS)
    m.start('moving', end_time=2.0, goal_tolerance=[('a', 0.05)], goal_time_tolerance=0.5)
    # Within the position tolerance but still moving past the stopped-velocity tolerance.
    end = m.update(2.6, [0.99, 0.0], [0.3, 0.0], [1.0, 0.0], trajectory_end=2.0)
    assert (end.status, end.error_code) == ('aborted', GOAL_TOLERANCE_VIOLATED)
    assert 'a still moving at 0.3000' in end.error_string, end.error_string
    assert 'from its desired position' not in end.error_string
