"""ArUco tag detection with poses and covariances (plain NumPy + OpenCV, no rclpy).

Pipeline per grey image (``TagDetector.detect``):

1. ``cv2.aruco.ArucoDetector.detectMarkers`` with corner refinement off, threshold
   windows 3 px, 7 px (larger contours only) and 11, 19 px on the image scaled by 0.6
   (three calls, ``THRESHOLD_WINDOWS``) and bit sampling tuned for small, blurred tags
   (8 px per cell, 30 % cell margin ignored; see ``TagDetector.default_parameters``); on
   the whole image, or only on a region of it (``roi``: where the cube was,
   ``RegionSearch``, which searches the whole image every few frames). The 7 px window
   finds flat tags whose thin quiet zone the 3 and 13 px windows merge with the
   background (issue 16: 25 tags within 1.5 m).
2. Corners refined by edge-line fitting (``corners.refine_quads``; unbiased, unlike
   ``CORNER_REFINE_SUBPIX`` on L-shaped corners, see that module).
3. Second pass: candidates ArUco rejected are refined the same way and decoded again
   (``corners.decode_quads``, no error correction, black border and white quiet zone
   required; where the edge fit fails, at the contour corners). Far, foreshortened
   tags are often rejected only because their integer contour corners sample the bits
   badly. Only contours that look like a marker at their corners (frame and bits
   contrast, ``blur_decode.marker_contrast``, >= ``CANDIDATE_MIN_CONTRAST``), at most
   ``MAX_CANDIDATES`` (16), largest first, one per place (the same contour found by
   several threshold windows is refined once).
4. Pose of each tag by ``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE``: object
   points in its documented order (top-left, top-right, bottom-right, bottom-left at
   (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2)), i.e. ArUco's corner order; the
   tag frame has x right, y up and z out of the tag face. The lower-error of the two
   IPPE solutions is used; the other one sizes the tilt uncertainty (below).
   Fallback: IPPE_SQUARE (OpenCV 5.0) fails when the tag is parallel to the image plane
   (to within ~0.001 deg: noise-free renders, not noisy camera images), i.e. when the
   quad is an exact parallelogram and the homography has no perspective part. The tag
   in the image centre then gets the identity rotation (facing away; reprojection error
   ~0.7 side), elsewhere a rotation tilted by up to ~65 deg, with errors of 0.1-4 px
   where the true pose has none. So when the quad is a parallelogram to within
   ``PARALLELOGRAM_PX`` (0.02 px; IPPE fails up to ~3e-4 px) or the best IPPE error
   exceeds ``PNP_FALLBACK_PX`` (0.5 px), the pose is also solved with ``SOLVEPNP_SQPNP``
   and ``SOLVEPNP_ITERATIVE`` (both right on such quads, and ~5-15x IPPE's cost) and the
   solution with the lowest reprojection error is used (``Detection.solver`` names it).
5. Covariance and confidence (below). Degenerate or implausible detections are
   dropped with a reason (``DetectionResult.dropped``).
   Face search (``face_search``, on when ``cube_size`` > 0): the cube faces next to each
   found tag that face the camera (within 75 deg) and hold no found tag are predicted
   from the tag's pose (``face_search.adjacent_face_boxes``; the mirrored IPPE pose too
   when ambiguity > ``FACE_SEARCH_AMBIGUITY``) down to their marker quads; quads dark
   inside against their quiet zone (``blur_decode.darkness``) are refined and decoded as
   in step 3 or, failing that, by correlation with every code blurred by a set of
   kernels (``blur_decode.decode_blurred``, ``blur_decode`` option), and get poses as in
   step 4; a second round predicts from the tags the first found
   (``DetectionResult.face_search`` counts them). It finds tags that motion blur and
   JPEG leave without any ArUco contour.
6. Rigid cube (``cube_size`` > 0, default 0.10 m): tags whose centres are an adjacent-face
   distance apart are fitted as one rigid ARcube from all their corners, seeded by every
   IPPE solution of every tag (``rigid_cube``; it removes IPPE's mirrored-tilt flips).
   ``DetectionResult.cubes`` lists the cube poses; each of their tags gets the pose and
   covariance the cube implies (``solver`` 'rigid_cube', ``cube`` its index), and keeps
   its own pose in ``single_pose`` / ``single_covariance`` / ``single_reprojection_error``
   (``single_tag_pose`` gives the tag's own pose either way).

Tracking (``TagDetector.track``; ``RegionSearch`` between full-frame passes): the last
frame's tags are followed instead of searched for: corners moved by Lucas-Kanade optical
flow, refined (step 2), decoded again under their own id (step 3's bits, or the face
search's blurred-code correlation), then steps 4-6 (face search, rigid cube). No ArUco
pass; ``RegionSearch`` falls back to ArUco in the region when a tag ArUco had found is
lost (``Detection.source``).

Covariance model (6 x 6, order x, y, z, rot x, rot y, rot z, axes of the output frame;
rotations as a small rotation vector). With ``f`` the focal length (px), ``s`` the
marker size, ``t`` the tag centre in the camera frame, range ``r = |t|``, ``side`` the
marker's apparent side in the image (square root of its image area: foreshortening
included) and the corner noise ``sigma = sqrt(corner_sigma_px^2 + (40 px^2 / side^2)^2
+ rms^2)`` (``rms``: reprojection error, px; the middle term is the edge fit's loss of
accuracy on small tags, calibrated on the sim bridge's renders):

- position: ``sigma_lateral = r * sigma / (2 f)`` across the line of sight (the centre
  averages four corners) and ``sigma_range = r * sigma / side`` along it (the range
  comes from the apparent size); so it grows with distance (linearly across, ~r^2
  along the ray) and with the reprojection error;
- orientation, in the tag frame: tilt about the tag's x and y axes
  ``sigma_tilt = sigma * f / side^2`` (perspective differences across the marker,
  which vanish as the tag shrinks), plus, when the second IPPE solution is nearly as
  good (best / second reprojection error > ``ambiguity_ratio``, default 0.7: the
  tilt ambiguity of small, far tags), half the angle between the two solutions;
  roll about the normal ``sigma_roll = sigma / side``; rotated into the output frame.
  Position-orientation cross terms are 0. Floors of 0.1 mm and 1 mrad keep it positive
  definite. On the renders the range errors are ~1 sigma at 2 m (median |z| 0.9).

Confidence in [0, 1]: ``exp(-rms^2 / 2) * min(1, side / 20 px)``.

Images are converted from ``sensor_msgs/Image``-shaped data without cv_bridge by
``image_encodings.image_to_gray`` (re-exported here): 8-bit mono and colour, YUV 4:2:2,
mono16 and Bayer; anything else raises ``ImageEncodingError``.
``sensor_msgs/CompressedImage`` payloads (JPEG or PNG, image_transport's ``compressed``
format strings such as ``'rgb8; jpeg compressed bgr8'``) are decoded by
``compressed_image_to_gray`` (``cv2.imdecode``); a corrupt payload raises
``ImageDecodeError`` (an ``ImageEncodingError``).

Refusals (``ValueError`` with both values named, never a ``cv2.error``): an unknown
dictionary name or id (the valid names listed), an image that is empty, not 2-D or not
uint8 (``TagDetector.detect``), and an image whose size differs from the camera's
``image_size`` given at construction (``ImageSizeError``: the scaled image of a 2x
resized camera would put every tag at twice its distance).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from .blur_decode import MIN_DARKNESS, darkness, decode_blurred, marker_contrast
from .corners import decode_quads, quad_areas, refine_quads
from .face_search import adjacent_face_boxes, copy_parameters
from .image_encodings import (
    EIGHT_BIT_ENCODINGS,
    SUPPORTED_ENCODINGS,
    ImageEncodingError,
    ImageLayoutError,
    image_msg_to_gray,
    image_to_gray,
)
from .rigid_cube import fit_cubes

__all__ = [
    'ImageEncodingError', 'ImageDecodeError', 'ImageLayoutError', 'ImageSizeError', 'image_to_gray',
    'image_msg_to_gray', 'compressed_image_to_gray', 'compressed_msg_to_gray',
    'parse_compressed_format', 'check_image_size', 'SUPPORTED_ENCODINGS',
    'DICTIONARY_NAMES', 'dictionary_id', 'dictionary_name', 'marker_object_points', 'Detection',
    'DroppedDetection', 'DetectionResult', 'TagDetector', 'RegionSearch', 'search_region',
    'clip_regions', 'transform_covariance', 'pose_covariance',
]

# What a CompressedImage format may name as the original or transport encoding.
_ENCODINGS = EIGHT_BIT_ENCODINGS

DICTIONARY_NAMES = tuple(sorted(n for n in dir(cv2.aruco) if n.startswith('DICT_')))
# OpenCV id -> name; cv2.aruco.getPredefinedDictionary maps an unknown id to DICT_4X4_50
# without a word, so ids are checked against this table first.
_DICTIONARY_BY_ID = {}
for _name in DICTIONARY_NAMES:
    _DICTIONARY_BY_ID.setdefault(int(getattr(cv2.aruco, _name)), _name)
del _name

_FULL_CONFIDENCE_SIDE_PX = 20.0
_POSITION_FLOOR = 1e-4       # m
# Corner noise that grows as tags shrink: the edge fit of a marker only ~15 px across
# sees 2-3 px per cell; 40 / side^2 px (0.16 px at 16 px) matches the renders' errors.
SMALL_TAG_PX2 = 40.0
# Rejected contours re-examined per image (largest first). 16, not 24: the face search
# finds most tags the last 8 did, and the 1 ms they cost pays for it (issue 16).
MAX_CANDIDATES = 16
# Rejected contours are refined only when they look like a marker at their contour
# corners: quiet zone brighter than the border cells, and black and white inner cells,
# both by this many grey levels (``blur_decode.marker_contrast``; ~60 % of the rejected
# contours on the realistic suite fail it, none of those the second pass decodes).
CANDIDATE_MIN_CONTRAST = 15.0
# Rejected contours whose centres are closer than this fraction of a larger one's side
# (and areas within 1.5x) are the same contour from another threshold window: only the
# largest is refined (the edge fit takes all of them to the same edges).
CANDIDATE_DUPLICATE = 0.15
# ArUco's adaptive-threshold windows, one detectMarkers call per set: (min, max, step px
# of the image the call sees, image scale, minMarkerPerimeterRate or None: the default).
# 3 px: small, far (and occluded) tags. 7 px: flat tags whose thin quiet zone the wider
# windows merge with the background (issue 16); only contours of perimeter >= 0.1 of
# the image width (tags within ~1.5 m; the smaller ones are the 3 px window's): half
# the call's cost. 11 and 19 px on the image scaled by 0.6 (~18 and 32 px at full
# size: large, dim, shaded or blurred tags): ~40 % of the cost of 20 and 33 px at full
# size; its corners are scaled back and refined on the full image like the others.
THRESHOLD_WINDOWS = ((3, 3, 10, 1.0, None), (7, 7, 10, 1.0, 0.1), (11, 19, 8, 0.6, None))
# Accepted markers of two window sets with the same id and centres this close are one.
DUPLICATE_PX = 3.0
# Face search (``face_search``): rounds of prediction (the second from the tags the
# first found: a cube's third face).
FACE_SEARCH_ROUNDS = 2
# Best / second IPPE reprojection error above which the face search also trusts a tag's
# mirrored pose (below it, the mirrored pose only adds boxes on faces with no tag).
FACE_SEARCH_AMBIGUITY = 0.6
_ROTATION_FLOOR = 1e-3       # rad
# Best IPPE_SQUARE reprojection error (px) above which SQPNP and ITERATIVE are tried too
# (module docstring). Good detections on the renders stay well below it.
PNP_FALLBACK_PX = 0.5
# A quad this close to a parallelogram (|q0 + q2 - q1 - q3|, px) is IPPE_SQUARE's
# degenerate case (module docstring): the fallback solvers run too.
PARALLELOGRAM_PX = 0.02
_PNP_FALLBACKS = (('sqpnp', cv2.SOLVEPNP_SQPNP), ('iterative', cv2.SOLVEPNP_ITERATIVE))


class ImageDecodeError(ImageEncodingError):
    """A compressed image payload that does not decode (corrupt, truncated, empty)."""


class ImageSizeError(ValueError):
    """The image's size is not the one the camera intrinsics are for."""


def check_image_size(width, height, expected):
    """Raise ImageSizeError unless (width, height) equals `expected` (None: anything)."""
    if expected is None:
        return
    ew, eh = expected
    if (int(width), int(height)) != (ew, eh):
        raise ImageSizeError(
            f'image is {int(width)}x{int(height)} px but the camera intrinsics (camera_info) '
            f'are for {ew}x{eh} px: poses would be wrong (a scaled image scales every '
            f'distance); resize the image or use the matching camera_info')


def _parse_format(fmt):
    """(original encoding or None, codec or None, transport encoding or None) of a
    CompressedImage format string."""
    fmt = (fmt or '').strip()
    original, _, rest = fmt.rpartition(';') if ';' in fmt else ('', '', fmt)
    tokens = rest.split()
    lowered = [t.lower() for t in tokens]
    if 'compresseddepth' in lowered:
        raise ImageEncodingError(
            f'compressed image format {fmt!r}: compressedDepth (depth images) is not '
            'supported; expected JPEG or PNG of an 8-bit image')
    codec = None
    if lowered:
        codec = {'jpeg': 'jpeg', 'jpg': 'jpeg', 'png': 'png'}.get(lowered[0])
        if codec is None:
            raise ImageEncodingError(
                f'compressed image format {fmt!r}: unsupported codec {tokens[0]!r}; '
                'expected jpeg or png')
    transport = tokens[2] if len(tokens) >= 3 and lowered[1] == 'compressed' else None
    return original.strip() or None, codec, transport


def parse_compressed_format(fmt):
    """``(original encoding, codec, transport encoding)`` of a sensor_msgs/CompressedImage
    format string in image_transport's ``compressed`` convention: ``'<encoding>; jpeg
    compressed <encoding>'``, ``'<encoding>; png compressed <encoding>'`` or the legacy
    ``'jpeg'`` / ``'png'``; parts that are absent are None (an empty format: the codec is
    read from the payload). Raises ImageEncodingError for other codecs, compressedDepth
    and original encodings that are not 8-bit images (image_encodings.EIGHT_BIT_ENCODINGS)."""
    original, codec, transport = _parse_format(fmt)
    for enc in (original, transport):
        if enc is not None and enc not in _ENCODINGS:
            raise ImageEncodingError(
                f'compressed image format {fmt!r}: unsupported image encoding {enc!r}; '
                f"supported: {', '.join(_ENCODINGS)}")
    return original, codec, transport


_MAGIC = {'jpeg': b'\xff\xd8', 'png': b'\x89PNG'}


def compressed_image_to_gray(fmt, data) -> np.ndarray:
    """A (height, width) uint8 grey image from a CompressedImage's format and data.

    JPEG and PNG, decoded with ``cv2.imdecode`` straight to grey, except when the payload
    holds RGB-ordered channels (transport encoding rgb8 / rgba8), which are decoded in
    colour and converted as RGB. Raises ImageEncodingError for an unsupported format and
    ImageDecodeError for a payload that does not decode."""
    _, codec, transport = parse_compressed_format(fmt)
    try:
        buf = np.frombuffer(memoryview(data), dtype=np.uint8)
    except TypeError:
        buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if buf.size == 0:
        raise ImageDecodeError(f'empty compressed image payload (format {fmt!r})')
    if codec is not None and not buf[:len(_MAGIC[codec])].tobytes() == _MAGIC[codec]:
        raise ImageDecodeError(
            f'compressed image payload of {buf.size} bytes is not {codec.upper()} data '
            f'(format {fmt!r})')
    rgb_order = transport in ('rgb8', 'rgba8')
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR if rgb_order else cv2.IMREAD_GRAYSCALE)
    except cv2.error as error:
        raise ImageDecodeError(f'compressed image payload of {buf.size} bytes does not '
                               f'decode (format {fmt!r}): {error.msg.strip()}') from None
    if img is None or img.size == 0:
        raise ImageDecodeError(f'compressed image payload of {buf.size} bytes is corrupt or '
                               f'truncated (format {fmt!r})')
    if rgb_order:
        # IMREAD_COLOR returns the payload's channels as stored, read as BGR.
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img


def compressed_msg_to_gray(msg) -> np.ndarray:
    """``compressed_image_to_gray`` of anything with sensor_msgs/CompressedImage's fields."""
    return compressed_image_to_gray(msg.format, msg.data)


def dictionary_id(name) -> int:
    """OpenCV id of a predefined ArUco dictionary given by name (e.g. 'DICT_4X4_50') or by
    its OpenCV id; anything else raises ValueError listing the valid names."""
    if isinstance(name, str) and name in DICTIONARY_NAMES:
        return int(getattr(cv2.aruco, name))
    if isinstance(name, (int, np.integer)) and not isinstance(name, bool) \
            and int(name) in _DICTIONARY_BY_ID:
        return int(name)
    raise ValueError(f"unknown ArUco dictionary {name!r}; expected one of "
                     f"{', '.join(DICTIONARY_NAMES)} (or its cv2.aruco id)")


def dictionary_name(name_or_id) -> str:
    """The name of a predefined ArUco dictionary given by name or OpenCV id."""
    did = dictionary_id(name_or_id)
    return name_or_id if isinstance(name_or_id, str) else _DICTIONARY_BY_ID[did]


def marker_object_points(marker_size: float) -> np.ndarray:
    """SOLVEPNP_IPPE_SQUARE's documented object points = ArUco corner order (4, 3)."""
    h = 0.5 * float(marker_size)
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass
class Detection:
    """One tag: pose of its centre (z out of the face) in `frame`, with covariance."""

    tag_id: int
    corners: np.ndarray            # (4, 2) px, ArUco order
    pose: np.ndarray               # (4, 4) tag -> frame
    covariance: np.ndarray         # (6, 6) x y z rx ry rz, axes of `frame`
    reprojection_error: float      # RMS, px
    confidence: float
    side_px: float                 # apparent side (sqrt of the image area), px
    marker_size: float             # m
    frame: str = 'camera'
    ambiguity: float = 0.0         # best / second-best IPPE reprojection error (0..1)
    solver: str = 'ippe_square'    # PnP method whose pose is used (module docstring)
    # Index into DetectionResult.cubes when `pose` is the one its cube's rigid fit implies
    # (solver 'rigid_cube'); -1 when `pose` is the tag's own.
    cube: int = -1
    # The tag's own (single-tag) pose, covariance and RMS error when `pose` is the rigid
    # cube's; None otherwise (then `pose` is the tag's own: see `single_tag_pose`).
    single_pose: np.ndarray = field(default=None, repr=False)
    single_covariance: np.ndarray = field(default=None, repr=False)
    single_reprojection_error: float = None
    # (k, 4, 4) single-tag pose solutions, best first (IPPE's two, or the fallback's).
    candidates: np.ndarray = field(default=None, repr=False)
    # How the tag was first found: 'aruco' (ArUco or the second pass) or 'face_search';
    # a tag found again by TagDetector.track keeps it.
    source: str = 'aruco'

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3]

    @property
    def single_tag_pose(self) -> np.ndarray:
        """The tag's own pose (from its four corners alone), whatever `pose` is."""
        return self.pose if self.single_pose is None else self.single_pose

    @property
    def single_tag_covariance(self) -> np.ndarray:
        return self.covariance if self.single_covariance is None else self.single_covariance

    @property
    def normal(self) -> np.ndarray:
        return self.pose[:3, 2]

    def transformed(self, transform, frame: str) -> "Detection":
        """This detection expressed in another frame; `transform` maps camera -> frame."""
        transform = np.asarray(transform, dtype=np.float64)
        rot = transform[:3, :3]
        return replace(
            self, pose=transform @ self.pose,
            covariance=transform_covariance(self.covariance, rot), frame=frame,
            single_pose=None if self.single_pose is None else transform @ self.single_pose,
            single_covariance=None if self.single_covariance is None
            else transform_covariance(self.single_covariance, rot),
            candidates=None if self.candidates is None else transform[None] @ self.candidates)


@dataclass
class DroppedDetection:
    tag_id: int                    # -1 when the marker was never identified
    reason: str
    corners: np.ndarray = field(default=None, repr=False)


@dataclass
class DetectionResult:
    detections: list
    dropped: list
    second_pass: int = 0           # detections recovered from rejected candidates
    cubes: list = field(default_factory=list)   # rigid_cube.CubePose, >= 2 tags each
    roi: list = None               # [(x0, y0, x1, y1) px] searched; None: the whole image
    face_search: int = 0           # detections found on the found tags' cube faces
    tracked: int = 0               # detections found again where they were (TagDetector.track)

    def in_frame(self, transform, frame: str) -> "DetectionResult":
        return replace(self, detections=[d.transformed(transform, frame)
                                         for d in self.detections],
                       dropped=list(self.dropped),
                       cubes=[c.transformed(transform, frame) for c in self.cubes])


def _inside_any(points, quads) -> np.ndarray:
    """Whether each point (P, 2) lies inside any convex quad (Q, 4, 2) (either winding)."""
    a = quads[None, :, :, :]                                   # (1, Q, 4, 2)
    b = quads[None, :, [1, 2, 3, 0], :]
    p = points[:, None, None, :]                               # (P, 1, 1, 2)
    cross = (b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) \
        - (b[..., 1] - a[..., 1]) * (p[..., 0] - a[..., 0])    # (P, Q, 4)
    inside = (cross >= 0).all(axis=2) | (cross <= 0).all(axis=2)
    return inside.any(axis=1)


def _normal_angle(rotation, rvec) -> float:
    """Angle (rad) between the face normal of `rotation` and that of rotation vector `rvec`."""
    other, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
    return float(np.arccos(np.clip(rotation[:, 2] @ other[:, 2], -1.0, 1.0)))


def transform_covariance(covariance, rotation) -> np.ndarray:
    """Rotate a 6 x 6 (position, rotation-vector) covariance by `rotation` (3 x 3)."""
    big = np.zeros((6, 6))
    big[:3, :3] = big[3:, 3:] = rotation
    return big @ covariance @ big.T


def pose_covariance(rotation, translation, side_px, rms_px, focal_px, corner_sigma_px,
                    ambiguity_angle=0.0) -> np.ndarray:
    """The 6 x 6 covariance model of the module docstring, in the camera frame."""
    t = np.asarray(translation, dtype=np.float64)
    rng = float(np.linalg.norm(t))
    ray = t / max(rng, 1e-9)
    side = max(float(side_px), 1.0)
    sigma = float(np.sqrt(corner_sigma_px ** 2 + (SMALL_TAG_PX2 / side ** 2) ** 2 + rms_px ** 2))
    s_lat = max(rng * sigma / (2.0 * focal_px), _POSITION_FLOOR)
    s_rng = max(rng * sigma / side, _POSITION_FLOOR)
    pos = s_lat ** 2 * (np.eye(3) - np.outer(ray, ray)) + s_rng ** 2 * np.outer(ray, ray)
    s_tilt = min(np.hypot(sigma * focal_px / side ** 2, 0.5 * ambiguity_angle), np.pi / 2)
    s_tilt = max(s_tilt, _ROTATION_FLOOR)
    s_roll = max(sigma / side, _ROTATION_FLOOR)
    rot_tag = np.diag([s_tilt ** 2, s_tilt ** 2, s_roll ** 2])
    cov = np.zeros((6, 6))
    cov[:3, :3] = pos
    cov[3:, 3:] = rotation @ rot_tag @ rotation.T
    return cov


def clip_regions(roi, shape):
    """`roi` (one (x0, y0, x1, y1) px box or a sequence of them) as a list of int boxes
    clipped to an image of `shape` (rows, cols), overlapping boxes merged into their
    bounding box (so no pixel is searched twice); None for None or when a box covers the
    whole image. Raises ValueError for boxes that are not four finite numbers or when no
    box has a pixel in the image."""
    if roi is None:
        return None
    h, w = int(shape[0]), int(shape[1])
    try:
        arr = np.asarray(roi, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or not (arr.shape == (4,) or (arr.ndim == 2 and arr.shape[1] == 4)):
        raise ValueError(f'roi must be (x0, y0, x1, y1) px or a list of them, got {roi!r}')
    if not np.isfinite(arr).all():
        raise ValueError(f'roi must be finite, got {roi!r}')
    lo = np.clip(np.floor(arr.reshape(-1, 4)[:, :2]), 0, (w, h)).astype(int)
    hi = np.clip(np.ceil(arr.reshape(-1, 4)[:, 2:]), 0, (w, h)).astype(int)
    boxes = [(int(a[0]), int(a[1]), int(b[0]), int(b[1])) for a, b in zip(lo, hi)
             if b[0] > a[0] and b[1] > a[1]]
    if not boxes:
        raise ValueError(f'roi {roi!r} has no pixel in the {w}x{h} image')
    merged = True
    while merged:                        # union of overlapping boxes until none overlap
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]),
                                max(a[3], b[3]))
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    if any(box == (0, 0, w, h) for box in boxes):
        return None
    return sorted(boxes)


def search_region(detections, shape, margin=1.5, min_margin_px=24.0):
    """The regions (list of (x0, y0, x1, y1) px) to search next frame for the tags of
    `detections`: each tag's corner bounding box grown by `margin` times its larger side
    plus `min_margin_px` on each side (room for its cube's other faces, ~1.25 tag sides
    away, and for motion), clipped to an image of `shape`, overlapping ones merged
    (``clip_regions``); None when there is no detection (search it all)."""
    boxes = []
    for det in detections:
        pts = np.asarray(det.corners, dtype=np.float64).reshape(-1, 2)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        grow = float(margin) * float((hi - lo).max()) + float(min_margin_px)
        boxes.append((lo[0] - grow, lo[1] - grow, hi[0] + grow, hi[1] + grow))
    return clip_regions(boxes, shape) if boxes else None


# How RegionSearch searched a frame: ArUco on the whole image, ArUco in the region around
# the last tags, or the last tags followed (TagDetector.track).
SEARCH_KINDS = ('whole image', 'region', 'tracked')


class RegionSearch:
    """Search where the tags were. Every `full_frame_every`-th frame (the first one
    included), after a frame with no detection and after the detector changed (a new
    camera), ArUco searches the whole image. On the frames between, with `track` on,
    the last frame's tags are first looked for where they were (``TagDetector.track``:
    no ArUco pass, a fraction of its cost on a still or slowly moving camera); when
    every one of them is found again (those the face search found last frame: or lost
    to it again) that is the frame's result, otherwise (or with `track` off) ArUco
    searches ``search_region`` of the last frame's detections.
    `full_frame_every` 1: always the whole image. A tag that comes into view away from
    the found tags' cubes waits for the next full-frame pass.

    >>> search = RegionSearch(full_frame_every=5)
    >>> result = search.detect(detector, gray)     # DetectionResult; result.roi: searched
    """

    def __init__(self, full_frame_every: int = 5, margin: float = 1.5,
                 min_margin_px: float = 24.0, track: bool = True):
        if int(full_frame_every) < 1:
            raise ValueError(f'full_frame_every must be >= 1, got {full_frame_every}')
        if not (np.isfinite(margin) and margin >= 0 and np.isfinite(min_margin_px)
                and min_margin_px >= 0):
            raise ValueError(f'margin and min_margin_px must be >= 0, got {margin}, '
                             f'{min_margin_px}')
        self.full_frame_every = int(full_frame_every)
        self.margin, self.min_margin_px = float(margin), float(min_margin_px)
        self.track = bool(track)
        # Frames since construction by how they were searched (SEARCH_KINDS).
        self.frames = dict.fromkeys(SEARCH_KINDS, 0)
        self.reset()

    def reset(self):
        """Search the whole image next frame."""
        self._region, self._since_full, self._detector = None, 0, None
        self._previous, self._gray = [], None

    def detect(self, detector, gray) -> DetectionResult:
        """``detector.detect`` of `gray` in the region (or the whole image) due, or the
        last frame's tags found again (``detector.track``)."""
        if detector is not self._detector or (
                self._gray is not None and np.shape(gray) != self._gray.shape):
            self.reset()                 # a new camera, or a new image size
            self._detector = detector
        due = self._region is None or self._since_full >= self.full_frame_every - 1
        result = None
        if not due and self.track and self._previous:
            tracked, lost = detector.track(gray, self._previous, roi=self._region,
                                           previous_gray=self._gray)
            # A lost face-search tag was looked for again by track's own face search,
            # as ArUco's pass in the region would; a lost ArUco tag needs that pass.
            if all(det.source == 'face_search' for det in lost):
                result = tracked
        if result is None:
            result = detector.detect(gray, roi=None if due else self._region)
            kind = 'whole image' if result.roi is None else 'region'
        else:
            kind = 'tracked'
        self.frames[kind] += 1
        self._since_full = 0 if result.roi is None else self._since_full + 1
        self._previous = list(result.detections)
        # A copy: the caller may reuse its image buffer.
        self._gray = np.array(gray, dtype=np.uint8) if self.track else None
        self._region = search_region(result.detections, np.shape(gray), self.margin,
                                     self.min_margin_px)
        return result


def _scaled_detect(aruco, gray, scale: float):
    """``aruco.detectMarkers`` on `gray` resized by `scale` (INTER_AREA; 1: as is), the
    corners of accepted markers and rejected contours mapped back to `gray`'s pixels
    (pixel centres: x_full = (x_scaled + 0.5) * cols / scaled cols - 0.5)."""
    if scale == 1.0:
        return aruco.detectMarkers(gray)
    rows, cols = gray.shape
    w, h = max(1, int(round(cols * scale))), max(1, int(round(rows * scale)))
    c, i, r = aruco.detectMarkers(cv2.resize(gray, (w, h), interpolation=cv2.INTER_AREA))
    factor = np.array([cols / w, rows / h], dtype=np.float32)
    back = [(q + np.float32(0.5)) * factor - np.float32(0.5) for q in (c or ())]
    return back, i, [(q + np.float32(0.5)) * factor - np.float32(0.5) for q in (r or ())]


class TagDetector:
    """ArUco detection + IPPE_SQUARE poses with covariances, in the camera optical frame.

    >>> det = TagDetector(K, dist_coeffs=None, dictionary="DICT_4X4_50", marker_size=0.08)
    >>> result = det.detect(gray)            # DetectionResult
    >>> in_base = result.in_frame(T_base_camera, "base_link")
    """

    def __init__(self, camera_matrix, dist_coeffs=None, dictionary='DICT_4X4_50',
                 marker_size: float = 0.08, refine_corners: bool = True,
                 second_pass: bool = True, corner_sigma_px: float = 0.08,
                 max_reprojection_error: float = 2.0, min_side_px: float = 6.0,
                 ambiguity_ratio: float = 0.7, camera_frame: str = 'camera',
                 image_size=None, cube_size: float | None = 0.10, face_search: bool = True,
                 blur_decode: bool = True):
        if not (np.isfinite(marker_size) and marker_size > 0):
            raise ValueError(f'marker_size must be > 0 m, got {marker_size}')
        if not (np.isfinite(corner_sigma_px) and corner_sigma_px > 0):
            raise ValueError(f'corner_sigma_px must be > 0, got {corner_sigma_px}')
        if not max_reprojection_error > 0:
            raise ValueError(f'max_reprojection_error must be > 0 px, got '
                             f'{max_reprojection_error}')
        self.dictionary_name = dictionary_name(dictionary)
        self.dictionary = cv2.aruco.getPredefinedDictionary(dictionary_id(dictionary))
        self.marker_size = float(marker_size)
        self.refine_corners = bool(refine_corners)
        self.second_pass = bool(second_pass)
        self.corner_sigma_px = float(corner_sigma_px)
        self.max_reprojection_error = float(max_reprojection_error)
        self.min_side_px = float(min_side_px)
        self.ambiguity_ratio = float(ambiguity_ratio)
        self.camera_frame = camera_frame
        if cube_size is not None and not (np.isfinite(cube_size) and cube_size >= 0):
            raise ValueError(f'cube_size must be >= 0 m (0 or None: no rigid cube fit), '
                             f'got {cube_size}')
        if cube_size and cube_size <= marker_size:
            raise ValueError(f'cube_size {cube_size} m must exceed marker_size '
                             f'{marker_size} m (a tag is centred on a cube face)')
        self.cube_size = float(cube_size) if cube_size else 0.0
        self.object_points = marker_object_points(self.marker_size)
        self.params = self.default_parameters(refine_corners=self.refine_corners)
        # One ArUco detector per threshold-window set (THRESHOLD_WINDOWS); `aruco` is the
        # first, kept for callers that set its parameters.
        self.arucos = [cv2.aruco.ArucoDetector(self.dictionary, params)
                       for params in self.window_parameters(self.params)]
        self.aruco_scales = [float(w[3]) for w in THRESHOLD_WINDOWS]
        self.aruco = self.arucos[0]
        # Face search (module face_search): needs the cube geometry.
        self.face_search = bool(face_search) and self.cube_size > 0
        self.blur_decode = bool(blur_decode)
        self.screen_candidates = True
        self.set_camera(camera_matrix, dist_coeffs, image_size)

    @staticmethod
    def default_parameters(refine_corners: bool = True) -> "cv2.aruco.DetectorParameters":
        """ArUco parameters: defaults except for finer bit sampling of small, blurred tags
        and less candidate grouping (below). The base of every detectMarkers call:
        `window_parameters` sets each call's threshold windows (THRESHOLD_WINDOWS).

        Corner refinement is our own edge fit (refine_corners) or SUBPIX without it.
        """
        p = cv2.aruco.DetectorParameters()
        p.cornerRefinementMethod = (cv2.aruco.CORNER_REFINE_NONE if refine_corners
                                    else cv2.aruco.CORNER_REFINE_SUBPIX)
        p.perspectiveRemovePixelPerCell = 8
        p.perspectiveRemoveIgnoredMarginPerCell = 0.3
        # Threshold windows of one call over 3-33 px (default 3, 13, 23) for callers that
        # use these parameters alone; `detect` replaces them per call (THRESHOLD_WINDOWS).
        p.adaptiveThreshWinSizeMin = 3
        p.adaptiveThreshWinSizeMax = 33
        p.adaptiveThreshWinSizeStep = 10
        # Keep a marker's own contour apart from its white quiet zone's outer contour:
        # grouped (default 0.125), the outer one may win and then be dropped at the
        # image border, losing the marker.
        p.minMarkerDistanceRate = 0.05
        return p

    @staticmethod
    def window_parameters(base) -> list:
        """Copies of `base`, one per THRESHOLD_WINDOWS set (windows min, max, step px and
        the minimum marker perimeter rate where it is set)."""
        out = []
        for lo, hi, step, _, min_perimeter in THRESHOLD_WINDOWS:
            p = copy_parameters(base)
            p.adaptiveThreshWinSizeMin, p.adaptiveThreshWinSizeMax = lo, hi
            p.adaptiveThreshWinSizeStep = step
            if min_perimeter is not None:
                p.minMarkerPerimeterRate = float(min_perimeter)
            out.append(p)
        return out

    def _detect_markers(self, gray):
        """ArUco with each threshold-window set (on the image scaled as THRESHOLD_WINDOWS
        says): accepted markers (corners list, ids list; one per id and place), rejected
        contours (list), in full-image pixels."""
        corners, ids, rejected = [], [], []
        for aruco, scale in zip(self.arucos, self.aruco_scales):
            c, i, r = _scaled_detect(aruco, gray, scale)
            for quad, tag_id in zip(c, [] if i is None else i.ravel()):
                centre = quad.reshape(4, 2).mean(axis=0)
                if any(int(tag_id) == k and np.abs(centre - q.reshape(4, 2).mean(axis=0)).max()
                       < DUPLICATE_PX for q, k in zip(corners, ids)):
                    continue                    # the same marker found by another set
                corners.append(quad)
                ids.append(int(tag_id))
            rejected += [] if r is None else list(r)
        return corners, ids, rejected

    def set_camera(self, camera_matrix, dist_coeffs=None, image_size=None):
        """Intrinsics (3 x 3 K; distortion coefficients in OpenCV order or None) and the
        (width, height) of the images they are for (None: not checked by `detect`)."""
        k = np.asarray(camera_matrix, dtype=np.float64)
        if k.size != 9:
            raise ValueError(f'camera matrix must be 3 x 3, got shape {k.shape}')
        k = k.reshape(3, 3)
        if not (np.isfinite(k).all() and k[0, 0] > 0 and k[1, 1] > 0):
            raise ValueError('camera matrix must be finite with positive focal lengths')
        d = None if dist_coeffs is None else np.asarray(dist_coeffs, np.float64).reshape(-1)
        if d is not None and (d.size == 0 or not np.any(d)):
            d = None
        if d is not None and (d.size not in (4, 5, 8, 12, 14) or not np.isfinite(d).all()):
            raise ValueError(f'distortion needs 4, 5, 8, 12 or 14 finite coefficients, '
                             f'got {d.size}')
        if image_size is not None:
            size = tuple(image_size)
            if len(size) != 2 or not all(isinstance(v, (int, np.integer)) and v > 0
                                         for v in size):
                raise ValueError(f'image_size must be (width, height) in px > 0, got '
                                 f'{image_size!r}')
            image_size = (int(size[0]), int(size[1]))
        self.camera_matrix = k
        self.dist_coeffs = d
        self.image_size = image_size
        self.focal_px = 0.5 * (k[0, 0] + k[1, 1])

    # -- detection ------------------------------------------------------------------------
    def detect(self, gray, roi=None) -> DetectionResult:
        """Detect tags in a grey uint8 image; poses in the camera optical frame.

        `roi` (x0, y0, x1, y1) px or a list of such boxes, e.g. ``search_region`` of the
        last detections: ArUco searches only those parts of the image (``clip_regions``;
        clutter elsewhere costs nothing); corners, decoding and poses use the whole image,
        so results are in full-image pixels. None: the whole image. ``RegionSearch``
        tracks the region from frame to frame with a full-frame pass at a lower rate.

        Raises ValueError (ImageSizeError for a size other than `image_size`) for input
        that is not a non-empty 2-D uint8 image of the camera's size, or an roi that is
        not four numbers or has no pixel in the image."""
        gray = self.check_image(gray)
        roi = clip_regions(roi, gray.shape)
        if roi is None:
            corners, tag_ids, rejected = self._detect_markers(gray)
        else:
            corners, tag_ids, rejected = [], [], []
            for x0, y0, x1, y1 in roi:
                c, i, r = self._detect_markers(np.ascontiguousarray(gray[y0:y1, x0:x1]))
                offset = np.array([x0, y0], dtype=np.float32)
                corners += [q + offset for q in c]
                tag_ids += i
                rejected += [q + offset for q in r]
        quads = np.array([c.reshape(4, 2) for c in corners], dtype=np.float64).reshape(-1, 4, 2)
        cand = np.zeros((0, 4, 2))
        if self.second_pass and rejected is not None and len(rejected):
            cand = self._candidates(gray, rejected, quads)
        if self.refine_corners and (len(tag_ids) or len(cand)):
            # One batch for the accepted markers and the second-pass candidates.
            refined, ok = refine_quads(gray, np.concatenate([quads, cand]))
            quads = refined[:len(tag_ids)]
            # Where the edge fit fails (blurred edges), the contour corners themselves
            # are decoded (refine_quads keeps them): on the realistic suite they read
            # blurred tags the fit loses.
            cand = refined[len(tag_ids):]
        recovered = 0
        if len(cand):
            extra_quads, extra_ids = self._decode_candidates(gray, cand)
            recovered = len(extra_ids)
            if recovered:
                quads = np.concatenate([quads, extra_quads])
                tag_ids += extra_ids
        detections, dropped, on_faces, cubes = self._finish(
            gray, [(tag_id, quad, 'aruco') for tag_id, quad in zip(tag_ids, quads)])
        return DetectionResult(detections, dropped, recovered, cubes, roi, len(on_faces))

    def track(self, gray, previous, roi=None, previous_gray=None):
        """Find the tags of `previous` (the last frame's detections) again where they were,
        without an ArUco pass: their corners moved by optical flow from `previous_gray`
        (the last frame, when given: ``cv2.calcOpticalFlowPyrLK``), refined on `gray` by
        the edge fit and decoded by bits or else by blurred-code correlation; a tag
        counts as found again only under its own id. Then the face search and the
        rigid-cube fit, as in ``detect``. Returns (DetectionResult, the detections of
        `previous` whose id is found again by neither); the result's `roi` is `roi` (what
        the caller would have searched) and `tracked` counts the tags found again at
        their old places.

        Raises ValueError as ``detect`` does for an image it refuses (`previous_gray`
        too)."""
        gray = self.check_image(gray)
        previous = list(previous)
        if not previous:
            return DetectionResult([], [], roi=roi), []
        ids = [int(d.tag_id) for d in previous]
        quads = np.array([np.asarray(d.corners, dtype=np.float64).reshape(4, 2)
                          for d in previous])
        if previous_gray is not None:
            previous_gray = self.check_image(previous_gray)
            if previous_gray.shape != gray.shape:
                raise ImageSizeError(
                    f'previous_gray is {previous_gray.shape[1]}x{previous_gray.shape[0]} px, '
                    f'the image {gray.shape[1]}x{gray.shape[0]} px: the flow needs one size')
            quads = self._flow(previous_gray, gray, quads)
        refined, ok = refine_quads(gray, quads)
        found = {}
        for k, res in enumerate(decode_quads(gray, refined, self.dictionary)):
            if ok[k] and res is not None and res[0] == ids[k]:
                found[k] = np.roll(refined[k], res[1], axis=0)
        unread = [k for k in range(len(ids)) if k not in found]
        if self.blur_decode and unread:
            # ArUco order is clockwise on screen, as decode_blurred wants it.
            for k, res in zip(unread, decode_blurred(gray, refined[unread], self.dictionary)):
                if res is not None and res[0] == ids[k]:
                    found[k] = np.roll(refined[k], res[1], axis=0)
        # The face search also finds faces that came into view next to the tags (a cube
        # turned by an action) and last frame's face-search tags, from their neighbours.
        detections, dropped, on_faces, cubes = self._finish(
            gray, [(ids[k], found[k], previous[k].source) for k in sorted(found)])
        tracked = len(detections) - len(on_faces)
        unclaimed = collections.Counter(d.tag_id for d in detections)
        lost = []
        for det in previous:
            if unclaimed[det.tag_id] > 0:
                unclaimed[det.tag_id] -= 1
            else:
                lost.append(det)
        return DetectionResult(detections, dropped, 0, cubes, roi, len(on_faces),
                               tracked), lost

    def _finish(self, gray, read):
        """How ``detect`` and ``track`` end: poses of the tags read [(tag_id, quad,
        source)] (steps 4-5; those dropped apart), the face search from them and the
        rigid-cube fit. Returns (detections, dropped, the face search's share of
        detections, cubes)."""
        detections, dropped = [], []
        for tag_id, quad, source in read:
            det = self._pose(tag_id, quad, source)
            (dropped if isinstance(det, DroppedDetection) else detections).append(det)
        on_faces = self._search_faces(gray, detections) if self.face_search else []
        detections += on_faces
        cubes = self._rigid_cubes(detections) if self.cube_size else []
        return detections, dropped, on_faces, cubes

    @staticmethod
    def _flow(before, after, quads):
        """`quads` (Q, 4, 2) of image `before` moved to image `after` by pyramidal
        Lucas-Kanade flow of their corners; a quad keeps its corners where the flow of
        one of them failed or moved them apart (by over a third of the quad's side)."""
        pts = quads.reshape(-1, 1, 2).astype(np.float32)
        moved, status, _ = cv2.calcOpticalFlowPyrLK(
            before, after, pts, None, winSize=(15, 15), maxLevel=2,
            criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
        if moved is None:
            return quads
        moved = moved.reshape(-1, 4, 2).astype(np.float64)
        shift = moved - quads
        spread = np.linalg.norm(shift - shift.mean(axis=1, keepdims=True), axis=2).max(axis=1)
        good = status.reshape(-1, 4).all(axis=1) & np.isfinite(moved).all(axis=(1, 2)) \
            & (spread < np.sqrt(np.abs(quad_areas(quads))) / 3.0)
        out = quads.copy()
        out[good] = moved[good]
        return out

    def _search_faces(self, gray, detections):
        """Detections on the cube faces next to found tags that should show a tag and hold
        none found (``face_search.adjacent_face_boxes`` from both IPPE poses of each tag):
        the predicted marker quads themselves, decoded (``_decode_predicted``); then once
        more from the tags this found (a cube's third face)."""
        found, seeds = [], list(detections)
        for _ in range(FACE_SEARCH_ROUNDS):
            if not seeds:
                break
            boxes, quads = self._face_boxes(gray, seeds, detections + found)
            if not len(boxes):
                break
            seeds = self._decode_predicted(gray, quads, detections + found)
            found += seeds
        return found

    def _face_boxes(self, gray, seeds, detections):
        # The mirrored IPPE pose too where it is nearly as good (it puts the faces elsewhere).
        boxes, quads = adjacent_face_boxes(
            np.concatenate([d.candidates if d.ambiguity > FACE_SEARCH_AMBIGUITY
                            else d.candidates[:1] for d in seeds]),
            np.array([d.pose[:3, 3] for d in detections]), self.camera_matrix,
            self.dist_coeffs, self.cube_size, self.marker_size, gray.shape, with_quads=True)
        keep = boxes[:, 4] >= self.min_side_px
        return boxes[keep], quads[keep]

    def _decode_predicted(self, gray, quads, detections):
        """Detections at predicted marker quads (K, 4, 2): those dark inside against their
        quiet zone (``blur_decode.darkness``; no marker otherwise), one per place, refined
        and decoded by bits (``decode_quads``) or else, refined or as predicted, by
        correlation with blurred codes (``decode_blurred``)."""
        # Screen order: clockwise, as ArUco orders markers.
        quads = quads.copy()
        flip = quad_areas(quads) < 0
        quads[flip] = quads[flip][:, ::-1]
        cells = int(self.dictionary.markerSize) + 2
        dark = darkness(gray, quads, cells)
        keep = np.flatnonzero(dark >= MIN_DARKNESS)
        # One quad per place (the same face predicted from several tags or poses): the
        # darkest against its quiet zone, i.e. the best aligned with the marker.
        keep = keep[np.argsort(-dark[keep], kind='stable')]
        centres = quads.mean(axis=1)
        sides = np.sqrt(np.abs(quad_areas(quads)))
        chosen = []
        for k in keep:
            if all(np.linalg.norm(centres[k] - centres[j]) > 0.3 * sides[j] for j in chosen):
                chosen.append(k)
        if not chosen:
            return []
        quads = quads[chosen]
        refined, ok = refine_quads(gray, quads)
        res = decode_quads(gray, refined, self.dictionary)
        out = [(np.roll(refined[k], res[k][1], axis=0), res[k][0])
               for k in range(len(quads)) if ok[k] and res[k] is not None]
        left = [k for k in range(len(quads)) if not (ok[k] and res[k] is not None)]
        if self.blur_decode and left:
            tries = [refined[k] for k in left if ok[k]] + [quads[k] for k in left]
            owner = [k for k in left if ok[k]] + left
            done = set()
            for k, quad, r in zip(owner, tries, decode_blurred(gray, np.array(tries),
                                                               self.dictionary)):
                if r is not None and k not in done:
                    done.add(k)
                    out.append((np.roll(quad, r[1], axis=0), r[0]))
        known = np.array([d.corners for d in detections], dtype=np.float64)
        dets = []
        for quad, tag_id in out:
            centre = quad.mean(axis=0)[None]
            if _inside_any(centre, known)[0] or (
                    dets and _inside_any(centre, np.array([d.corners for d in dets]))[0]):
                continue
            det = self._pose(tag_id, quad, 'face_search')
            if not isinstance(det, DroppedDetection):
                dets.append(det)
        return dets

    def _rigid_cubes(self, detections):
        """Fit one rigid pose per cube of >= 2 tags (``rigid_cube``); its tags' `pose`
        becomes the one the cube implies, their own kept in `single_*`. In place."""
        cubes, rigid = fit_cubes(detections, [d.candidates for d in detections],
                                 self.camera_matrix, self.dist_coeffs, self.cube_size,
                                 self.object_points, self.max_reprojection_error,
                                 self.corner_sigma_px, SMALL_TAG_PX2)
        for i, (pose, cov, rms, k) in rigid.items():
            det = detections[i]
            detections[i] = replace(
                det, pose=pose, covariance=cov, reprojection_error=rms, cube=k,
                solver='rigid_cube', ambiguity=0.0, single_pose=det.pose,
                single_covariance=det.covariance,
                single_reprojection_error=det.reprojection_error)
        return cubes

    def check_image(self, gray) -> np.ndarray:
        """`gray` as a C-contiguous (height, width) uint8 array, or ValueError saying why
        not: empty, not 2-D (colour: convert it first), not uint8, or not `image_size`."""
        if not isinstance(gray, np.ndarray):
            try:
                gray = np.asarray(gray)
            except (TypeError, ValueError) as error:
                raise ValueError(f'expected a 2-D uint8 grey image, got {type(gray).__name__}'
                                 f' ({error})') from None
        if gray.ndim == 3 and gray.shape[2] == 1:
            gray = gray[:, :, 0]
        if gray.ndim == 3 and gray.shape[2] in (3, 4):
            raise ValueError(
                f'expected a 2-D uint8 grey image, got {gray.shape[2]} channels '
                f'{gray.shape} {gray.dtype}: convert it first (image_to_gray, or '
                f'cv2.cvtColor with COLOR_BGR2GRAY / COLOR_BGRA2GRAY)')
        if gray.ndim != 2:
            raise ValueError(f'expected a 2-D uint8 grey image, got a {gray.ndim}-D array '
                             f'{gray.shape} {gray.dtype}')
        if gray.size == 0:
            raise ValueError(f'empty image ({gray.shape[1]}x{gray.shape[0]} px)')
        if gray.dtype != np.uint8:
            raise ValueError(f'expected a 2-D uint8 grey image, got dtype {gray.dtype} '
                             f'{gray.shape}: scale to 0..255 and convert to uint8 first')
        check_image_size(gray.shape[1], gray.shape[0], self.image_size)
        return np.ascontiguousarray(gray)

    def _candidates(self, gray, rejected, accepted, limit=MAX_CANDIDATES):
        """Rejected contours worth a second look: large enough, not inside an accepted
        marker (its inner contours), marker-like (``CANDIDATE_MIN_CONTRAST``), one per
        place (``CANDIDATE_DUPLICATE``), at most `limit`, largest first."""
        cand = np.concatenate(rejected, axis=None).astype(np.float64).reshape(-1, 4, 2)
        area = np.abs(quad_areas(cand))
        keep = area >= self.min_side_px ** 2
        if accepted.shape[0] and keep.any():
            keep &= ~_inside_any(cand.mean(axis=1), accepted)
        idx = np.flatnonzero(keep)
        if idx.size and self.screen_candidates:
            frame, bits = marker_contrast(gray, cand[idx], int(self.dictionary.markerSize) + 2)
            idx = idx[(frame >= CANDIDATE_MIN_CONTRAST) & (bits >= CANDIDATE_MIN_CONTRAST)]
        idx = idx[np.argsort(-area[idx], kind='stable')]
        if idx.size > 1 and CANDIDATE_DUPLICATE > 0:
            # The same contour from several threshold windows: refined to the same edges,
            # so only the largest of those (centres within CANDIDATE_DUPLICATE of its side,
            # areas within 1.5x) is kept.
            c = cand[idx].mean(axis=1)
            a = area[idx]
            near = (np.linalg.norm(c[:, None] - c[None], axis=2)
                    < CANDIDATE_DUPLICATE * np.sqrt(a)[None]) & (a[None] < 1.5 * a[:, None])
            dup = np.zeros(idx.size, dtype=bool)
            for k in range(idx.size):
                if not dup[k]:
                    dup[k + 1:] |= near[k + 1:, k]
            idx = idx[~dup]
        idx = idx[:limit]
        return cand[idx]

    def _decode_candidates(self, gray, cand):
        # Screen order: clockwise, as ArUco orders markers.
        flip = quad_areas(cand) < 0
        cand = cand.copy()
        cand[flip] = cand[flip][:, ::-1]
        quads, found = [], []
        for quad, res in zip(cand, decode_quads(gray, cand, self.dictionary)):
            if res is None:
                continue
            if quads and _inside_any(quad.mean(axis=0)[None], np.array(quads))[0]:
                continue                                   # same marker, another contour
            quads.append(np.roll(quad, res[1], axis=0))
            found.append(res[0])
        return np.array(quads).reshape(-1, 4, 2), found

    def _pose(self, tag_id, quad, source='aruco'):
        if not np.isfinite(quad).all():
            return DroppedDetection(tag_id, 'non-finite corners', quad)
        area = float(quad_areas(quad[None])[0])
        side = float(np.sqrt(abs(area)))
        if side < self.min_side_px:
            return DroppedDetection(
                tag_id, f'degenerate quad: side {side:.1f} px < {self.min_side_px} px', quad)
        if area <= 0 or not cv2.isContourConvex(quad.astype(np.float32).reshape(-1, 1, 2)):
            return DroppedDetection(tag_id, 'non-convex or mirrored quad', quad)
        try:
            solutions = self._solve_pnp(quad, 'ippe_square', cv2.SOLVEPNP_IPPE_SQUARE)
        except cv2.error as error:
            return DroppedDetection(tag_id, f'solvePnP failed: {error.msg}', quad)
        ippe = solutions
        parallelogram = np.abs(quad[0] + quad[2] - quad[1] - quad[3]).max() < PARALLELOGRAM_PX
        if parallelogram or not ippe or ippe[0][0] > PNP_FALLBACK_PX or ippe[0][2][2] <= 0:
            # IPPE_SQUARE's (near) fronto-parallel failure (module docstring).
            for name, flag in _PNP_FALLBACKS:
                try:
                    solutions = solutions + self._solve_pnp(quad, name, flag)
                except cv2.error:
                    pass
            solutions.sort(key=lambda sol: sol[0])
        if not solutions:
            return DroppedDetection(tag_id, 'solvePnP found no pose', quad)
        rms, rvec, tvec, solver = solutions[0]
        if not (np.isfinite(rvec).all() and np.isfinite(tvec).all() and np.isfinite(rms)):
            return DroppedDetection(tag_id, 'non-finite pose', quad)
        if tvec[2] <= 0:
            return DroppedDetection(tag_id, 'pose behind the camera', quad)
        if rms > self.max_reprojection_error:
            return DroppedDetection(
                tag_id, f'reprojection error {rms:.2f} px > {self.max_reprojection_error} px',
                quad)
        rot, _ = cv2.Rodrigues(rvec)
        ambiguity, angle = 0.0, 0.0
        if solver == 'ippe_square':
            second = ippe[1] if len(ippe) > 1 else None
        else:
            # The best other pose: one whose face normal differs (the mirrored tilt).
            second = next((sol for sol in solutions[1:]
                           if _normal_angle(rot, sol[1]) > _ROTATION_FLOOR), None)
        if second is not None and np.isfinite(second[0]) and second[0] > 0:
            ambiguity = float(min(1.0, rms / second[0]))
            if ambiguity > self.ambiguity_ratio:
                angle = _normal_angle(rot, second[1])
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot, tvec
        cov = pose_covariance(rot, tvec, side, rms, self.focal_px, self.corner_sigma_px, angle)
        confidence = float(np.exp(-0.5 * rms ** 2) * min(1.0, side / _FULL_CONFIDENCE_SIDE_PX))
        cands = [pose]
        for sol in solutions[1:]:
            if np.isfinite(sol[1]).all() and np.isfinite(sol[2]).all() and sol[2][2] > 0 \
                    and _normal_angle(rot, sol[1]) > _ROTATION_FLOOR:
                other = np.eye(4)
                other[:3, :3], _ = cv2.Rodrigues(sol[1])
                other[:3, 3] = sol[2]
                cands.append(other)
                break
        return Detection(tag_id, quad.copy(), pose, cov, rms, confidence, side,
                         self.marker_size, self.camera_frame, ambiguity, solver,
                         candidates=np.array(cands), source=source)

    def _solve_pnp(self, quad, name, flag):
        """[(rms px, rvec, tvec, name)] of cv2.solvePnPGeneric with `flag`, finite ones,
        lowest error first."""
        n, rvecs, tvecs, errors = cv2.solvePnPGeneric(
            self.object_points, quad, self.camera_matrix, self.dist_coeffs, flags=flag)
        errors = np.asarray(errors, dtype=np.float64).reshape(-1)
        out = []
        for i in range(int(n)):
            rvec = np.asarray(rvecs[i], dtype=np.float64).reshape(3)
            tvec = np.asarray(tvecs[i], dtype=np.float64).reshape(3)
            if np.isfinite(errors[i]) and np.isfinite(rvec).all() and np.isfinite(tvec).all():
                out.append((float(errors[i]), rvec, tvec, name))
        out.sort(key=lambda sol: sol[0])
        return out
