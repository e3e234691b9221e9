"""ArUco tag detection with poses and covariances (plain NumPy + OpenCV, no rclpy).

Pipeline per grey image (``TagDetector.detect``):

1. ``cv2.aruco.ArucoDetector.detectMarkers`` with corner refinement off, threshold
   windows 3 px, 7 px (larger contours only) and 11, 19 px on the image scaled by 0.6
   (three calls, ``THRESHOLD_WINDOWS``) and bit sampling tuned for small, blurred tags
   (8 px per cell, 30 % cell margin ignored; see ``TagDetector.default_parameters``); on
   the whole image, or only on a region of it (``roi``: where the cube was,
   ``RegionSearch``, which searches the whole image every few frames). The 7 px window
   finds flat tags whose thin quiet zone the 3 and 13 px windows merge with the
   background (issue 16: 25 tags within 1.5 m). The scaled call sees the markers the
   first two found painted over (``paint_markers``): their contours would only be
   identified again, ~1.4 ms each for DICT_APRILTAG_36h11 in OpenCV 5 (54 of 73 ms on a
   320x240 photo of 30 tags).
2. Corners refined by edge-line fitting (``corners.refine_quads``; unbiased, unlike
   ``CORNER_REFINE_SUBPIX`` on L-shaped corners, see that module); on tags of 64 px and
   more, kept only where they sit on the marker's edges next to the corners no worse
   than the contour's corners (``corners.keep_better_corners``: straight lines through
   the curved edges of a large tag in a distorted photo move its corners inwards).
3. Second pass: candidates ArUco rejected are refined the same way and decoded again
   (``corners.decode_quads``, no error correction, black border and white quiet zone
   required; where the edge fit fails, at the contour corners). Far, foreshortened
   tags are often rejected only because their integer contour corners sample the bits
   badly. Only contours that look like a marker at their corners (frame and bits
   contrast, ``blur_decode.marker_contrast``, >= ``CANDIDATE_MIN_CONTRAST``), at most
   ``MAX_CANDIDATES`` (16), largest first, one per place (the same contour found by
   several threshold windows is refined once).
4. Pose of each tag by ``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE`` (SQPNP and
   ITERATIVE where IPPE fails), its covariance and confidence: the pose and covariance
   model of ``tag_pose`` (``TagPoseModel``, built from the detector's settings by
   ``TagDetector.pose_model``).
5. Degenerate or implausible detections are dropped with a reason
   (``DetectionResult.dropped``): among them an RMS reprojection error above the larger
   of ``max_reprojection_error`` px and ``max_reprojection_fraction`` of the tag's side,
   and, after refinement, a second report of one tag (the same id within half a side:
   ``tag_pose.unique_detections``; two threshold windows' contours of one tag).
   Face search (``face_search``, on when ``cube_size`` > 0): the cube faces next to each
   found tag that face the camera (within 75 deg) and hold no found tag are predicted
   from the tag's pose (``face_search.adjacent_face_boxes``; the mirrored IPPE pose too
   when ambiguity > ``FACE_SEARCH_AMBIGUITY``) down to their marker quads; quads dark
   inside against their quiet zone (``blur_decode.darkness``) are refined and decoded as
   in step 3 or, failing that, by correlation with every code blurred by a set of
   kernels (``blur_decode.decode_blurred``, ``blur_decode`` option), and get poses as in
   step 4; a second round predicts from the tags the first found
   (``DetectionResult.face_search`` counts them). It finds tags that motion blur and
   JPEG leave without any ArUco contour. The correlation's CPU time per frame (with
   tracking's) is bounded by ``face_search_budget_ms``: a quad is decoded only while its
   expected cost (``blur_decode.quad_seconds``: measured, ~4 ms for DICT_4X4_50, ~34 ms
   for DICT_APRILTAG_36h11) fits in what is left (``DetectionResult.decode_skipped``
   counts the others). The faces are predicted from the cube's geometry: ``cube_size``
   and ``marker_size`` (the tag-to-face ratio, 0.8 by default; set both for a cube
   printed otherwise).
6. Rigid cube (``cube_size`` > 0, default 0.10 m): tags whose centres are an adjacent-face
   distance apart are fitted as one rigid ARcube from all their corners, seeded by every
   IPPE solution of every tag (``rigid_cube``; it removes IPPE's mirrored-tilt flips).
   ``DetectionResult.cubes`` lists the cube poses; each of their tags gets the pose and
   covariance the cube implies (``solver`` 'rigid_cube', ``cube`` its index), and keeps
   its own pose in ``single_pose`` / ``single_covariance`` / ``single_reprojection_error``
   (``single_tag_pose`` gives the tag's own pose either way).

Tracking (``TagDetector.track``) and the region search between full-frame passes
(``RegionSearch``, ``search_region``, ``clip_regions``) live in ``region_search``.

Images: ``image_encodings`` converts ``sensor_msgs/Image`` and ``CompressedImage``
payloads to grey without cv_bridge (``image_to_gray``, ``compressed_image_to_gray``) and
holds the checks ``detect`` applies (``check_gray_image``, ``check_image_size``).

Refusals (``ValueError`` with both values named, never a ``cv2.error``): an unknown
dictionary name or id (the valid names listed), an image that is empty, not 2-D or not
uint8 (``TagDetector.detect``), and an image whose size differs from the camera's
``image_size`` given at construction (``ImageSizeError``: the scaled image of a 2x
resized camera would put every tag at twice its distance).

The names other modules import from here (images, poses, region search) are re-exported
from their modules.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from abp_description.robot_profile import load_profile

from .blur_decode import DecodeBudget, marker_contrast
from .corners import (
    decode_quads,
    inside_any_quad,
    keep_better_corners,
    quad_areas,
    refine_quads,
)
from .face_search import (
    FACE_SEARCH_AMBIGUITY,
    FACE_SEARCH_ROUNDS,
    copy_parameters,
    search_faces,
)
from .image_encodings import (
    SUPPORTED_ENCODINGS,
    ImageDecodeError,
    ImageEncodingError,
    ImageLayoutError,
    ImageSizeError,
    check_gray_image,
    check_image_size,
    compressed_image_to_gray,
    compressed_msg_to_gray,
    image_msg_to_gray,
    image_to_gray,
    parse_compressed_format,
)
from .region_search import (
    SEARCH_KINDS,
    RegionSearch,
    clip_regions,
    flow_quads,
    lost_tags,
    reread_quads,
    search_region,
)
from .rigid_cube import fit_cubes
from .tag_pose import (
    MAX_REPROJECTION_FRACTION,
    PARALLELOGRAM_PX,
    PNP_FALLBACK_PX,
    SMALL_TAG_PX2,
    Detection,
    DetectionResult,
    DroppedDetection,
    TagPoseModel,
    marker_object_points,
    pose_covariance,
    transform_covariance,
    unique_detections,
)

__all__ = [
    'ImageEncodingError', 'ImageDecodeError', 'ImageLayoutError', 'ImageSizeError', 'image_to_gray',
    'image_msg_to_gray', 'compressed_image_to_gray', 'compressed_msg_to_gray',
    'parse_compressed_format', 'check_image_size', 'SUPPORTED_ENCODINGS',
    'DICTIONARY_NAMES', 'dictionary_id', 'dictionary_name', 'marker_object_points', 'Detection',
    'DroppedDetection', 'DetectionResult', 'TagDetector', 'RegionSearch', 'search_region',
    'clip_regions', 'transform_covariance', 'pose_covariance', 'SEARCH_KINDS',
    'PARALLELOGRAM_PX', 'PNP_FALLBACK_PX', 'SMALL_TAG_PX2', 'FACE_SEARCH_AMBIGUITY',
    'FACE_SEARCH_ROUNDS',
]

DICTIONARY_NAMES = tuple(sorted(n for n in dir(cv2.aruco) if n.startswith('DICT_')))
# OpenCV id -> name; cv2.aruco.getPredefinedDictionary maps an unknown id to DICT_4X4_50
# without a word, so ids are checked against this table first.
_DICTIONARY_BY_ID = {}
for _name in DICTIONARY_NAMES:
    _DICTIONARY_BY_ID.setdefault(int(getattr(cv2.aruco, _name)), _name)
del _name

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
# CPU time (ms) per frame the blurred-code decoding (face search and tracking) may take:
# several quads of DICT_4X4_50 (~4 ms each); none of DICT_APRILTAG_36h11 (~34 ms each,
# expected ~38 ms before the first is measured: 0.35 s on a 320x240 photo unbudgeted).
FACE_SEARCH_BUDGET_MS = 30.0
# The scaled window set (THRESHOLD_WINDOWS) sees the image with the markers the full-size
# sets found painted over (``paint_markers``), each grown by this fraction of its size
# (0: not painted).
PAINT_FOUND_GROW = 0.12
# Accepted markers of two window sets with the same id and centres this close are one
# (before refinement, to refine it once); contours further apart that the edge fit moves
# onto the same tag are merged after it (``unique_detections`` in ``_finish``).
DUPLICATE_PX = 3.0


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


def paint_markers(gray, corners, grow=None):
    """A copy of `gray` with each marker quad of `corners` (grown by `grow` of its size
    about its centre, PAINT_FOUND_GROW by default: the contour's corners leave a pixel of
    the black border) filled with its quiet zone's brightness (90th percentile of its
    bounding box grown by half), so no contour is found there."""
    grow = PAINT_FOUND_GROW if grow is None else grow
    out = gray.copy()
    rows, cols = gray.shape
    for quad in corners:
        q = np.asarray(quad, dtype=np.float64).reshape(4, 2)
        centre = q.mean(axis=0)
        q = centre + (1.0 + grow) * (q - centre)
        lo, hi = q.min(axis=0), q.max(axis=0)
        pad = 0.5 * (hi - lo)
        x0, y0 = np.clip(np.floor(lo - pad), 0, (cols, rows)).astype(int)
        x1, y1 = np.clip(np.ceil(hi + pad), 0, (cols, rows)).astype(int)
        if x1 <= x0 or y1 <= y0:
            continue
        box = gray[y0:y1, x0:x1].ravel()
        k = int(0.9 * (box.size - 1))
        level = int(np.partition(box, k)[k])          # np.percentile: ~10x the cost
        cv2.fillConvexPoly(out, np.round(q).astype(np.int32), level)
    return out


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
                 max_reprojection_error: float = 2.0,
                 max_reprojection_fraction: float = MAX_REPROJECTION_FRACTION,
                 min_side_px: float = 6.0,
                 ambiguity_ratio: float = 0.7, camera_frame: str = '',
                 image_size=None, cube_size: float | None = 0.10, face_search: bool = True,
                 blur_decode: bool = True,
                 face_search_budget_ms: float = FACE_SEARCH_BUDGET_MS):
        if not (np.isfinite(marker_size) and marker_size > 0):
            raise ValueError(f'marker_size must be > 0 m, got {marker_size}')
        if not (np.isfinite(corner_sigma_px) and corner_sigma_px > 0):
            raise ValueError(f'corner_sigma_px must be > 0, got {corner_sigma_px}')
        if not max_reprojection_error > 0:
            raise ValueError(f'max_reprojection_error must be > 0 px, got '
                             f'{max_reprojection_error}')
        if not (np.isfinite(max_reprojection_fraction) and 0 <= max_reprojection_fraction < 1):
            raise ValueError(f'max_reprojection_fraction must be in [0, 1) of the tag side, '
                             f'got {max_reprojection_fraction}')
        self.dictionary_name = dictionary_name(dictionary)
        self.dictionary = cv2.aruco.getPredefinedDictionary(dictionary_id(dictionary))
        self.marker_size = float(marker_size)
        self.refine_corners = bool(refine_corners)
        self.second_pass = bool(second_pass)
        self.corner_sigma_px = float(corner_sigma_px)
        self.max_reprojection_error = float(max_reprojection_error)
        self.max_reprojection_fraction = float(max_reprojection_fraction)
        self.min_side_px = float(min_side_px)
        self.ambiguity_ratio = float(ambiguity_ratio)
        # '': the camera optical frame of the default robot profile (the uBot-6's).
        self.camera_frame = camera_frame or load_profile().frames.camera_optical
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
        if not (np.isfinite(face_search_budget_ms) and face_search_budget_ms >= 0):
            raise ValueError(f'face_search_budget_ms must be >= 0 ms, got '
                             f'{face_search_budget_ms}')
        self.face_search_budget_ms = float(face_search_budget_ms)
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
            seen = gray
            if scale != 1.0 and corners and PAINT_FOUND_GROW > 0:
                # The scaled windows look for large, dim tags; the markers already found
                # would only come back as contours ArUco tries to identify again (~1.4 ms
                # each for DICT_APRILTAG_36h11 in OpenCV 5: most of a small frame's cost).
                seen = paint_markers(gray, corners)
            c, i, r = _scaled_detect(aruco, seen, scale)
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
            unrefined = np.concatenate([quads, cand])
            refined, ok = refine_quads(gray, unrefined)
            # Kept only where they sit on the marker's edges at the corners no worse than
            # the contour's (curved edges of large tags: ``keep_better_corners``).
            refined, _ = keep_better_corners(gray, refined, unrefined)
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
        budget = self.decode_budget()
        detections, dropped, on_faces, cubes = self._finish(
            gray, [(tag_id, quad, 'aruco') for tag_id, quad in zip(tag_ids, quads)], budget)
        return DetectionResult(detections, dropped, recovered, cubes, roi, len(on_faces),
                               decode_skipped=budget.skipped)

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
            quads = flow_quads(previous_gray, gray, quads)
        budget = self.decode_budget()
        found = reread_quads(gray, quads, ids, self.dictionary, self.blur_decode, budget)
        # The face search also finds faces that came into view next to the tags (a cube
        # turned by an action) and last frame's face-search tags, from their neighbours.
        detections, dropped, on_faces, cubes = self._finish(
            gray, [(ids[k], found[k], previous[k].source) for k in sorted(found)], budget)
        tracked = len(detections) - len(on_faces)
        return DetectionResult(detections, dropped, 0, cubes, roi, len(on_faces),
                               tracked, budget.skipped), lost_tags(previous, detections)

    def decode_budget(self) -> DecodeBudget:
        """A new frame's budget for blurred-code decoding (``face_search_budget_ms``)."""
        return DecodeBudget(1e-3 * self.face_search_budget_ms)

    def _finish(self, gray, read, budget=None):
        """How ``detect`` and ``track`` end: poses of the tags read [(tag_id, quad,
        source)] (steps 4-5; those dropped apart), the face search from them and the
        rigid-cube fit. Returns (detections, dropped, the face search's share of
        detections, cubes)."""
        detections, dropped = [], []
        pose_model = self.pose_model()
        for tag_id, quad, source in read:
            det = pose_model.pose(tag_id, quad, source)
            (dropped if isinstance(det, DroppedDetection) else detections).append(det)
        # After refinement: two windows' contours of one tag refined onto its edges.
        detections, twins = unique_detections(detections)
        dropped += twins
        on_faces = search_faces(gray, detections, pose_model, self.dictionary, self.cube_size,
                                self.blur_decode, budget) if self.face_search else []
        detections += on_faces
        cubes = self._rigid_cubes(detections) if self.cube_size else []
        return detections, dropped, on_faces, cubes

    def _rigid_cubes(self, detections):
        """Fit one rigid pose per cube of >= 2 tags (``rigid_cube``); its tags' `pose`
        becomes the one the cube implies, their own kept in `single_*`. In place."""
        cubes, rigid = fit_cubes(detections, [d.candidates for d in detections],
                                 self.camera_matrix, self.dist_coeffs, self.cube_size,
                                 self.object_points, self.max_reprojection_error,
                                 self.corner_sigma_px, SMALL_TAG_PX2,
                                 self.max_reprojection_fraction)
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
        not: empty, not 2-D (colour: convert it first), not uint8, or not `image_size`
        (``image_encodings.check_gray_image``)."""
        return check_gray_image(gray, self.image_size)

    def _candidates(self, gray, rejected, accepted, limit=MAX_CANDIDATES):
        """Rejected contours worth a second look: large enough, not inside an accepted
        marker (its inner contours), marker-like (``CANDIDATE_MIN_CONTRAST``), one per
        place (``CANDIDATE_DUPLICATE``), at most `limit`, largest first."""
        cand = np.concatenate(rejected, axis=None).astype(np.float64).reshape(-1, 4, 2)
        area = np.abs(quad_areas(cand))
        keep = area >= self.min_side_px ** 2
        if accepted.shape[0] and keep.any():
            keep &= ~inside_any_quad(cand.mean(axis=1), accepted)
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
            if quads and inside_any_quad(quad.mean(axis=0)[None], np.array(quads))[0]:
                continue                                   # same marker, another contour
            quads.append(np.roll(quad, res[1], axis=0))
            found.append(res[0])
        return np.array(quads).reshape(-1, 4, 2), found

    def pose_model(self) -> TagPoseModel:
        """The pose and covariance model (``tag_pose``) of the detector's current camera,
        marker and limits."""
        return TagPoseModel(self.camera_matrix, self.dist_coeffs, self.focal_px,
                            self.marker_size, self.object_points, self.corner_sigma_px,
                            self.max_reprojection_error, self.min_side_px,
                            self.ambiguity_ratio, self.camera_frame,
                            self.max_reprojection_fraction)

    def _pose(self, tag_id, quad, source='aruco'):
        """``TagPoseModel.pose`` of one tag: a Detection or a DroppedDetection."""
        return self.pose_model().pose(tag_id, quad, source)
