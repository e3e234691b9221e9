"""The detector's `fixed_camera_pose`: a camera that does not move, given in the base frame
as a person measures it (camera body x forward, y left, z up; positive pitch looks down)."""

import numpy as np
import pytest

from abp_perception.camera_model import fixed_camera_pose


def test_pose_of_the_optical_frame():
    pose = fixed_camera_pose([0.1, -0.2, 0.5, 0.0, 30.0, 0.0])
    assert np.allclose(pose[:3, 3], [0.1, -0.2, 0.5])
    # Optical z (the viewing direction): forward and 30 deg down.
    assert np.allclose(pose[:3, 2], [np.cos(np.radians(30)), 0, -np.sin(np.radians(30))])
    # Optical x is the camera's right (-y of the body), optical y points down-ish.
    assert np.allclose(pose[:3, 0], [0, -1, 0])
    assert pose[2, 1] < 0
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3))
    assert np.isclose(np.linalg.det(pose[:3, :3]), 1.0)
    # Yaw turns the viewing direction left.
    left = fixed_camera_pose([0, 0, 0.5, 0, 0, 90])
    assert np.allclose(left[:3, 2], [0, 1, 0])


def test_empty_means_from_joint_states_and_bad_values_are_refused():
    assert fixed_camera_pose([]) is None and fixed_camera_pose(None) is None
    for bad in ([0.0, 0.0, 0.5], [0, 0, 0.5, 0, float('nan'), 0]):
        with pytest.raises(ValueError, match=r'fixed_camera_pose must be \[x, y, z'):
            fixed_camera_pose(bad)
