"""One tag's pose and its covariance from its four image corners (plain NumPy + OpenCV, no
rclpy): the tag detector's pose and covariance model and the detection types it returns
(``detector`` finds and reads the tags, ``rigid_cube`` fits a cube's tags as one).

Pose of each tag by ``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE``: object
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

Degenerate or implausible detections are dropped with a reason (``DroppedDetection``),
among them poses whose RMS reprojection error exceeds ``reprojection_limit``: the larger
of ``max_reprojection_error`` (px) and ``max_reprojection_fraction`` of the tag's side (a
gate in pixels alone judges a 100 px tag like a 15 px one). ``unique_detections`` keeps
one report per physical tag.

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
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from .corners import quad_areas

__all__ = ['Detection', 'DroppedDetection', 'DetectionResult', 'TagPoseModel',
           'marker_object_points', 'reprojection_limit', 'unique_detections',
           'DUPLICATE_SIDE_FRACTION', 'MAX_REPROJECTION_FRACTION', 'normal_angle',
           'pose_covariance', 'transform_covariance',
           'PARALLELOGRAM_PX', 'PNP_FALLBACK_PX', 'SMALL_TAG_PX2']

_FULL_CONFIDENCE_SIDE_PX = 20.0
_POSITION_FLOOR = 1e-4       # m
# Corner noise that grows as tags shrink: the edge fit of a marker only ~15 px across
# sees 2-3 px per cell; 40 / side^2 px (0.16 px at 16 px) matches the renders' errors.
SMALL_TAG_PX2 = 40.0
_ROTATION_FLOOR = 1e-3       # rad
# Best IPPE_SQUARE reprojection error (px) above which SQPNP and ITERATIVE are tried too
# (module docstring). Good detections on the renders stay well below it.
PNP_FALLBACK_PX = 0.5
# A quad this close to a parallelogram (|q0 + q2 - q1 - q3|, px) is IPPE_SQUARE's
# degenerate case (module docstring): the fallback solvers run too.
PARALLELOGRAM_PX = 0.02
# Detections of one id with centres closer than this fraction of the smaller side are
# one tag (``unique_detections``): two tags of one id are >= 1 side + quiet zone apart.
DUPLICATE_SIDE_FRACTION = 0.5
# Default of the reprojection gate's share of the tag's side (``reprojection_limit``):
# 2 px up to 50 px sides as before; 79-100 px tags near a wide-angle frame's edge have
# 2.4-2.5 px RMS from the lens model's residual alone (issue 34).
MAX_REPROJECTION_FRACTION = 0.04
_PNP_FALLBACKS = (('sqpnp', cv2.SOLVEPNP_SQPNP), ('iterative', cv2.SOLVEPNP_ITERATIVE))


def reprojection_limit(side_px, max_px, max_fraction=0.0):
    """max(`max_px`, `max_fraction` * `side_px`): the RMS reprojection gate of a tag of
    apparent side `side_px` (scalar or array)."""
    return np.maximum(float(max_px), float(max_fraction) * np.asarray(side_px, np.float64))


def unique_detections(detections):
    """`detections` without a second report of one physical tag: of the detections of one
    id whose centres are closer than ``DUPLICATE_SIDE_FRACTION`` of the smaller one's side
    (two threshold windows' contours of one tag, refined onto the same edges), the one
    with the lowest reprojection error is kept. Two tags of one id are kept apart: their
    centres are at least a side plus a quiet zone apart. Returns (kept, dropped) with a
    DroppedDetection naming the kept one for each duplicate; order kept."""
    order = sorted(range(len(detections)), key=lambda i: detections[i].reprojection_error)
    kept, dropped = [], []
    for i in order:
        det = detections[i]
        centre = np.asarray(det.corners, dtype=np.float64).reshape(4, 2).mean(axis=0)
        twin = next((k for k in kept if detections[k].tag_id == det.tag_id
                     and np.linalg.norm(centre - np.asarray(detections[k].corners).reshape(
                         4, 2).mean(axis=0)) < DUPLICATE_SIDE_FRACTION * min(
                         det.side_px, detections[k].side_px)), None)
        if twin is None:
            kept.append(i)
        else:
            dropped.append(DroppedDetection(
                det.tag_id, f'duplicate of the tag {det.tag_id} at '
                f'{np.round(np.asarray(detections[twin].corners).mean(axis=0), 1).tolist()} '
                'px (another contour of it)', det.corners))
    return [detections[i] for i in sorted(kept)], dropped


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
    # Quads whose blurred-code decode the frame's budget left out (face_search_budget_ms).
    decode_skipped: int = 0

    def in_frame(self, transform, frame: str) -> "DetectionResult":
        return replace(self, detections=[d.transformed(transform, frame)
                                         for d in self.detections],
                       dropped=list(self.dropped),
                       cubes=[c.transformed(transform, frame) for c in self.cubes])


def normal_angle(rotation, rvec) -> float:
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


@dataclass(frozen=True)
class TagPoseModel:
    """What a tag's pose and covariance depend on: the camera (intrinsics, distortion or
    None, `focal_px` the mean focal length), the marker (its size and
    ``marker_object_points``), the corner noise and the acceptance limits. ``TagDetector``
    makes one from its settings (``TagDetector.pose_model``)."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray | None
    focal_px: float
    marker_size: float
    object_points: np.ndarray
    corner_sigma_px: float
    max_reprojection_error: float
    min_side_px: float
    ambiguity_ratio: float
    camera_frame: str   # URDF frame of the camera (TagDetector's camera_frame)
    # The RMS gate grows with the tag: max(max_reprojection_error, this * side px).
    max_reprojection_fraction: float = 0.0

    def reprojection_limit(self, side_px):
        """The largest RMS reprojection error (px) a tag of apparent side `side_px` may
        have: ``max_reprojection_error`` for small tags, ``max_reprojection_fraction`` of
        the side for large ones (a lens-model residual grows with the tag's size)."""
        return reprojection_limit(side_px, self.max_reprojection_error,
                                  self.max_reprojection_fraction)

    def pose(self, tag_id, quad, source='aruco'):
        """The Detection of tag `tag_id` at `quad` (4, 2) px (ArUco order), or a
        DroppedDetection saying why it has none (module docstring)."""
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
            solutions = self.solve_pnp(quad, 'ippe_square', cv2.SOLVEPNP_IPPE_SQUARE)
        except cv2.error as error:
            return DroppedDetection(tag_id, f'solvePnP failed: {error.msg}', quad)
        ippe = solutions
        parallelogram = np.abs(quad[0] + quad[2] - quad[1] - quad[3]).max() < PARALLELOGRAM_PX
        if parallelogram or not ippe or ippe[0][0] > PNP_FALLBACK_PX or ippe[0][2][2] <= 0:
            # IPPE_SQUARE's (near) fronto-parallel failure (module docstring).
            for name, flag in _PNP_FALLBACKS:
                try:
                    solutions = solutions + self.solve_pnp(quad, name, flag)
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
        limit = self.reprojection_limit(side)
        if rms > limit:
            return DroppedDetection(
                tag_id, f'reprojection error {rms:.2f} px > {limit:.2f} px (side '
                f'{side:.0f} px)', quad)
        rot, _ = cv2.Rodrigues(rvec)
        ambiguity, angle = 0.0, 0.0
        if solver == 'ippe_square':
            second = ippe[1] if len(ippe) > 1 else None
        else:
            # The best other pose: one whose face normal differs (the mirrored tilt).
            second = next((sol for sol in solutions[1:]
                           if normal_angle(rot, sol[1]) > _ROTATION_FLOOR), None)
        if second is not None and np.isfinite(second[0]) and second[0] > 0:
            ambiguity = float(min(1.0, rms / second[0]))
            if ambiguity > self.ambiguity_ratio:
                angle = normal_angle(rot, second[1])
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot, tvec
        cov = pose_covariance(rot, tvec, side, rms, self.focal_px, self.corner_sigma_px, angle)
        confidence = float(np.exp(-0.5 * rms ** 2) * min(1.0, side / _FULL_CONFIDENCE_SIDE_PX))
        cands = [pose]
        for sol in solutions[1:]:
            if np.isfinite(sol[1]).all() and np.isfinite(sol[2]).all() and sol[2][2] > 0 \
                    and normal_angle(rot, sol[1]) > _ROTATION_FLOOR:
                other = np.eye(4)
                other[:3, :3], _ = cv2.Rodrigues(sol[1])
                other[:3, 3] = sol[2]
                cands.append(other)
                break
        return Detection(tag_id, quad.copy(), pose, cov, rms, confidence, side,
                         self.marker_size, self.camera_frame, ambiguity, solver,
                         candidates=np.array(cands), source=source)

    def solve_pnp(self, quad, name, flag):
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
