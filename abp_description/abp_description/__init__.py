"""The robot description: robot profiles (`robot_profile`: the uBot-6's is the default),
where their URDF and camera intrinsics live, and a camera intrinsics loader.

Plain Python (no rclpy). Data files are found in the installed share directory when
ament_index_python knows the package, else in the source tree beside this module.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .data_files import PACKAGE_NAME  # noqa: F401 (the package name, as before)


def urdf_path(profile=None):
    """Absolute path of the URDF of `profile` (default: the shipped uBot-6 profile)."""
    from .robot_profile import load_profile
    return (profile or load_profile()).urdf_file()


def camera_yaml_path(profile=None):
    """Absolute path of the head camera's intrinsics YAML of `profile` (default: uBot-6)."""
    from .robot_profile import load_profile
    return (profile or load_profile()).camera_calibration


@dataclass(frozen=True)
class CameraIntrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)
    distortion_model: str = 'plumb_bob'
    frame_id: str = 'camera_optical_frame'

    @property
    def K(self):  # noqa: N802 -- the usual name of the camera matrix
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self):  # noqa: N802
        return np.asarray(self.distortion, dtype=float)


def camera_intrinsics(path=None, frame_id=None):
    """Load the head camera's intrinsics (ROS camera_calibration YAML) as CameraIntrinsics.
    `frame_id`: the frame its images are stamped in (a camera driver's parameter, e.g. the
    robot profile's optical frame); default the file's `frame_id`, else the uBot-6's."""
    import yaml

    path = Path(path) if path is not None else Path(camera_yaml_path())
    with open(path) as stream:
        doc = yaml.safe_load(stream)
    try:
        k = [float(v) for v in doc['camera_matrix']['data']]
        width, height = int(doc['image_width']), int(doc['image_height'])
        dist_doc = doc.get('distortion_coefficients') or {}
        dist = tuple(float(v) for v in dist_doc.get('data', [0.0] * 5))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f'{path}: not a camera calibration YAML ({err!r})') from err
    if len(k) != 9 or width <= 0 or height <= 0 or k[0] <= 0 or k[4] <= 0:
        raise ValueError(f'{path}: bad camera_matrix or image size')
    return CameraIntrinsics(
        width=width, height=height, fx=k[0], fy=k[4], cx=k[2], cy=k[5], distortion=dist,
        distortion_model=str(doc.get('distortion_model', 'plumb_bob')),
        frame_id=frame_id or str(doc.get('frame_id', 'camera_optical_frame')),
    )


__all__ = ['CameraIntrinsics', 'camera_intrinsics', 'camera_yaml_path', 'urdf_path']
