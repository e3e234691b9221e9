"""look_at: the one head-aiming rule points the optical axis at the target."""

import numpy as np
import pytest

from abp_description.frames import base_to_world
from abp_description.kinematics import RobotKinematics, look_at, look_at_world


@pytest.fixture(scope='module')
def kin():
    return RobotKinematics()


@pytest.mark.parametrize('target', [(0.4, 0.0, 0.05), (0.5, 0.3, 0.0), (0.35, -0.25, 0.1)])
def test_optical_axis_passes_through_the_target(kin, target):
    q, err = look_at(kin, kin.neutral(), target)
    assert err < 1e-3
    cam = kin.camera_pose(q)
    d = cam[:3, :3].T @ (np.asarray(target) - cam[:3, 3])
    assert d[2] > 0 and np.hypot(d[0], d[1]) / d[2] < 1e-3


def test_world_target_from_a_moved_base_matches_the_base_frame_target(kin):
    base = np.array([1.0, 2.0, 0.8])
    target_base = np.array([0.45, 0.1, 0.05])
    target_world = (base_to_world(base) @ np.append(target_base, 1.0))[:3]
    q_world, _ = look_at_world(kin, kin.neutral(), base, target_world)
    q_base, _ = look_at(kin, kin.neutral(), target_base)
    assert np.allclose(q_world, q_base, atol=1e-9)
