"""What a camera driver sends, in the terms the tag detector needs (plain Python, no rclpy).

Frames. Drivers name their frames themselves (`camera_color_optical_frame`,
`head_camera_optical`, ...), and abp's kinematics know only the URDF's. `FrameMap` resolves
a header's frame_id to a URDF frame: an explicit `driver_frame:urdf_frame` pair of the
`frame_map` parameter first, then the name itself when the URDF has it, then the
`camera_frame` parameter for an empty frame_id. Anything else is refused naming the
parameter that would fix it.

Intrinsics. `intrinsics_from_camera_info` reads sensor_msgs/CameraInfo's K, D, R and P.
A raw image is undistorted with K and D. A rectified image (image_proc's `image_rect`) is
already undistorted: its intrinsics are P's left 3x3 and D must not be applied again; P
projects points of the rectified frame, which R rotates from the camera frame (identity for
a monocular camera, a stereo rectification otherwise), so detections are rotated back by
R^T. A right stereo camera's P[0, 3] = -fx' B only shifts the origin to the other camera,
and poses solved with P's 3x3 are already in this camera's own rectified frame.
"""

from dataclasses import dataclass

import numpy as np

FRAME_MAP_PARAMETER = 'frame_map'
# The optical frame (z forward, x right, y down) in a camera body frame (REP 103: x
# forward, y left, z up).
OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def fixed_camera_pose(values):
    """The 4x4 pose of a fixed camera's optical frame in the base frame, from the
    `fixed_camera_pose` parameter [x, y, z, roll, pitch, yaw] (m, deg) of the camera body
    (x forward, y left, z up; positive pitch looks down), or None for [] (the pose
    comes from the joint states). Raises ValueError for another length or a non-finite
    value."""
    values = [] if values is None else [float(v) for v in values]
    if not values:
        return None
    if len(values) != 6 or not np.all(np.isfinite(values)):
        raise ValueError('fixed_camera_pose must be [x, y, z, roll, pitch, yaw] (m, deg) '
                         f'of the camera in the base frame, or []; got {values}')
    from scipy.spatial.transform import Rotation
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler('xyz', values[3:], degrees=True).as_matrix() \
        @ OPTICAL_IN_BODY
    pose[:3, 3] = values[:3]
    return pose


class FrameMapError(ValueError):
    """A frame_map entry that cannot be used (malformed, or not a frame of the URDF)."""


class UnknownFrame(ValueError):
    """A frame_id that neither the frame map nor the URDF knows."""


def _strip(frame):
    # tf2 frame ids carry no leading slash; tolerate ROS 1 style names.
    return frame.strip().lstrip('/')


class FrameMap:
    """Resolves driver frame_ids to frames of the robot model.

    `entries`: 'driver_frame:urdf_frame' strings; `has_frame(name)`: whether the URDF
    has a frame; `default_frame`: the URDF frame of an image without a frame_id."""

    def __init__(self, entries, has_frame, default_frame):
        self._has_frame = has_frame
        self.default_frame = default_frame
        self.mapping = {}
        for entry in entries or ():
            driver, sep, urdf = str(entry).partition(':')
            driver, urdf = _strip(driver), _strip(urdf)
            if not sep or not driver or not urdf or ':' in urdf:
                raise FrameMapError(
                    f"{FRAME_MAP_PARAMETER}: entry {entry!r} is not 'driver_frame:urdf_frame'")
            if not has_frame(urdf):
                raise FrameMapError(f'{FRAME_MAP_PARAMETER}: entry {entry!r} maps to '
                                    f'{urdf!r}, which is not a frame of the URDF')
            if self.mapping.get(driver, urdf) != urdf:
                raise FrameMapError(f'{FRAME_MAP_PARAMETER}: {driver!r} is mapped twice '
                                    f'({self.mapping[driver]!r} and {urdf!r})')
            self.mapping[driver] = urdf

    def resolve(self, frame_id):
        """The URDF frame of a header's frame_id; raises UnknownFrame for one not known."""
        name = _strip(frame_id or '')
        if not name:
            return self.default_frame
        if name in self.mapping:
            return self.mapping[name]
        if self._has_frame(name):
            return name
        raise UnknownFrame(
            f'frame {name[:60]!r} is not a frame of the URDF: map it to the URDF frame of '
            f"the camera with the parameter {FRAME_MAP_PARAMETER}, e.g. "
            f"{FRAME_MAP_PARAMETER}:=['{name[:60]}:{self.default_frame}']")


@dataclass(frozen=True)
class Intrinsics:
    camera_matrix: np.ndarray        # 3 x 3
    dist_coeffs: np.ndarray | None   # None: no distortion to undo
    rectification: np.ndarray | None  # 3 x 3 R of a rectified stereo image; None: identity


def _rotation_or_none(r):
    """R as a 3 x 3 rotation, or None for identity or an unset (all-zero) R; raises
    ValueError for a matrix that is not a rotation."""
    r = np.asarray(r, dtype=np.float64).reshape(3, 3)
    if not np.any(r) or np.allclose(r, np.eye(3), atol=1e-9):
        return None
    if not (np.allclose(r @ r.T, np.eye(3), atol=1e-4) and np.linalg.det(r) > 0):
        raise ValueError('rectification matrix R is not a rotation')
    return r


def intrinsics_from_camera_info(k, d, r, p, rectified):
    """The detector's camera model from CameraInfo's K (9), D, R (9) and P (12).

    rectified=False: K and D (the raw image). rectified=True: P's left 3x3, no distortion,
    and R when it is a rotation other than identity. Raises ValueError naming what is
    wrong (a rectified image with an unset P, a P or K without positive focal lengths)."""
    if not rectified:
        k = np.asarray(k, dtype=np.float64).reshape(3, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1)
        return Intrinsics(k, d if d.size else None, None)
    p = np.asarray(p, dtype=np.float64).reshape(-1)
    if p.size != 12 or not np.any(p):
        raise ValueError('image_is_rectified is true but camera_info has no projection '
                         'matrix P (all zero): calibrate the camera, or set '
                         'image_is_rectified:=false for raw images')
    p = p.reshape(3, 4)
    if not np.all(np.isfinite(p)) or p[0, 0] <= 0 or p[1, 1] <= 0:
        raise ValueError('projection matrix P without finite, positive focal lengths')
    return Intrinsics(p[:, :3].copy(), None, _rotation_or_none(r))


def rectified_to_camera(rectification):
    """4 x 4 pose of the rectified frame in the camera frame (R^T), or None for identity."""
    if rectification is None:
        return None
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(rectification).T
    return pose


def joints_moving_frame(model, frame_name):
    """Names of the joints whose positions move `frame_name` relative to the model's root
    (a pinocchio.Model): what a camera pose must be looked up at the image stamp for."""
    frame = model.frames[model.getFrameId(frame_name)]
    joint = frame.parentJoint if hasattr(frame, 'parentJoint') else frame.parent
    return tuple(model.names[j] for j in model.supports[joint] if j > 0)


__all__ = ['FRAME_MAP_PARAMETER', 'FrameMap', 'FrameMapError', 'Intrinsics', 'UnknownFrame',
           'intrinsics_from_camera_info', 'joints_moving_frame', 'rectified_to_camera']
