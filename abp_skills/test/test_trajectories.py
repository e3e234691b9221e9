"""Ruckig joint trajectories and path profiles, and the ORBIT base profile and tracker."""

import numpy as np
import pytest

from abp_skills.trajectories import (
    BaseLimits,
    Limits,
    OrbitTracker,
    SampledTrajectory,
    bearing_about,
    head_pan_towards,
    integrate_unicycle,
    joint_trajectory,
    path_profile,
    plan_base_approach,
    plan_orbit,
    sample_profile,
    wrap,
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


def _integrate(plan, dt=0.002):
    """Euler-free exact integration of the plan's own (v, ω) samples."""
    times, _, v, w = plan.sample(dt)
    pose = plan.start_pose.copy()
    for k in range(len(times) - 1):
        h = times[k + 1] - times[k]
        pose = integrate_unicycle(pose, (v[k] + v[k + 1]) / 2, (w[k] + w[k + 1]) / 2, h)
    return pose


@pytest.mark.parametrize('angle_deg', [45, -45, 90, -90, 180])
def test_orbit_profile_integrates_to_the_right_angle(angle_deg):
    cube = np.array([0.4, 0.0])
    start = np.zeros(3)
    limits = BaseLimits()
    plan = plan_orbit(start, cube, np.radians(angle_deg), 0.4, limits)
    end = _integrate(plan)
    # Relative yaw +θ <=> the robot's bearing about the cube changes by -θ.
    change = wrap(bearing_about(cube, end) - bearing_about(cube, start))
    assert wrap(change + np.radians(angle_deg)) == pytest.approx(0.0, abs=np.radians(0.3))
    assert np.linalg.norm(end[:2] - cube) == pytest.approx(0.4, abs=2e-3)
    assert abs(head_pan_towards(end, cube)) < np.radians(0.5)   # facing the cube
    np.testing.assert_allclose(end, plan.end_pose(), atol=3e-3)
    # v = r·ω on the arc, and the limits hold throughout.
    times, poses, v, w = plan.sample(0.01)
    arc = np.abs(v) > 1e-3
    np.testing.assert_allclose(np.abs(w[arc]), np.abs(v[arc]) / 0.4, rtol=1e-6)
    assert np.all(np.sign(w[arc]) == -np.sign(angle_deg))
    assert np.max(np.abs(v)) <= limits.linear_velocity + 1e-9
    assert np.max(np.abs(w)) <= limits.angular_velocity + 1e-9
    # The head can keep the cube in view all along (within the pan limit ±1.6 rad).
    pans = [wrap(np.arctan2(cube[1] - p[1], cube[0] - p[0]) - p[2]) for p in poses]
    assert np.max(np.abs(pans)) <= 1.6
    phases = [plan.reference(t)[3] for t in times]
    assert phases[0] == 'approach' and phases[-1] == 'stroke'


def test_orbit_first_drives_to_the_radius_and_faces_the_cube():
    start = np.array([0.1, -0.2, 0.3])
    cube = np.array([0.7, 0.1])
    plan = plan_orbit(start, cube, np.radians(90), 0.45)
    assert [s.kind for s in plan.segments] == ['turn', 'line', 'turn', 'arc', 'turn']
    end = _integrate(plan)
    assert np.linalg.norm(end[:2] - cube) == pytest.approx(0.45, abs=2e-3)
    change = wrap(bearing_about(cube, end) - bearing_about(cube, start))
    assert np.degrees(change) == pytest.approx(-90, abs=0.5)


def test_base_approach_keeps_the_bearing():
    start = np.array([0.0, 0.0, 0.0])
    cube = np.array([0.55, 0.12])
    plan = plan_base_approach(start, cube, 0.40)
    end = _integrate(plan)
    assert np.linalg.norm(end[:2] - cube) == pytest.approx(0.40, abs=2e-3)
    assert wrap(bearing_about(cube, end) - bearing_about(cube, start)) == pytest.approx(0, abs=1e-3)
    assert abs(head_pan_towards(end, cube)) < 1e-3
    assert plan_base_approach(end, cube, 0.40).segments == []


@pytest.mark.parametrize('angle_deg', [90, -45, 180])
def test_orbit_tracker_closes_the_loop_on_odometry(angle_deg):
    """A base that drives 8 % too far and turns 7 % too little, one tick late, still ends
    within tolerance: the tracker corrects from the measured pose."""
    cube = np.array([0.4, 0.0])
    plan = plan_orbit(np.zeros(3), cube, np.radians(angle_deg), 0.4)
    tracker = OrbitTracker(plan)
    pose, cmd, t, dt = np.zeros(3), (0.0, 0.0), 0.0, 0.05
    while True:
        v, w, _, done, ok = tracker.command(t, pose)
        if done:
            break
        pose = integrate_unicycle(pose, 1.08 * cmd[0], 0.93 * cmd[1], dt)
        cmd, t = (v, w), t + dt
    assert ok
    b_err, h_err, r_err = tracker.final_errors(pose)
    assert abs(b_err) <= tracker.yaw_tolerance and abs(h_err) <= tracker.yaw_tolerance
    assert abs(r_err) <= tracker.position_tolerance
    assert t < plan.duration + tracker.settle_time


def test_orbit_tracker_reports_a_base_that_does_not_move():
    plan = plan_orbit(np.zeros(3), np.array([0.4, 0.0]), np.radians(45), 0.4)
    tracker = OrbitTracker(plan, settle_time=1.0)
    t = 0.0
    while True:
        _, _, _, done, ok = tracker.command(t, np.zeros(3))
        if done:
            break
        t += 0.1
    # It is given the time to drive back to the end point once, then reported.
    assert not ok and t == pytest.approx(tracker.settle_deadline, abs=0.11)
    assert plan.duration + 1.0 < tracker.settle_deadline < plan.duration + 20.0


@pytest.mark.parametrize('side', [0.03, -0.05])
def test_orbit_tracker_removes_a_sideways_error_when_settling(side):
    """A unicycle cannot move sideways: a base knocked sideways at the end of the arc
    turns, drives back to the end point and turns to face the cube."""
    cube = np.array([0.4, 0.0])
    plan = plan_orbit(np.zeros(3), cube, np.radians(-90), 0.4)
    tracker = OrbitTracker(plan, settle_time=2.0)
    pose, t, dt, knocked = np.zeros(3), 0.0, 0.05, False
    while True:
        if t >= plan.duration and not knocked:
            pose = pose + side * np.array([-np.sin(pose[2]), np.cos(pose[2]), 0.0])
            knocked = True
            assert not tracker.settled(pose)
        v, w, _, done, ok = tracker.command(t, pose)
        if done:
            break
        pose, t = integrate_unicycle(pose, v, w, dt), t + dt
    assert ok, tracker.final_errors(pose)
    b_err, h_err, r_err = tracker.final_errors(pose)
    assert abs(b_err) <= tracker.yaw_tolerance and abs(h_err) <= tracker.yaw_tolerance
    assert abs(r_err) <= tracker.position_tolerance


def test_orbit_rejects_bad_input():
    with pytest.raises(ValueError):
        plan_orbit(np.zeros(3), np.array([0.4, 0.0]), np.radians(90), 0.0)
    with pytest.raises(ValueError):
        plan_orbit(np.zeros(3), np.zeros(2), np.radians(90), 0.4)
