"""Ruckig joint trajectories and path profiles."""

import numpy as np
import pytest

from abp_skills.motion_profiles import (
    Limits,
    SampledTrajectory,
    joint_trajectory,
    path_profile,
    sample_profile,
)

NAMES = ('a', 'b', 'c')
LIMITS = Limits(velocity=[1.0, 2.0, 0.5], acceleration=[2.0, 3.0, 1.0], jerk=[10.0, 20.0, 5.0])


def test_joint_trajectory_respects_limits_and_reaches_waypoints():
    start = np.array([0.0, 0.0, 0.0])
    waypoints = [np.array([1.0, -0.5, 0.3]), np.array([0.2, 1.5, 0.3]),
                 np.array([-0.4, 0.0, -0.6])]
    dt = 0.01
    traj = joint_trajectory(NAMES, start, waypoints, LIMITS, dt=dt)
    np.testing.assert_allclose(traj.start, start)
    np.testing.assert_allclose(traj.end, waypoints[-1], atol=1e-12)
    # Every waypoint is passed at rest.
    for wp in waypoints:
        dist = np.linalg.norm(traj.positions - wp, axis=1)
        k = int(np.argmin(dist))
        assert dist[k] < 1e-9
        np.testing.assert_allclose(traj.velocities[k], 0.0, atol=1e-9)
    vel_lim, acc_lim, jerk_lim = (np.asarray(x) for x in (LIMITS.velocity,
                                                          LIMITS.acceleration, LIMITS.jerk))
    assert np.all(np.abs(traj.velocities) <= vel_lim * (1 + 1e-6))
    assert np.all(np.abs(traj.accelerations) <= acc_lim * (1 + 1e-6))
    jerk = np.diff(traj.accelerations, axis=0) / np.diff(traj.times)[:, None]
    assert np.all(np.abs(jerk) <= jerk_lim * (1 + 1e-3))
    # Positions are consistent with the velocities (the samples are one trajectory).
    integrated = start + np.concatenate(
        [[np.zeros(3)], np.cumsum((traj.velocities[1:] + traj.velocities[:-1]) / 2
                                  * np.diff(traj.times)[:, None], axis=0)])
    np.testing.assert_allclose(integrated, traj.positions, atol=2e-3)
    assert np.all(np.diff(traj.times) > 0)


def test_joint_trajectory_is_phase_synchronised_and_time_optimal_per_segment():
    traj = joint_trajectory(NAMES, np.zeros(3), [np.array([0.5, 0.5, 0.5])], LIMITS, dt=0.005)
    # The slowest joint (c: v 0.5, a 1.0, j 5) sets the duration; the others follow it
    # on the same normalised profile (a straight line in joint space).
    alone = joint_trajectory(('c',), [0.0], [[0.5]], Limits(0.5, 1.0, 5.0), dt=0.005)
    assert traj.duration == pytest.approx(alone.duration, abs=0.01)
    # A 1-D rest-to-rest jerk-limited move cannot be faster than 2 * sqrt(d / a)
    # (the bang-bang acceleration bound).
    assert alone.duration >= 2 * np.sqrt(0.5 / 1.0) - 1e-6
    fractions = traj.positions / 0.5
    np.testing.assert_allclose(fractions[:, 0], fractions[:, 2], atol=1e-6)


def test_no_motion_gives_a_hold():
    traj = joint_trajectory(NAMES, np.ones(3), [np.ones(3)], LIMITS)
    assert traj.duration == 0.0 and len(traj.times) == 1
    hold = SampledTrajectory.hold(NAMES, [1, 2, 3], duration=2.0)
    np.testing.assert_allclose(hold.at(1.0), [1, 2, 3])


def test_sampled_trajectory_helpers():
    traj = joint_trajectory(NAMES, np.zeros(3), [np.array([1.0, 1.0, 1.0])], LIMITS)
    sub = traj.select(('c', 'a'))
    np.testing.assert_allclose(sub.positions[:, 0], traj.positions[:, 2])
    both = SampledTrajectory.concat([traj, joint_trajectory(NAMES, traj.end, [np.zeros(3)],
                                                            LIMITS)])
    assert both.duration == pytest.approx(2 * traj.duration)
    np.testing.assert_allclose(both.at(traj.duration), [1, 1, 1], atol=1e-9)
    np.testing.assert_allclose(both.end, 0.0, atol=1e-12)
    with pytest.raises(ValueError):
        joint_trajectory(NAMES, np.zeros(3), [np.zeros(2)], LIMITS)
    with pytest.raises(ValueError):
        joint_trajectory(NAMES, np.zeros(3), [np.ones(3)], Limits(0.0, 1.0, 1.0))


def test_path_profile():
    profile = path_profile(0.08, 0.1, 0.3, 2.0)
    times, s, v, a = sample_profile(profile, 0.01)
    assert s[0, 0] == 0.0 and s[-1, 0] == pytest.approx(0.08)
    assert np.all(np.diff(s[:, 0]) >= -1e-12)
    assert np.max(v) <= 0.1 + 1e-9 and np.max(np.abs(a)) <= 0.3 + 1e-9
