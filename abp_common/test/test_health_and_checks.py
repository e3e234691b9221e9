"""The ROS-free parts of /diagnostics and of the input checks."""

import json
from types import SimpleNamespace as NS

import pytest

from abp_common import input_checks
from abp_common.health_stats import ERROR, OK, WARN, HealthStats
from abp_common.input_checks import Rejected, StampCheck


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def stamp(seconds):
    return NS(sec=int(seconds), nanosec=int(round((seconds - int(seconds)) * 1e9)))


def test_a_rejection_kind_is_logged_once_per_period_and_always_counted():
    clock = FakeClock()
    stats = HealthStats(log_period_s=5.0, monotonic=clock)
    logged = [stats.reject('odom', 'non_finite') for _ in range(100)]
    assert logged == [True] + [False] * 99
    # Another kind, or another topic, has its own throttle.
    assert stats.reject('odom', 'empty') and stats.reject('cmd_vel', 'non_finite')
    clock.t += 4.9
    assert not stats.reject('odom', 'non_finite')
    clock.t += 0.2
    assert stats.reject('odom', 'non_finite')
    assert stats.rejected[('odom', 'non_finite')] == 102


def test_levels_and_values():
    clock = FakeClock()
    stats = HealthStats(window_s=10.0, monotonic=clock)
    stats.expect('camera/image_raw', 2.0)
    for _ in range(20):
        stats.count_input('camera/image_raw')
        clock.t += 0.1
    stats.latency(0.002)
    snap = stats.snapshot()
    assert snap['level'] == OK, snap
    values = dict(snap['values'])
    assert float(values['camera/image_raw rate (Hz)']) == pytest.approx(10.0)
    assert values['camera/image_raw inputs'] == '20'
    assert values['latency max (ms)'] == '2.00'
    # Some inputs rejected: WARN, counted by topic and kind.
    stats.count_input('camera/image_raw')
    stats.reject('camera/image_raw', 'size')
    snap = stats.snapshot()
    assert snap['level'] == WARN and '1 inputs rejected' in snap['message']
    assert dict(snap['values'])['rejected camera/image_raw size'] == '1'
    # Every input of a topic rejected over the window: ERROR naming the topic.
    clock.t += 11.0
    stats.count_input('odom')
    stats.reject('odom', 'non_finite')
    snap = stats.snapshot()
    assert snap['level'] == ERROR and 'odom' in snap['message']
    # A silent expected topic warns.
    clock.t += 11.0
    snap = stats.snapshot()
    assert snap['level'] == WARN and 'no camera/image_raw for' in snap['message']
    stats.fault('simulation thread failed')
    assert stats.snapshot()['level'] == ERROR


def test_stamp_check_future_past_and_replays():
    check = StampCheck(max_future_s=1.0, max_lag_s=10.0)
    now = 100 * 10**9
    with pytest.raises(Rejected) as error:
        check.check(stamp(101.5), now)
    assert error.value.kind == 'stamp_future'
    check.check(stamp(100.5), now)
    check.taken(stamp(100.0))
    with pytest.raises(Rejected) as error:
        check.check(stamp(80.0), now)
    assert error.value.kind == 'stamp_past'
    check.check(stamp(95.0), now)                 # within the lag
    # A node on wall time replaying recorded (small) stamps in order: accepted.
    replay = StampCheck(1.0, 10.0)
    wall = 1_700_000_000 * 10**9
    for t in (1.0, 2.0, 3.5):
        replay.check(stamp(t), wall)
        replay.taken(stamp(t))
    # A sender whose clock restarted (a new simulation): accepted, its clock restarted too.
    check.check(stamp(2.0), 3 * 10**9)
    # A clock that has not started checks no future; zero means now where asked.
    check.check(stamp(1e6), 0)
    StampCheck(1.0, 10.0, zero_is_now=True).check(stamp(0), now)


def test_newest_stamp_is_clamped_to_a_clock_that_went_back():
    check = StampCheck(1.0, 10.0)
    assert check.newest_not_after(5 * 10**9) is None
    check.taken(stamp(50.0))
    assert check.newest_not_after(60 * 10**9) == 50 * 10**9
    # The simulation restarted: its clock is at 4 s, the newest stamp taken at 50 s.
    assert check.newest_not_after(4 * 10**9) == 4 * 10**9
    assert check.newest_not_after(0) == 50 * 10**9   # no clock yet: nothing to clamp to


def pose(x=0.0, w=1.0):
    return NS(position=NS(x=x, y=0.0, z=0.0), orientation=NS(x=0.0, y=0.0, z=0.0, w=w))


def observation(frame='base_link', **hypothesis):
    h = dict(aspect_type=2, support=1.0, score=1.0,
             object_pose=NS(pose=pose(), covariance=[0.0] * 36), feature_indices=[0])
    h.update(hypothesis)
    feature = NS(position=NS(x=0.0, y=0.0, z=0.0), normal=NS(x=0.0, y=0.0, z=1.0),
                 position_covariance=[0.0] * 9)
    return NS(header=NS(frame_id=frame), features=[feature], hypotheses=[NS(**h)])


@pytest.mark.parametrize('msg, kind', [
    (observation(frame='map'), 'frame'),
    (observation(aspect_type=7), 'out_of_range'),
    (observation(feature_indices=[3]), 'out_of_range'),
    (observation(object_pose=NS(pose=pose(x=float('nan')), covariance=[0.0] * 36)),
     'non_finite'),
    (observation(object_pose=NS(pose=pose(w=0.0), covariance=[0.0] * 36)), 'empty'),
    (observation(support=float('inf')), 'non_finite'),
])
def test_malformed_observations_are_named(msg, kind):
    input_checks.aspect_observation(observation(), ('base_link',))
    with pytest.raises(Rejected) as error:
        input_checks.aspect_observation(msg, ('base_link',))
    assert error.value.kind == kind


def test_joint_states_odometry_and_skills_state():
    input_checks.joint_state(NS(name=['a', 'b'], position=[0.0, 1.0]))
    for msg, kind in ((NS(name=['a'], position=[0.0, 1.0]), 'size_mismatch'),
                      (NS(name=[], position=[]), 'empty'),
                      (NS(name=['a'], position=[float('nan')]), 'non_finite'),
                      (NS(name=['a'] * 500, position=[0.0] * 500), 'oversized')):
        with pytest.raises(Rejected) as error:
            input_checks.joint_state(msg)
        assert error.value.kind == kind
    twist = NS(linear=NS(x=0.0), angular=NS(z=float('inf')))
    with pytest.raises(Rejected, match='non_finite'):
        input_checks.odometry(NS(pose=NS(pose=pose()), twist=NS(twist=twist)))
    assert input_checks.skills_state(json.dumps({'node': '/a', 'skill': ''}))['node'] == '/a'
    for text, kind in (('{', 'malformed'), ('[1]', 'malformed'), ('{"node": 3}', 'malformed'),
                       ('x' * 10000, 'oversized')):
        with pytest.raises(Rejected) as error:
            input_checks.skills_state(text)
        assert error.value.kind == kind
