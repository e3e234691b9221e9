"""Planar (SE(2)) and rotation helpers shared by every package (plain NumPy, no rclpy).

Units are in the names: angles in radians unless a name ends in `_deg`; planar poses
are (x_m, y_m, yaw_rad) arrays; 4x4 matrices are homogeneous poses.
"""

import numpy as np

# scipy.spatial (0.3-0.4 s to import) is imported by the two functions that use it: most
# nodes import this module and never call them (docs/STARTUP.md).


def wrap_rad(angle_rad):
    """Angle (scalar or array) wrapped into [-pi, pi)."""
    wrapped = (np.asarray(angle_rad, dtype=float) + np.pi) % (2 * np.pi) - np.pi
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def rot_z(angle_rad):
    """3x3 rotation about z."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_z_deg(angle_deg):
    """3x3 rotation about z, from degrees (the ATG's 45-degree yaw steps)."""
    return rot_z(np.radians(angle_deg))


def axis_angle_deg(rotation):
    """(angle in degrees, unit axis) of a 3x3 rotation. Below 1 degree the axis is
    undefined and returned as zeros; near 180 degrees (where the antisymmetric part
    vanishes) it comes from the diagonal, its sign from the largest component's row."""
    q = np.asarray(rotation, dtype=float)
    angle = float(np.degrees(np.arccos(np.clip((np.trace(q) - 1) / 2, -1.0, 1.0))))
    if angle < 1.0:
        return angle, np.zeros(3)
    if angle > 179.0:
        axis = np.sqrt(np.clip((np.diag(q) + 1) / 2, 0.0, None))
        big = int(np.argmax(axis))
        return angle, np.sign(q[big] + (np.arange(3) == big)) * axis
    axis = np.array([q[2, 1] - q[1, 2], q[0, 2] - q[2, 0], q[1, 0] - q[0, 1]])
    return angle, axis / np.linalg.norm(axis)


def yaw_of_rotation(rotation):
    """Yaw (rad) of a 3x3 rotation's x axis projected on the floor."""
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


def yaw_of_quaternion(x, y, z, w):
    """Yaw (rad) of a unit quaternion (ROS order x, y, z, w) about z."""
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def quaternion_from_yaw(yaw_rad):
    """(x, y, z, w) of a rotation about z."""
    return 0.0, 0.0, float(np.sin(yaw_rad / 2.0)), float(np.cos(yaw_rad / 2.0))


def rotation_from_quaternion(x, y, z, w):
    """3x3 rotation of a quaternion (ROS order x, y, z, w), normalised first."""
    q = np.array([x, y, z, w], dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError('quaternion has zero or non-finite norm')
    from scipy.spatial.transform import Rotation
    return Rotation.from_quat(q / n).as_matrix()


def quaternion_from_rotation(rotation):
    """Unit quaternion (x, y, z, w) with w >= 0 of a 3x3 rotation matrix."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(np.asarray(rotation, dtype=float).reshape(3, 3)).as_quat(
        canonical=True)


def se2_compose(a, b):
    """Planar pose a ∘ b: b expressed in a's frame, returned in a's parent frame."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1],
                     wrap_rad(a[2] + b[2])])


def se2_between(a, b):
    """Planar pose of b in a's frame (a⁻¹ ∘ b)."""
    c, s = np.cos(a[2]), np.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_rad(b[2] - a[2])])


def integrate_twist(pose, v_mps, w_radps, dt_s):
    """Planar pose (x, y, yaw) after driving at (v, w) for dt: the exact arc."""
    x, y, th = (float(c) for c in pose)
    if abs(w_radps) < 1e-9:
        return np.array([x + v_mps * dt_s * np.cos(th), y + v_mps * dt_s * np.sin(th), th])
    th2 = th + w_radps * dt_s
    return np.array([x + v_mps / w_radps * (np.sin(th2) - np.sin(th)),
                     y - v_mps / w_radps * (np.cos(th2) - np.cos(th)), wrap_rad(th2)])


def base_to_world(base_pose):
    """4x4 world pose of base_link from the planar base pose (x, y, yaw)."""
    x, y, yaw = (float(v) for v in base_pose)
    out = np.eye(4)
    out[:3, :3] = rot_z(yaw)
    out[0, 3], out[1, 3] = x, y
    return out


__all__ = ['axis_angle_deg', 'base_to_world', 'integrate_twist', 'quaternion_from_rotation',
           'quaternion_from_yaw',
           'rotation_from_quaternion', 'rot_z', 'rot_z_deg', 'se2_between', 'se2_compose',
           'wrap_rad', 'yaw_of_quaternion', 'yaw_of_rotation']
