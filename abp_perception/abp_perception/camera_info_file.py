"""Camera calibration files (ROS camera_calibration / camera_info_manager YAML) as the
fields of a sensor_msgs/CameraInfo (plain Python, no rclpy).

The format is what `cameracalibrator` writes and camera_info_manager reads:

    image_width: 640
    image_height: 480
    camera_name: head_camera
    camera_matrix:            {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients:  {rows: 1, cols: 5, data: [k1, k2, t1, t2, k3]}
    rectification_matrix:     {rows: 3, cols: 3, data: [...]}
    projection_matrix:        {rows: 3, cols: 4, data: [...]}

`rectification_matrix` may be left out (identity) and so may `projection_matrix`
(K with a zero fourth column, as for a monocular camera), as camera_info_manager allows.
Anything else wrong raises `CalibrationFileError` naming the file and the field.
"""

import math
import pathlib
from dataclasses import dataclass

import yaml

# distortion model -> the numbers of coefficients it takes (as the detector accepts them)
DISTORTION_COEFFICIENTS = {'plumb_bob': (0, 4, 5), 'rational_polynomial': (0, 8),
                           'equidistant': (4,)}
IDENTITY_3X3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


class CalibrationFileError(ValueError):
    """A calibration file that is missing or not a camera_calibration YAML."""


@dataclass(frozen=True)
class CameraCalibration:
    """The CameraInfo fields of one calibration (row-major tuples, as in the message)."""

    width: int
    height: int
    camera_name: str
    k: tuple                 # 9
    distortion_model: str
    d: tuple
    r: tuple                 # 9
    p: tuple                 # 12

    @property
    def size(self):
        """(width, height) in pixels."""
        return self.width, self.height

    def fill(self, msg):
        """Set the calibration fields of a sensor_msgs/CameraInfo (or anything with its
        fields); the header is the caller's."""
        msg.width, msg.height = self.width, self.height
        msg.distortion_model = self.distortion_model
        msg.d = list(self.d)
        msg.k = list(self.k)
        msg.r = list(self.r)
        msg.p = list(self.p)
        return msg


def _matrix(doc, key, rows, cols, path, default=None):
    entry = doc.get(key)
    if entry is None:
        if default is not None:
            return default
        raise CalibrationFileError(f'{path}: no {key}')
    try:
        data = tuple(float(v) for v in entry['data'])
    except (KeyError, TypeError, ValueError) as error:
        raise CalibrationFileError(f'{path}: {key} needs a list of numbers under data '
                                   f'({error!r})') from None
    if rows is not None and len(data) != rows * cols:
        raise CalibrationFileError(f'{path}: {key} has {len(data)} numbers, expected '
                                   f'{rows} x {cols} = {rows * cols}')
    if not all(math.isfinite(v) for v in data):
        raise CalibrationFileError(f'{path}: {key} has a number that is not finite')
    return data


def parse_calibration(doc, path='<calibration>'):
    """A CameraCalibration from a loaded camera_calibration YAML document."""
    if not isinstance(doc, dict):
        raise CalibrationFileError(f'{path}: not a camera_calibration YAML (no mapping)')
    try:
        width, height = int(doc['image_width']), int(doc['image_height'])
    except KeyError as error:
        raise CalibrationFileError(f'{path}: no {error.args[0]}') from None
    except (TypeError, ValueError) as error:
        raise CalibrationFileError(f'{path}: image size is not a number ({error})') from None
    if width <= 0 or height <= 0:
        raise CalibrationFileError(f'{path}: image size {width}x{height} is not positive')
    k = _matrix(doc, 'camera_matrix', 3, 3, path)
    if k[0] <= 0 or k[4] <= 0:
        raise CalibrationFileError(f'{path}: camera_matrix needs positive focal lengths '
                                   f'(fx {k[0]}, fy {k[4]})')
    model = str(doc.get('distortion_model') or 'plumb_bob')
    d = _matrix(doc, 'distortion_coefficients', None, None, path, default=())
    if model not in DISTORTION_COEFFICIENTS:
        raise CalibrationFileError(f'{path}: distortion_model {model!r} is not one of '
                                   f"{', '.join(DISTORTION_COEFFICIENTS)}")
    counts = DISTORTION_COEFFICIENTS[model]
    if len(d) not in counts:
        raise CalibrationFileError(f'{path}: {len(d)} distortion_coefficients for {model} '
                                   f'(takes {" or ".join(map(str, counts))})')
    r = _matrix(doc, 'rectification_matrix', 3, 3, path, default=IDENTITY_3X3)
    p = _matrix(doc, 'projection_matrix', 3, 4, path,
                default=(k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0))
    return CameraCalibration(width, height, str(doc.get('camera_name') or ''), k, model, d,
                             r, p)


def load_calibration(path):
    """Read a camera_calibration YAML file; CalibrationFileError when it is missing,
    unreadable or malformed."""
    path = pathlib.Path(path).expanduser()
    if not path.is_file():
        raise CalibrationFileError(f'calibration file {path} does not exist'
                                   + (' (it is a folder)' if path.is_dir() else ''))
    try:
        with open(path) as stream:
            doc = yaml.safe_load(stream)
    except (OSError, UnicodeDecodeError) as error:
        raise CalibrationFileError(f'cannot read calibration file {path}: {error}') from None
    except yaml.YAMLError as error:
        raise CalibrationFileError(f'calibration file {path} is not YAML: {error}') from None
    return parse_calibration(doc, path)


def calibration_yaml(calibration):
    """The camera_calibration YAML text of a CameraCalibration (what load_calibration
    reads back)."""
    def matrix(rows, cols, data):
        return {'rows': rows, 'cols': cols, 'data': [float(v) for v in data]}
    doc = {'image_width': calibration.width, 'image_height': calibration.height,
           'camera_name': calibration.camera_name,
           'camera_matrix': matrix(3, 3, calibration.k),
           'distortion_model': calibration.distortion_model,
           'distortion_coefficients': matrix(1, len(calibration.d), calibration.d),
           'rectification_matrix': matrix(3, 3, calibration.r),
           'projection_matrix': matrix(3, 4, calibration.p)}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def check_image_size(calibration, size, source='the frames'):
    """Raise CalibrationFileError when `size` (width, height) is not the calibration's."""
    width, height = size
    if (width, height) != calibration.size:
        raise CalibrationFileError(
            f'the calibration is for {calibration.width}x{calibration.height} px but '
            f'{source} are {width}x{height} px: calibrate at this size, or capture at '
            'the calibrated one')


__all__ = ['CalibrationFileError', 'CameraCalibration', 'DISTORTION_COEFFICIENTS',
           'calibration_yaml', 'check_image_size', 'load_calibration', 'parse_calibration']
