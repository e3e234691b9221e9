"""Camera calibration YAML files in ROS's format (plain Python, no rclpy).

The format is what ROS's `camera_calibration` writes and `camera_info_manager` reads
(camera_calibration_parsers' YAML):

    image_width: 640
    image_height: 480
    camera_name: webcam
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
    projection_matrix: {rows: 3, cols: 4, data: [fx', 0, cx', 0, 0, fy', cy', 0, 0, 0, 1, 0]}

`load(path)` gives a `CameraCalibration` (K, D, R, P, width, height, name, model) with
`camera_info_fields()` for a sensor_msgs/CameraInfo; `save(path, ...)` writes one.
For a single camera R is the identity and P is the camera matrix of the undistorted
image, as camera_calibration computes it (`cv2.getOptimalNewCameraMatrix`, alpha 0).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np
import yaml

DISTORTION_MODELS = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}


class CalibrationFileError(ValueError):
    """A calibration file that is missing, unreadable or malformed (the message says how)."""


@dataclass(frozen=True)
class CameraCalibration:
    width: int
    height: int
    camera_name: str
    K: np.ndarray                # (3, 3)
    D: np.ndarray                # (n,) for distortion_model
    R: np.ndarray                # (3, 3)
    P: np.ndarray                # (3, 4)
    distortion_model: str = 'plumb_bob'

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def fill(self, msg):
        """Set the calibration fields of a sensor_msgs/CameraInfo (or anything with its
        fields); the header is the caller's. Returns `msg`."""
        for name, value in self.camera_info_fields().items():
            setattr(msg, name, value)
        return msg

    def camera_info_fields(self) -> dict:
        """Keyword arguments for sensor_msgs.msg.CameraInfo (header excluded)."""
        return {'width': self.width, 'height': self.height,
                'distortion_model': self.distortion_model,
                'd': [float(v) for v in self.D], 'k': [float(v) for v in self.K.ravel()],
                'r': [float(v) for v in self.R.ravel()], 'p': [float(v) for v in self.P.ravel()]}


def projection_matrix(K, D, size, alpha: float = 0.0) -> np.ndarray:
    """P (3x4) of a single camera: the undistorted image's camera matrix, no translation."""
    new_k, _ = cv2.getOptimalNewCameraMatrix(np.asarray(K, float), np.asarray(D, float),
                                             tuple(int(v) for v in size), alpha)
    return np.hstack([new_k, np.zeros((3, 1))])


def _matrix(rows, cols, values) -> dict:
    return {'rows': rows, 'cols': cols, 'data': [float(v) for v in np.ravel(values)]}


def to_dict(calibration: CameraCalibration) -> dict:
    c = calibration
    return {'image_width': int(c.width), 'image_height': int(c.height),
            'camera_name': c.camera_name,
            'camera_matrix': _matrix(3, 3, c.K),
            'distortion_model': c.distortion_model,
            'distortion_coefficients': _matrix(1, len(c.D), c.D),
            'rectification_matrix': _matrix(3, 3, c.R),
            'projection_matrix': _matrix(3, 4, c.P)}


def make(K, D, size, camera_name: str = 'camera', R=None, P=None,
         distortion_model: str = 'plumb_bob') -> CameraCalibration:
    """A CameraCalibration from K, D and the image size (w, h); R defaults to the identity
    and P to `projection_matrix(K, D, size)`."""
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(D, dtype=np.float64).reshape(-1)
    R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64).reshape(3, 3)
    P = projection_matrix(K, D, size) if P is None else np.asarray(P, float).reshape(3, 4)
    return CameraCalibration(int(size[0]), int(size[1]), str(camera_name), K, D, R, P,
                             distortion_model)


def save(path: str, calibration: CameraCalibration):
    """Write `calibration` to `path` (atomically: a reader never sees half a file)."""
    text = yaml.safe_dump(to_dict(calibration), sort_keys=False, default_flow_style=None)
    tmp = f'{path}.part'
    with open(tmp, 'w', encoding='utf-8') as f:
        f.write(text)
    os.replace(tmp, path)


def _read_matrix(doc, key, rows, cols, path):
    entry = doc.get(key)
    if not isinstance(entry, dict) or 'data' not in entry:
        raise CalibrationFileError(f'{path}: {key} is missing or has no data')
    try:
        data = np.asarray(entry['data'], dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationFileError(f'{path}: {key}.data is not a list of numbers') from None
    try:
        want_rows = int(entry.get('rows', rows if rows is not None else 1))
        want_cols = int(entry.get('cols', cols if cols is not None else data.size))
    except (TypeError, ValueError):
        raise CalibrationFileError(f'{path}: {key}.rows and .cols must be integers') from None
    if rows is not None and (want_rows, want_cols) != (rows, cols):
        raise CalibrationFileError(f'{path}: {key} is {want_rows} x {want_cols}, '
                                   f'expected {rows} x {cols}')
    if data.size != want_rows * want_cols or not np.all(np.isfinite(data)):
        raise CalibrationFileError(f'{path}: {key} needs {want_rows * want_cols} finite '
                                   f'numbers, has {data.size}')
    return data.reshape(want_rows, want_cols)


def load(path: str) -> CameraCalibration:
    """Read a camera_calibration YAML (CalibrationFileError with the path and the reason)."""
    try:
        with open(path, encoding='utf-8') as f:
            doc = yaml.safe_load(f)
    except OSError as exc:
        raise CalibrationFileError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise CalibrationFileError(f'{path}: not YAML: {exc}') from None
    if not isinstance(doc, dict):
        raise CalibrationFileError(f'{path}: not a camera calibration (a YAML mapping)')
    try:
        width, height = int(doc['image_width']), int(doc['image_height'])
    except (KeyError, TypeError, ValueError):
        raise CalibrationFileError(f'{path}: image_width and image_height must be '
                                   'integers') from None
    if width <= 0 or height <= 0:
        raise CalibrationFileError(f'{path}: image size {width} x {height} is not positive')
    model = doc.get('distortion_model', 'plumb_bob')
    if model not in DISTORTION_MODELS:
        raise CalibrationFileError(f'{path}: distortion_model {model!r} is not one of '
                                   f'{", ".join(DISTORTION_MODELS)}')
    K = _read_matrix(doc, 'camera_matrix', 3, 3, path)
    D = _read_matrix(doc, 'distortion_coefficients', None, None, path).reshape(-1)
    if D.size not in (0, DISTORTION_MODELS[model]):
        raise CalibrationFileError(f'{path}: {model} has {DISTORTION_MODELS[model]} '
                                   f'distortion coefficients, the file gives {D.size}')
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationFileError(f'{path}: camera_matrix focal lengths must be > 0')
    R = _read_matrix(doc, 'rectification_matrix', 3, 3, path) \
        if 'rectification_matrix' in doc else np.eye(3)
    P = _read_matrix(doc, 'projection_matrix', 3, 4, path) \
        if 'projection_matrix' in doc else np.hstack([K, np.zeros((3, 1))])
    return CameraCalibration(width, height, str(doc.get('camera_name', '')), K, D, R, P, model)


def check_image_size(calibration, size, source='the frames'):
    """Raise CalibrationFileError when `size` (width, height) is not the calibration's."""
    width, height = size
    if (width, height) != calibration.size:
        raise CalibrationFileError(
            f'the calibration is for {calibration.width}x{calibration.height} px but '
            f'{source} are {width}x{height} px: calibrate at this size, or capture at '
            'the calibrated one')


__all__ = ['CalibrationFileError', 'CameraCalibration', 'check_image_size', 'load', 'make',
           'projection_matrix', 'save', 'to_dict']
