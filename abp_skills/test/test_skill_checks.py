"""The running skill's rules (skill_checks) and its state ages (robot_state), with fake
clocks and no ROS graph."""

from types import SimpleNamespace

import numpy as np
import pytest

from abp_skills.robot_state import RobotState, point_base_to_odom, point_odom_to_base
from abp_skills.skill_checks import (
    ArrivalCheck,
    FeedbackThrottle,
    OdometryGap,
    Refused,
    manual_goal_overrides,
    sleep_on_clock,
    timeout_reason,
)


class Clock:
    def __init__(self, t=0.0):
        self.t = t

    def __call__(self):
        return self.t

    def sleep(self, seconds):
        self.t += max(seconds, 1e-3)


def test_manual_goals_become_config_overrides_or_refusals():
    push = SimpleNamespace(face='', stroke_length=0.04)
    assert manual_goal_overrides('push', push) == {'push_stroke': 0.04}
    assert manual_goal_overrides('lift', SimpleNamespace(lift_height=0.0)) == {
        'lift_height': 0.0}
    assert manual_goal_overrides('flip', SimpleNamespace(roll_deg=90.0)) == {
        'flip_roll_deg': 90.0}
    with pytest.raises(Refused, match='only the front face'):
        manual_goal_overrides('push', SimpleNamespace(face='top', stroke_length=0.0))
    with pytest.raises(Refused, match='lift_height must be >= 0'):
        manual_goal_overrides('lift', SimpleNamespace(lift_height=-0.1))
    with pytest.raises(Refused, match='flip_roll_deg'):
        manual_goal_overrides('flip', SimpleNamespace(roll_deg=float('nan')))
    with pytest.raises(ValueError):
        manual_goal_overrides('orbit', SimpleNamespace())


def test_timeout_and_feedback_pacing():
    assert timeout_reason(119.9, 120.0) is None
    assert timeout_reason(120.1, 120.0) == 'timeout: the skill took more than 120 s'
    assert timeout_reason(-3.0, 120.0).startswith('the clock went back 3.0 s')
    throttle = FeedbackThrottle(0.25)
    assert [throttle.due(t) for t in (-0.1, 0.0, 0.1, 0.15, 0.2, 0.4)] == [
        True, False, False, True, False, True]


def test_arrival_waits_for_the_joints_in_node_and_wall_time():
    wall = Clock(1000.0)
    check = ArrivalCheck('stroke', ('a', 'b'), [1.0, 2.0], duration_s=3.0, tolerance=0.05,
                         settle_s=2.0, monotonic=wall)
    assert not check.ended(2.9) and check.check(2.9, [0.0, 0.0]) == (False, '')
    assert check.check(3.0, [0.98, 2.03]) == (True, '')        # arrived
    assert check.check(3.5, [0.5, 2.0]) == (False, '')          # settling
    assert check.check(5.5, [0.5, 2.0]) == (False, '')          # node time up, wall not
    wall.t += 2.0
    done, reason = check.check(5.5, [0.5, 2.0])
    assert done and reason == ('the joints did not reach the end of the stroke phase '
                               '(a 0.500 rad off)')


def test_late_odometry_stops_and_waits_in_wall_time_before_aborting():
    wall = Clock(50.0)
    gap = OdometryGap(2.0, monotonic=wall)
    assert gap.update(True) == 'drive' and not gap.holding
    # A short gap (a starved process at a high sim speed-up): stop, hold, then resume.
    assert gap.update(False) == 'stop' and gap.holding
    wall.t += 1.9
    assert gap.update(False) == 'hold'
    assert gap.update(True) == 'resume' and not gap.holding
    assert gap.update(True) == 'drive'
    # The wait starts again at every gap: a new one gets the whole 2 s.
    wall.t += 10.0
    assert gap.update(False) == 'stop'
    wall.t += 1.0
    assert gap.update(False) == 'hold'
    wall.t += 1.0
    assert gap.update(False) == 'abort'
    assert gap.reason() == ('odometry lost: no recent /odom for 2.0 s of wall time '
                            '(state_wait_timeout 2.0 s)')
    # No wait at all: abort at the first stale pose.
    assert OdometryGap(0.0, monotonic=wall).update(False) == 'abort'


def test_sleep_on_clock_follows_the_clock_but_not_a_stopped_one():
    clock = Clock()
    sleep_on_clock(0.05, clock, sleep=clock.sleep, monotonic=clock)
    assert clock.t == pytest.approx(0.05, abs=2e-3)
    stopped, wall = Clock(), Clock()
    sleep_on_clock(0.05, stopped, sleep=wall.sleep, monotonic=wall)
    assert stopped.t == 0.0 and wall.t == pytest.approx(0.5, abs=2e-3)


def _state(clock):
    return RobotState(clock, lambda positions, default=None: np.array(
        [positions.get('a', default[0] if default is not None else 0.0),
         positions.get('b', default[1] if default is not None else 0.0)]),
        monotonic=clock, sleep=clock.sleep)


def test_state_ages_refuse_what_is_missing_or_old():
    clock = Clock(10.0)
    state = _state(clock)
    with pytest.raises(Refused, match='no /joint_states received'):
        state.joints(1.0)
    assert clock.t == pytest.approx(11.0, abs=0.03)   # waited max_state_age for a first one
    with pytest.raises(Refused, match='no recent /odom'):
        state.base_pose(1.0)
    assert state.base_pose(1.0, required=False) is None
    with pytest.raises(Refused, match='no cube pose estimate'):
        state.cube(5.0)
    state.set_joint_positions({'a': 1.0, 'b': 2.0})
    state.set_joint_positions({'b': 3.0})               # a keeps its last value
    np.testing.assert_allclose(state.joints(1.0), [1.0, 3.0])
    state.set_odom((1.0, 0.0, np.pi / 2))
    clock.t += 1.5
    # Too old: each waits max_state_age (1 s here) for a fresh one, then refuses.
    with pytest.raises(Refused, match='/joint_states is 2.5 s old'):
        state.joints(1.0)
    with pytest.raises(Refused, match='/odom is 3.5 s old'):
        state.base_pose(1.0)
    np.testing.assert_allclose(state.latest_joints(), [1.0, 3.0])


def test_a_stale_state_is_taken_when_a_fresh_one_comes_within_the_wait():
    # A starved process reads its callbacks late: the value is old when the skill starts,
    # and a fresh one arrives while it waits.
    clock = Clock(10.0)
    state = _state(clock)
    state.set_joint_positions({'a': 1.0, 'b': 2.0})
    clock.t += 1.5

    def sleep_then_deliver(seconds):
        clock.sleep(seconds)
        if clock.t > 11.8:
            state.set_joint_positions({'a': 4.0})
    state._sleep = sleep_then_deliver
    np.testing.assert_allclose(state.joints(1.0, first_wait_s=2.0), [4.0, 2.0])
    assert clock.t == pytest.approx(11.8, abs=0.05)


def test_the_cube_estimate_follows_the_base_and_ages():
    clock = Clock(0.0)
    state = _state(clock)
    state.set_odom((0.0, 0.0, 0.0))
    state.set_cube_estimate(np.array([0.4, 0.0, 0.05]))
    base, odom = state.cube(5.0)
    np.testing.assert_allclose(base, [0.4, 0.0, 0.05])
    state.set_odom((0.1, 0.0, np.pi / 2))              # drove 0.1 m, turned left
    base, odom = state.cube(5.0)
    np.testing.assert_allclose(odom, [0.4, 0.0, 0.05])
    np.testing.assert_allclose(base, [0.0, -0.3, 0.05], atol=1e-12)
    clock.t = 6.0
    with pytest.raises(Refused, match=r'6\.0 s old \(max_estimate_age 5\.0 s\)'):
        state.cube(5.0)


def test_point_frames_are_inverse():
    pose = (0.3, -0.2, 0.7)
    p = np.array([0.5, 0.1, 0.05])
    np.testing.assert_allclose(point_odom_to_base(pose, point_base_to_odom(pose, p)), p)

