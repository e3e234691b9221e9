"""Driver frames and camera_info intrinsics as the detector needs them
(abp_perception.camera_model)."""

import numpy as np
import pytest

from abp_description.kinematics import RobotKinematics
from abp_perception.camera_model import (
    FrameMap,
    FrameMapError,
    UnknownFrame,
    intrinsics_from_camera_info,
    joints_moving_frame,
    rectified_to_camera,
)

URDF_FRAMES = {'camera_optical_frame', 'head_link', 'base_link'}


def frame_map(entries):
    return FrameMap(entries, URDF_FRAMES.__contains__, 'camera_optical_frame')


def test_driver_frames_resolve_through_the_map_then_the_urdf():
    frames = frame_map(['camera_color_optical_frame:camera_optical_frame',
                        '/head_cam : head_link'])
    assert frames.resolve('camera_color_optical_frame') == 'camera_optical_frame'
    assert frames.resolve('head_cam') == 'head_link'
    assert frames.resolve('/head_cam') == 'head_link'
    assert frames.resolve('head_link') == 'head_link'          # in the URDF itself
    assert frames.resolve('') == 'camera_optical_frame'        # no frame_id: camera_frame


def test_an_unknown_frame_is_refused_naming_the_parameter():
    with pytest.raises(UnknownFrame, match='frame_map') as info:
        frame_map([]).resolve('camera_color_optical_frame')
    assert 'camera_color_optical_frame:camera_optical_frame' in str(info.value)


@pytest.mark.parametrize('entry, message', [
    ('no_colon', 'not .driver_frame:urdf_frame.'),
    (':camera_optical_frame', 'not .driver_frame:urdf_frame.'),
    ('a:b:c', 'not .driver_frame:urdf_frame.'),
    ('cam:not_in_urdf', 'not a frame of the URDF'),
])
def test_bad_map_entries_are_refused(entry, message):
    with pytest.raises(FrameMapError, match=message):
        frame_map([entry])


def test_a_frame_mapped_twice_is_refused():
    with pytest.raises(FrameMapError, match='mapped twice'):
        frame_map(['cam:head_link', 'cam:camera_optical_frame'])


K = [500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0]
D = [0.1, -0.05, 0.001, 0.0, 0.0]
P = [480.0, 0.0, 322.0, 0.0, 0.0, 481.0, 238.0, 0.0, 0.0, 0.0, 1.0, 0.0]
IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def test_raw_images_use_k_and_d():
    got = intrinsics_from_camera_info(K, D, IDENTITY, P, rectified=False)
    np.testing.assert_array_equal(got.camera_matrix, np.reshape(K, (3, 3)))
    np.testing.assert_array_equal(got.dist_coeffs, D)
    assert got.rectification is None


def test_rectified_images_use_p_and_no_distortion():
    got = intrinsics_from_camera_info(K, D, IDENTITY, P, rectified=True)
    np.testing.assert_array_equal(got.camera_matrix, np.reshape(P, (3, 4))[:, :3])
    assert got.dist_coeffs is None and got.rectification is None
    # An unset R (all zero, as uncalibrated drivers send it) is identity too.
    assert intrinsics_from_camera_info(K, D, [0.0] * 9, P, True).rectification is None


def test_a_stereo_rectification_rotates_back_to_the_camera_frame():
    angle = np.radians(2.0)
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    right_p = list(P)
    right_p[3] = -480.0 * 0.06                                 # -fx' * baseline
    got = intrinsics_from_camera_info(K, D, r.ravel(), right_p, True)
    np.testing.assert_allclose(got.rectification, r)
    # A point in the rectified frame, R^T back to the camera frame.
    point_rect = np.array([0.1, 0.0, 1.0, 1.0])
    point_cam = rectified_to_camera(got.rectification) @ point_rect
    np.testing.assert_allclose(r @ point_cam[:3], point_rect[:3])


def test_rectified_without_a_projection_matrix_is_refused():
    with pytest.raises(ValueError, match='no projection matrix P'):
        intrinsics_from_camera_info(K, D, IDENTITY, [0.0] * 12, True)
    with pytest.raises(ValueError, match='not a rotation'):
        intrinsics_from_camera_info(K, D, [2.0, 0, 0, 0, 1, 0, 0, 0, 1], P, True)


def test_the_head_joints_move_the_camera_and_the_wheels_do_not():
    kin = RobotKinematics()
    joints = joints_moving_frame(kin.model, 'camera_optical_frame')
    assert {'head_pan_joint', 'head_tilt_joint', 'torso_pitch_joint'} <= set(joints)
    assert not any('wheel' in j or 'elbow' in j for j in joints)
