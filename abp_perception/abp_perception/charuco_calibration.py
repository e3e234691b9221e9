"""Camera intrinsics from pictures of a printed ChArUco board (plain OpenCV, no rclpy).

The board (`BoardSpec`, printed by `make_cubes --charuco`) is a chessboard whose white
squares hold ArUco markers: the markers name every chessboard corner, so a view that
shows only part of the board still gives corners with known board coordinates.
`cv2.aruco.CharucoDetector` finds them, `cv2.calibrateCamera` fits the pinhole model with
plumb-bob distortion (k1, k2, p1, p2, k3) to all views. The board's markers come from
DICT_5X5_100, not the cubes' DICT_4X4_50, so a board left in view never reads as a cube.

API names are those of OpenCV >= 4.7 (the robot's 4.11 and the wheels' 5.x alike).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np

IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff', '.pgm', '.ppm')
MIN_CORNERS_PER_VIEW = 6       # fewer, or all on one line, and a view adds no constraint


class CalibrationError(ValueError):
    """The pictures cannot give a calibration worth saving (the message says why)."""


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares_x columns x squares_y rows of square_mm squares, markers
    of marker_mm in the white squares."""

    squares_x: int = 5
    squares_y: int = 7
    square_mm: float = 30.0
    marker_mm: float = 21.0     # 7 modules of 3 mm (5x5 bits + border)
    dictionary: str = 'DICT_5X5_100'

    def __post_init__(self):
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError('a ChArUco board needs at least 3 x 3 squares')
        if not 0 < self.marker_mm < self.square_mm:
            raise ValueError(f'marker ({self.marker_mm} mm) must be smaller than the square '
                             f'({self.square_mm} mm)')
        if not self.dictionary.startswith('DICT_') or not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f'unknown ArUco dictionary {self.dictionary!r}')
        markers = (self.squares_x * self.squares_y) // 2
        size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)) \
            .bytesList.shape[0]
        if markers > size:
            raise ValueError(f'{self.squares_x} x {self.squares_y} squares need {markers} '
                             f'markers; {self.dictionary} has {size}')

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.squares_x * self.square_mm, self.squares_y * self.square_mm

    def board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board, in metres (object points in m)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm / 1000,
                                      self.marker_mm / 1000, dictionary)

    def image(self, px_per_mm: float = 2.0) -> np.ndarray:
        """The board as an 8-bit image without margin, `px_per_mm` pixels per millimetre."""
        w, h = self.size_mm
        size = (int(round(w * px_per_mm)), int(round(h * px_per_mm)))
        return self.board().generateImage(size, marginSize=0, borderBits=1)

    def describe(self) -> str:
        return (f'{self.squares_x} x {self.squares_y} squares of {self.square_mm:g} mm, '
                f'markers {self.marker_mm:g} mm, {self.dictionary}')


@dataclass
class Calibration:
    """The result of `calibrate`: K (3x3), D (5,), image size (w, h), the RMS reprojection
    error (px) and which pictures were used."""

    camera_matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple
    rms_px: float
    views_used: list = field(default_factory=list)
    views_skipped: list = field(default_factory=list)   # (name, why)


def iter_pictures(source: str, every: int = 1):
    """(name, BGR or grey image) of every picture of `source`: a folder of images (sorted
    by name) or a video file (every `every`-th frame). CalibrationError if unreadable."""
    if every < 1:
        raise CalibrationError(f'--every must be >= 1, got {every}')
    if os.path.isdir(source):
        names = sorted(n for n in os.listdir(source) if n.lower().endswith(IMAGE_EXTENSIONS))
        if not names:
            raise CalibrationError(f'{source}: no images ({", ".join(IMAGE_EXTENSIONS)})')
        for name in names[::every]:
            image = cv2.imread(os.path.join(source, name), cv2.IMREAD_UNCHANGED)
            yield name, image                 # None: unreadable, reported as skipped
        return
    if not os.path.isfile(source):
        raise CalibrationError(f'{source}: no such file or folder')
    capture = cv2.VideoCapture(source)
    if not capture.isOpened():
        raise CalibrationError(f'{source}: OpenCV cannot open it as a video')
    try:
        index = 0
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            if index % every == 0:
                yield f'frame {index}', frame
            index += 1
    finally:
        capture.release()
    if index == 0:
        raise CalibrationError(f'{source}: the video has no frames OpenCV can decode')


def _grey(image: np.ndarray) -> np.ndarray:
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    return image


def board_points(detector, board, image):
    """(object points (N, 3) m, image points (N, 2) px) of the board corners seen in
    `image`, or (None, why) if the view cannot be used."""
    corners, ids, _, _ = detector.detectBoard(_grey(image))
    count = 0 if ids is None else len(ids)
    if count < MIN_CORNERS_PER_VIEW:
        return None, f'{count} board corners found (needs {MIN_CORNERS_PER_VIEW})'
    if board.checkCharucoCornersCollinear(ids):
        return None, 'the corners found lie on one line'
    obj, img = board.matchImagePoints(corners, ids)
    return (obj.reshape(-1, 3).astype(np.float32), img.reshape(-1, 2).astype(np.float32)), ''


def calibrate(pictures, spec: BoardSpec = BoardSpec(), *, min_views: int = 10,
              max_error_px: float = 1.0, radial_coefficients: int = 2) -> Calibration:
    """Calibrate from (name, image) pairs. CalibrationError when fewer than `min_views`
    pictures show the board usably, the pictures differ in size, or the RMS reprojection
    error exceeds `max_error_px` (the message gives the numbers).

    `radial_coefficients` 2 (k1, k2; k3 held at 0) or 3: two, as ROS's camera_calibration
    by default, because k3 trades off against k1 and k2 and swings wildly unless the views
    fill the image's corners."""
    if radial_coefficients not in (2, 3):
        raise CalibrationError(f'radial coefficients must be 2 or 3, got {radial_coefficients}')
    board = spec.board()
    detector = cv2.aruco.CharucoDetector(board)
    objects, images, used, skipped = [], [], [], []
    size = None
    for name, image in pictures:
        if image is None:
            skipped.append((name, 'unreadable image'))
            continue
        this_size = (image.shape[1], image.shape[0])
        if size is None:
            size = this_size
        elif this_size != size:
            raise CalibrationError(f'{name} is {this_size[0]} x {this_size[1]} px but the '
                                   f'first picture is {size[0]} x {size[1]}: one camera mode '
                                   'per calibration')
        points, why = board_points(detector, board, image)
        if points is None:
            skipped.append((name, why))
            continue
        objects.append(points[0])
        images.append(points[1])
        used.append(name)
    if len(used) < min_views:
        raise CalibrationError(
            f'only {len(used)} of {len(used) + len(skipped)} pictures show the board usably '
            f'(needs {min_views}): show the whole {spec.describe()} board from more '
            'distances and angles, tilted, in every part of the image')
    flags = cv2.CALIB_FIX_K3 if radial_coefficients == 2 else 0
    rms, K, D, _, _ = cv2.calibrateCamera(objects, images, size, None, None, flags=flags)
    D = np.asarray(D, dtype=np.float64).reshape(-1)[:5]
    result = Calibration(np.asarray(K, dtype=np.float64), D, size, float(rms), used, skipped)
    if not np.isfinite(rms) or rms > max_error_px:
        raise CalibrationError(
            f'RMS reprojection error {rms:.3f} px over {len(used)} views is above the limit '
            f'{max_error_px:g} px: blurred pictures, a board that is not flat, or a lens '
            'the plumb-bob model does not fit (a fisheye)')
    return result


__all__ = ['BoardSpec', 'Calibration', 'CalibrationError', 'board_points', 'calibrate',
           'iter_pictures']
