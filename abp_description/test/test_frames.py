"""frames: SE(2) algebra, quaternions, wrapping and arc integration against SciPy."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from abp_description.frames import (
    base_to_world,
    integrate_twist,
    quaternion_from_rotation,
    quaternion_from_yaw,
    rot_z,
    rot_z_deg,
    rotation_from_quaternion,
    se2_between,
    se2_compose,
    wrap_rad,
    yaw_of_quaternion,
    yaw_of_rotation,
)


def test_wrap_rad_scalar_and_array():
    assert wrap_rad(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert np.allclose(wrap_rad(np.array([0.0, 2 * np.pi + 0.1])), [0.0, 0.1])


def test_rotations_agree_with_scipy():
    rng = np.random.default_rng(0)
    for yaw in rng.uniform(-np.pi, np.pi, 5):
        assert np.allclose(rot_z(yaw), Rotation.from_euler('z', yaw).as_matrix())
        assert np.allclose(rot_z_deg(np.degrees(yaw)), rot_z(yaw))
        assert yaw_of_rotation(rot_z(yaw)) == pytest.approx(yaw)
        assert yaw_of_quaternion(*quaternion_from_yaw(yaw)) == pytest.approx(yaw)
    for quat in rng.normal(size=(5, 4)):
        expected = Rotation.from_quat(quat).as_matrix()  # SciPy's order is x, y, z, w too
        assert np.allclose(rotation_from_quaternion(*quat), expected)
        back = quaternion_from_rotation(expected)
        assert back[3] >= 0 and np.allclose(rotation_from_quaternion(*back), expected)
    with pytest.raises(ValueError, match='zero or non-finite'):
        rotation_from_quaternion(0.0, 0.0, 0.0, 0.0)


def test_se2_compose_and_between_invert_each_other():
    a, b = np.array([1.0, -2.0, 0.7]), np.array([0.3, 0.4, -2.5])
    assert np.allclose(se2_between(a, se2_compose(a, b)), b)
    composed = base_to_world(a) @ base_to_world(b)
    assert np.allclose(base_to_world(se2_compose(a, b)), composed)


def test_integrate_twist_follows_the_arc_and_the_line():
    # A quarter circle of radius 1 m from the origin facing +x ends at (1, 1) facing +y.
    end = integrate_twist((0.0, 0.0, 0.0), np.pi / 2, np.pi / 2, 1.0)
    assert np.allclose(end, [1.0, 1.0, np.pi / 2])
    assert np.allclose(integrate_twist((1.0, 0.0, np.pi / 2), 0.5, 0.0, 2.0), [1.0, 1.0,
                                                                               np.pi / 2])
    # Many small steps of the same twist land where one exact step does.
    pose = np.zeros(3)
    for _ in range(100):
        pose = integrate_twist(pose, 0.2, 0.5, 0.01)
    assert np.allclose(pose, integrate_twist(np.zeros(3), 0.2, 0.5, 1.0))
