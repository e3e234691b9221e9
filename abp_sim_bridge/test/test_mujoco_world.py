"""MujocoWorld with real MuJoCo physics (world: mujoco; no mocks). The skill-driven tests
(the skills' real plans run on this world) live in abp_bench/test/test_mujoco_skills.py:
abp_bench depends on this package, not the other way round."""

import cv2
import numpy as np
import pytest

from abp_belief.cube import R_UP
from abp_description.frames import rot_z
from abp_description.kinematics import RobotKinematics, look_at_world
from abp_sim_bridge.joint_trajectory_follower import TrajectoryPoint
from abp_sim_bridge.mujoco_scene import CubeSpec
from abp_sim_bridge.mujoco_world import (  # also sets MUJOCO_GL=egl by default
    MujocoSettings,
    MujocoWorld,
    discrete_state,
)

pytestmark = pytest.mark.timeout(120)

FACE_TAGS = (0, 1, 2, 3, 4, 5)


def make_world(kin, heavy_face=None, cube_x=0.40, cube_yaw=0.0, up_face=4, **changes):
    """World with the robot at the origin looking at a cube at (cube_x, 0) standing on
    body face `up_face` (MODEL.md's R_UP) turned by `cube_yaw` (rad)."""
    cube = CubeSpec(position=(cube_x, 0.0, 0.05), rotation=rot_z(cube_yaw) @ R_UP[up_face],
                    heavy_face=heavy_face)
    q0, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), cube.position)
    settings = MujocoSettings(initial_positions=tuple(q0), **changes)
    return MujocoWorld(cube, FACE_TAGS, settings, kin)


@pytest.fixture(scope='module')
def kin():
    return RobotKinematics()


def run(world, seconds):
    for _ in range(int(round(seconds / world.dt))):
        world.step()


def test_physics_runs_at_500_hz_or_more(kin):
    world = make_world(kin)
    assert world.model.opt.timestep <= 0.002 + 1e-12
    assert world.substeps * world.model.opt.timestep == pytest.approx(world.dt)


def test_base_drives_under_cmd_vel_within_its_limits(kin):
    world = make_world(kin, cube_x=1.5)
    world.set_cmd_vel(0.2, 0.0)
    for _ in range(5):  # keep the command alive for 1 s (cmd_vel_timeout 0.5 s)
        run(world, 0.2)
        world.set_cmd_vel(0.2, 0.0)
    x, y, yaw = world.robot_pose()
    # 0.2 s to reach 0.2 m/s at 1 m/s^2, then cruise: ~0.18 m in 1 s.
    assert x == pytest.approx(0.18, abs=0.02)
    assert abs(y) < 1e-3 and abs(yaw) < 1e-3
    assert world.odometry_twist()[0] == pytest.approx(0.2, abs=0.01)
    run(world, 1.0)  # the command times out: the base stops
    assert abs(world.odometry_twist()[0]) < 1e-3
    np.testing.assert_allclose(world.base_in_odom(), world.robot_pose(), atol=1e-9)
    world.set_cmd_vel(0.0, 5.0)  # beyond the angular limit of 1.5 rad/s
    run(world, 0.5)
    assert world.odometry_twist()[1] == pytest.approx(1.5, abs=0.02)


def test_odometry_noise_moves_the_true_base_only(kin):
    world = make_world(kin, cube_x=1.5, orbit_odometry_noise=(0.05, 0.1))
    world.set_cmd_vel(0.1, 0.0)
    run(world, 1.0)
    odom, true = world.base_in_odom(), world.robot_pose()
    assert np.linalg.norm(odom - true) > 1e-3
    assert any(e.effect == 'odometry error' for _, e in world.events)
    run(world, 0.2)
    np.testing.assert_allclose(world.base_in_odom(), odom, atol=1e-6)


def test_joint_follows_a_trajectory(kin):
    world = make_world(kin)
    start = world.q[kin.joint_index('head_pan_joint')]
    tilt = world.q[kin.joint_index('head_tilt_joint')]
    world.set_trajectory('head_controller', ['head_pan_joint', 'head_tilt_joint'],
                         [TrajectoryPoint(1.0, np.array([start + 0.5, tilt]))])
    run(world, 0.5)
    half = world.q[kin.joint_index('head_pan_joint')]
    assert half == pytest.approx(start + 0.25, abs=0.02)
    run(world, 1.0)
    assert world.q[kin.joint_index('head_pan_joint')] == pytest.approx(start + 0.5, abs=0.005)


@pytest.mark.parametrize('up_face, yaw_step', [(4, 4), (4, 5), (0, 4), (2, 0), (5, 3)])
def test_discrete_state_matches_the_spawned_pose(kin, up_face, yaw_step):
    # Robot at the origin facing +x, cube at +x: the view frame's x_V is world -x, so
    # relative yaw = world yaw + 180 deg.
    world = make_world(kin, up_face=up_face, cube_yaw=np.radians(45 * yaw_step - 180))
    run(world, 0.2)
    assert world.discrete_state() == (up_face, yaw_step)
    assert discrete_state(world.display_cube().pose(), world.robot_pose()) == (up_face, yaw_step)


def test_camera_image_shows_the_tags_the_state_predicts(kin):
    world = make_world(kin)
    img = world.render()
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
    # State 36: body +z up, body -x (face 1) faces the robot.
    assert ids is not None and set(ids.ravel()) == {FACE_TAGS[4], FACE_TAGS[1]}
    # The top tag's image-top edge points to body -x (flat_renderer's tag axes), here
    # towards the robot: its first two corners (top-left, top-right) are lower in the image.
    top = corners[list(ids.ravel()).index(FACE_TAGS[4])][0]
    assert top[:2, 1].mean() > top[2:, 1].mean() + 20
    # A snapshot renders the same frame later.
    snap = world.snapshot()
    run(world, 0.1)
    assert np.array_equal(world.render(snap), img)
    assert world.render(encoding='mono8').shape == (480, 640)


@pytest.mark.parametrize('dictionary', ['DICT_APRILTAG_36h11', 'DICT_5X5_100'])
def test_the_cube_wears_the_tags_of_the_dictionary_it_is_given(kin, dictionary):
    world = make_world(kin, tag_dictionary=dictionary)
    gray = world.render(encoding='mono8')

    def read(name):
        aruco = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)))
        _, ids, _ = aruco.detectMarkers(gray)
        return set() if ids is None else set(ids.ravel().tolist())
    assert read(dictionary) == {FACE_TAGS[4], FACE_TAGS[1]}
    assert read('DICT_4X4_50') == set()   # not the default tags any more


def test_a_grasp_opening_moves_the_hands_but_not_the_joint_readings(kin):
    # A drawn grasp fault is a calibration error: the shoulder goes further out while its
    # encoder reads the command back, so the skills do not abort on arrival (they did, and
    # then every later skill aborted too) and the grasp really is wider.
    world = make_world(kin)
    run(world, 0.5)
    roll = kin.joint_index('left_shoulder_roll_joint')
    before_q, before_hands = world.q.copy(), world.hand_positions()
    world.set_grasp_opening(0.05)
    run(world, 1.0)
    assert world.q[roll] == pytest.approx(before_q[roll], abs=0.01)
    physical = world.data.qpos[world._qadr[roll]]
    gain = kin.profile.grasp_opening_joints['left_shoulder_roll_joint']
    assert physical - world.q[roll] == pytest.approx(0.05 * gain, rel=0.05)
    def hand_gap(hands):
        return np.linalg.norm(hands['left'] - hands['right'])
    assert hand_gap(world.hand_positions()) > hand_gap(before_hands) + 0.02


def test_a_drawn_missed_push_does_not_outlive_the_manual_action(kin):
    # The sim bridge's faulty world draws the hands' offset for every arm motion that starts
    # out of contact. Drawn only after a contact, a missed push (no contact) stayed for the
    # rest of the episode and every later manual action missed the cube.
    from types import SimpleNamespace

    from abp_sim_bridge.worlds import mujoco_world_class

    faults = SimpleNamespace(p_slip_grasp=0.0, p_missed_push=0.5, slip_grasp_opening=0.01,
                             missed_push_offset=0.10)
    cube = CubeSpec(position=(0.45, 0.0, 0.05), rotation=R_UP[4])
    q0, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), cube.position)
    world = mujoco_world_class()(cube, FACE_TAGS, MujocoSettings(initial_positions=tuple(q0)),
                                 kin, faults=faults, fault_seed=3)
    from abp_description.controllers import ARM_JOINTS
    openings = []
    for motion in range(12):   # arm motions in place: none touches the cube
        stamp = world.time + 0.01
        for side in ('left', 'right'):   # one motion = both arms' trajectories, one stamp
            joints = list(ARM_JOINTS[side])
            hold = np.array([q0[kin.joint_index(j)] for j in joints])
            world.set_trajectory(f'{side}_arm_controller', joints,
                                 [TrajectoryPoint(0.2, hold)], stamp)
            openings.append(world.grasp_opening)
        run(world, 0.3)
    assert not world.hands_touching() and world.manual_actions == 0
    per_motion = openings[1::2]
    assert openings[0::2] == per_motion       # both arms of one motion: one draw
    assert set(per_motion) == {0.0, 0.10}     # redrawn: misses come and go
