import numpy as np
import pinocchio as pin
import pytest

import abp_description
from abp_description.kinematics import RobotKinematics, base_to_world
from abp_description.robot_profile import default_profile_path

EXPECTED_JOINTS = {
    'left_wheel_joint', 'right_wheel_joint', 'torso_pitch_joint', 'head_pan_joint',
    'head_tilt_joint',
    *(f'{side}_{j}_joint' for side in ('left', 'right')
      for j in ('shoulder_pitch', 'shoulder_roll', 'upper_arm_yaw', 'elbow')),
}


@pytest.fixture(scope='module')
def kin():
    return RobotKinematics()


def test_urdf_loads_in_pinocchio():
    model = pin.buildModelFromUrdf(abp_description.urdf_path())
    assert model.nv == 13  # 13 actuated DOF; nq is 15 because wheels are (cos, sin)
    assert set(model.names[1:]) == EXPECTED_JOINTS
    for frame in ('camera_link', 'camera_optical_frame', 'left_hand_link', 'right_hand_link'):
        assert model.existFrame(frame)
    assert 5.0 < pin.computeTotalMass(model) < 25.0


def test_joint_names_and_limits(kin):
    assert kin.nq == 13
    assert set(kin.joint_names) == EXPECTED_JOINTS
    assert set(kin.continuous_joints) == {'left_wheel_joint', 'right_wheel_joint'}
    finite = np.isfinite(kin.lower_limits)
    assert finite.sum() == 11
    assert np.all(kin.lower_limits[finite] < kin.upper_limits[finite])
    assert np.all(kin.upper_limits[finite] - kin.lower_limits[finite] < 2 * np.pi + 1e-9)
    assert np.all(kin.velocity_limits > 0) and np.all(kin.velocity_limits < 50)
    assert np.all(kin.effort_limits > 0) and np.all(kin.effort_limits < 200)
    assert kin.within_limits(kin.neutral())


def test_camera_pose_at_neutral_is_head_height_looking_forward(kin):
    pose = kin.camera_pose(kin.neutral())
    assert 0.65 <= pose[2, 3] <= 0.85
    z_axis, x_axis, y_axis = pose[:3, 2], pose[:3, 0], pose[:3, 1]
    np.testing.assert_allclose(z_axis, [1, 0, 0], atol=1e-9)   # optical axis forward
    np.testing.assert_allclose(x_axis, [0, -1, 0], atol=1e-9)  # image right = robot right
    np.testing.assert_allclose(y_axis, [0, 0, -1], atol=1e-9)  # image down = down


def test_head_tilt_looks_down(kin):
    q = kin.neutral()
    q[kin.joint_index('head_tilt_joint')] = 0.6
    z_axis = kin.camera_pose(q)[:3, 2]
    assert z_axis[2] == pytest.approx(-np.sin(0.6), abs=1e-9)


def test_hands_move_with_arm_joints(kin):
    q0 = kin.neutral()
    left0, right0 = kin.hand_pose(q0, 'left'), kin.hand_pose(q0, 'right')
    assert left0[1, 3] > 0.05 and right0[1, 3] < -0.05  # left hand on +y
    for side in ('left', 'right'):
        for joint in ('shoulder_pitch', 'shoulder_roll', 'elbow'):
            q = q0.copy()
            i = kin.joint_index(f'{side}_{joint}_joint')
            q[i] = np.clip(-0.5 if joint != 'shoulder_roll' else (0.5 if side == 'left' else -0.5),
                           kin.lower_limits[i], kin.upper_limits[i])
            moved = kin.hand_pose(q, side)[:3, 3] - kin.hand_pose(q0, side)[:3, 3]
            assert np.linalg.norm(moved) > 0.05, (side, joint)
            other = 'right' if side == 'left' else 'left'
            np.testing.assert_allclose(kin.hand_pose(q, other), kin.hand_pose(q0, other))
    # Raising an arm forward (negative pitch) brings the hand forward and up.
    q = q0.copy()
    q[kin.joint_index('left_shoulder_pitch_joint')] = -np.pi / 2
    hand = kin.hand_pose(q, 'left')[:3, 3]
    assert hand[0] > 0.4 and hand[2] > 0.5


def test_wheels_do_not_move_frames_but_accept_any_angle(kin):
    q = kin.neutral()
    q[kin.joint_index('left_wheel_joint')] = 7.0
    np.testing.assert_allclose(kin.camera_pose(q), kin.camera_pose(kin.neutral()), atol=1e-12)
    assert kin.within_limits(q)


def test_jacobian_matches_finite_difference(kin):
    rng = np.random.default_rng(0)
    q = kin.clip(rng.uniform(-0.8, 0.8, kin.nq))
    jac = kin.frame_jacobian(q, 'left_hand_link')
    assert jac.shape == (6, 13)
    eps = 1e-6
    for i in range(kin.nq):
        dq = np.zeros(kin.nq)
        dq[i] = eps
        plus, minus = kin.hand_pose(q + dq, 'left'), kin.hand_pose(q - dq, 'left')
        fd = (plus[:3, 3] - minus[:3, 3]) / (2 * eps)
        np.testing.assert_allclose(jac[:3, i], fd, atol=1e-6)


def test_floor_reach_with_torso_pitch(kin):
    # Leaning forward brings the shoulders low enough to touch the side of a cube on the floor.
    q = kin.neutral()
    q[kin.joint_index('torso_pitch_joint')] = 0.8
    q[kin.joint_index('left_shoulder_pitch_joint')] = -1.0
    hand = kin.hand_pose(q, 'left')[:3, 3]
    assert hand[0] > 0.25 and hand[2] < 0.15


def test_camera_intrinsics():
    cam = abp_description.camera_intrinsics()
    assert (cam.width, cam.height) == (640, 480)
    assert cam.fx > 0 and cam.fy > 0
    assert 0 < cam.cx < cam.width and 0 < cam.cy < cam.height
    assert cam.K.shape == (3, 3) and cam.K[2, 2] == 1.0
    assert np.all(cam.D == 0)
    assert cam.frame_id == 'camera_optical_frame'


def test_bad_camera_yaml(tmp_path):
    bad = tmp_path / 'cam.yaml'
    bad.write_text('image_width: 640\n')
    with pytest.raises(ValueError):
        abp_description.camera_intrinsics(bad)


def test_base_to_world():
    pose = base_to_world((1.0, 2.0, np.pi / 2))
    np.testing.assert_allclose(pose @ [1, 0, 0, 1], [1, 3, 0, 1], atol=1e-12)


def test_data_files_found_in_an_installed_share_directory(tmp_path, monkeypatch):
    pytest.importorskip('ament_index_python')
    share = tmp_path / 'share'
    (share / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (share / 'ament_index' / 'resource_index' / 'packages' / 'abp_description').write_text('')
    (share / 'abp_description' / 'urdf').mkdir(parents=True)
    (share / 'abp_description' / 'config').mkdir(parents=True)
    installed = share / 'abp_description' / 'urdf' / 'ubot6.urdf'
    installed.write_text(open(abp_description.urdf_path()).read())
    camera = share / 'abp_description' / 'config' / 'camera.yaml'
    camera.write_text(open(abp_description.camera_yaml_path()).read())
    # The default robot profile names both, relative to its own place in the share dir.
    (share / 'abp_description' / 'profiles').mkdir(parents=True)
    (share / 'abp_description' / 'profiles' / 'ubot6.yaml').write_text(
        open(default_profile_path()).read())
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert abp_description.urdf_path() == str(installed)
    assert abp_description.camera_yaml_path() == str(camera)
    assert abp_description.camera_intrinsics().width == 640
    assert default_profile_path() == str(share / 'abp_description' / 'profiles' / 'ubot6.yaml')
