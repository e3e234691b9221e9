"""One rigid pose per ARcube from all the corners of its visible tags (no rclpy).

A single tag's pose from IPPE has a two-fold ambiguity: the true tilt and its mirror
image about the line of sight fit the four corners almost equally well on small or far
tags, and picking the wrong one flips the tag's normal by tens of degrees. An ARcube's
tags are a rigid board: each tag is centred on a face of a cube of edge ``h``
(``cube_size``, docs/MODEL.md) with its edges parallel to the cube's edges, so in a frame
aligned with any one of them the others sit at one of the 24 face/roll placements
``F_q = [Q_q | Q_q (0, 0, h/2)]`` (``Q_q`` the 24 rotations of the cube, tag z = face
normal). Fitting one pose to the 4n corners of n >= 2 such tags removes the flip: the
mirrored pose of one tag does not fit the others.

``fit_cubes`` (called by ``TagDetector.detect``):

1. **Grouping**: tags of the same marker size whose centres are ``h / sqrt(2)`` apart
   (adjacent faces), within 3 sigma of the centres' distance uncertainty (from their
   covariances) or 25 %, are linked; every connected group of >= 2 tags is one cube
   candidate. The centres come from the range and image position, which the IPPE flip
   hardly moves.
2. **Seeds**: every IPPE solution of every tag of the group (both, when IPPE returns
   two) gives a cube pose ``T_tag [I | (0, 0, -h/2)]`` (cube frame: that tag's axes,
   origin at the cube centre).
3. **Placement**: under a seed, each other tag takes the placement ``F_q`` whose four
   projected corners are nearest its detected corners (all 24 tried at once).
4. **Refinement**: ``cv2.solvePnPRefineLM`` on all the group's corners from the seed;
   placements are re-chosen under the refined pose and it is refined again if any
   changed. The seed whose refined pose has the lowest RMS reprojection error wins.
5. **Check**: the fit is kept when every tag's own RMS error under it is at most
   ``max_reprojection_error`` (or ``max_reprojection_fraction`` of its side, the
   larger); otherwise the worst tag is dropped and a group of >= 2
   refitted (a stray tag linked by chance, or a tag from another cube); of a group of
   more than three tags (a cube shows at most three) the worst down to three at once.

Each tag of a fitted cube then gets the pose the cube implies for it (``T_cube F_q``),
with a covariance propagated from the cube fit; its own single-tag pose stays in
``Detection.single_pose`` / ``single_covariance``.

Covariance of the cube pose: ``sigma^2 (J^T J)^-1`` with ``J`` the pinhole Jacobian of
all the corners' image positions with respect to (translation, small rotation about the
camera axes), ``sigma`` the detector's corner noise (``corner_sigma_px``, the small-tag
term at the group's smallest tag and the fit's RMS error, as in ``tag_pose``); a tag's
covariance is that of its centre and rotation, ``A C A^T`` with
``A = [[I, -[R c]x], [0, I]]``, ``c`` the tag centre in the cube frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from abp_belief.cube import CUBE_ROTATIONS

from .tag_pose import transform_covariance

__all__ = ['CubePose', 'CUBE_GROUP', 'face_placements', 'fit_cubes', 'group_tags']

# Tag configurations (relative placements) refined per group, best seed fit first: the
# right one and IPPE's mirrored alternatives.
MAX_CONFIGURATIONS = 3
GN_ITERATIONS = 5            # Gauss-Newton steps at most from a seed (2-3 usually)
GN_TOLERANCE = 1e-6          # stop when no step exceeds this (m, rad)
# A configuration is refined when its seed's RMS error is within this factor of the best
# seed's or below SEED_RMS_PX.
SEED_RMS_RATIO = 4.0
SEED_RMS_PX = 2.0
_POSITION_FLOOR = 1e-4       # m
_ROTATION_FLOOR = 1e-3       # rad


# The 24 proper rotations of the cube, docs/MODEL.md's canonical order.
CUBE_GROUP = CUBE_ROTATIONS                                  # (24, 3, 3)
# _RELATIVE[a, b]: index of Q_a^T Q_b (the placement of b seen from a's frame).
_RELATIVE = np.argmin(np.abs(np.einsum('aji,bjk->abik', CUBE_GROUP, CUBE_GROUP)[:, :, None]
                             - CUBE_GROUP[None, None]).sum(axis=(3, 4)), axis=2)


def face_placements(cube_size: float) -> np.ndarray:
    """(24, 4, 4) tag -> cube poses of a tag centred on a face, edges parallel to the
    cube's, in a cube frame aligned with some tag: ``[Q | Q (0, 0, h/2)]``."""
    out = np.tile(np.eye(4), (24, 1, 1))
    out[:, :3, :3] = CUBE_GROUP
    out[:, :3, 3] = CUBE_GROUP[:, :, 2] * (0.5 * float(cube_size))
    return out


@dataclass
class CubePose:
    """One ARcube's rigid pose from the corners of >= 2 of its tags."""

    detections: tuple              # indices into DetectionResult.detections
    pose: np.ndarray               # (4, 4) cube -> frame; cube axes = the first tag's axes
    covariance: np.ndarray         # (6, 6) x y z rx ry rz of the cube centre, frame axes
    placements: np.ndarray         # (n, 4, 4) tag -> cube, one per detection
    reprojection_error: float      # RMS over all the corners, px
    cube_size: float               # m
    frame: str = 'camera'

    @property
    def position(self) -> np.ndarray:
        return self.pose[:3, 3]

    def tag_poses(self) -> np.ndarray:
        """(n, 4, 4) tag -> frame poses the cube implies."""
        return self.pose[None] @ self.placements

    def transformed(self, transform, frame: str) -> "CubePose":
        transform = np.asarray(transform, dtype=np.float64)
        return CubePose(self.detections, transform @ self.pose,
                        transform_covariance(self.covariance, transform[:3, :3]),
                        self.placements, self.reprojection_error, self.cube_size, frame)


def _skew(v):
    """(..., 3, 3) cross-product matrices."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def group_tags(positions, covariances, marker_sizes, cube_size, rel_tol=0.25,
               n_sigma=3.0):
    """Lists of indices (>= 2 each) of tags that may share a cube: connected components of
    the graph linking centres ``h / sqrt(2)`` apart (module docstring)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    n = pos.shape[0]
    if n < 2:
        return []
    cov = np.asarray(covariances, dtype=np.float64).reshape(n, 3, 3)
    size = np.asarray(marker_sizes, dtype=np.float64).reshape(n)
    d = pos[None] - pos[:, None]                                     # (n, n, 3)
    dist = np.linalg.norm(d, axis=2)
    u = d / np.maximum(dist, 1e-12)[..., None]
    csum = cov[None] + cov[:, None]
    sd = np.sqrt(np.maximum(np.einsum('ijk,ijkl,ijl->ij', u, csum, u), 0.0))
    target = float(cube_size) / np.sqrt(2.0)
    tol = np.maximum(rel_tol * target, n_sigma * sd)
    # np.isclose's test (its defaults) without its overhead (~40 us a frame).
    same_size = np.abs(size[None] - size[:, None]) <= 1e-8 + 1e-5 * np.abs(size[:, None])
    linked = (np.abs(dist - target) <= tol) & same_size
    np.fill_diagonal(linked, False)
    _, labels = _components(linked)
    groups = [np.flatnonzero(labels == k).tolist() for k in np.unique(labels)]
    return [g for g in groups if len(g) >= 2]


def _components(adjacency):
    """(count, labels) of the connected components of a small boolean adjacency matrix
    (label propagation: each node takes the smallest label among its neighbours)."""
    n = adjacency.shape[0]
    labels = np.arange(n)
    reach = adjacency | np.eye(n, dtype=bool)
    while True:
        new = np.where(reach, labels[None, :], n).min(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    _, labels = np.unique(labels, return_inverse=True)
    return int(labels.max(initial=-1)) + 1, labels


class _Problem:
    """The corners of one group of tags and the camera."""

    def __init__(self, quads, candidates, object_points, cube_size, camera_matrix,
                 dist_coeffs):
        self.quads = np.asarray(quads, dtype=np.float64)             # (n, 4, 2)
        self.candidates = candidates                                 # per tag: (k, 4, 4)
        self.obj = np.asarray(object_points, dtype=np.float64)       # (4, 3), tag frame
        self.h = float(cube_size)
        self.K = np.asarray(camera_matrix, dtype=np.float64)
        self.dist = dist_coeffs
        # Seeds and placements are scored with an ideal pinhole on undistorted corners.
        self.ideal = self.quads if dist_coeffs is None else cv2.undistortPoints(
            self.quads.reshape(-1, 1, 2), self.K, dist_coeffs, P=self.K).reshape(-1, 4, 2)
        self.placements = face_placements(cube_size)                 # (24, 4, 4)
        # Corners of each placement in the cube frame: (24, 4, 3).
        self.placed = np.einsum('qij,kj->qki', self.placements[:, :3, :3], self.obj) \
            + self.placements[:, None, :3, 3]
        self.to_centre = np.eye(4)
        self.to_centre[2, 3] = -0.5 * self.h                         # cube -> tag frame

    def _pixels(self, poses, points):
        """Ideal pinhole pixels (m, ..., 2) of cube-frame `points` (..., 3) under poses
        (m, 4, 4), and their depths."""
        pc = np.einsum('mij,...j->m...i', poses[:, :3, :3], points) \
            + poses[:, :3, 3].reshape((-1,) + (1,) * (points.ndim - 1) + (3,))
        z = pc[..., 2]
        px = np.stack([self.K[0, 0] * pc[..., 0] / z + self.K[0, 2],
                       self.K[1, 1] * pc[..., 1] / z + self.K[1, 2]], axis=-1)
        return px, z

    def place(self, poses):
        """Placement index per (pose, tag) (m, n): the one whose projected corners are
        nearest, among faces towards the camera; and the summed squared error (m,)."""
        px, z = self._pixels(poses, self.placed)                      # (m, 24, 4, 2)
        err = np.sum((px[:, None] - self.ideal[None, :, None]) ** 2, axis=(3, 4))  # (m,n,24)
        centres = np.einsum('mij,qj->mqi', poses[:, :3, :3], self.placements[:, :3, 3]) \
            + poses[:, None, :3, 3]
        normals = np.einsum('mij,qj->mqi', poses[:, :3, :3], self.placements[:, :3, 2])
        bad = (np.sum(normals * centres, axis=2) >= 0) | (z.min(axis=2) <= 0)   # (m, 24)
        err = np.where(bad[:, None, :], np.inf, err)
        placement = np.argmin(err, axis=2)
        return placement, np.take_along_axis(err, placement[..., None], axis=2)[..., 0].sum(1)

    def refine(self, poses, placement, iterations=GN_ITERATIONS):
        """Gauss-Newton on all the corners, for poses (m, 4, 4) with placements (m, n) at
        once (ideal pinhole pixels; left perturbation: translation, then small rotation
        about the camera axes). Returns poses, per-tag RMS (m, n) px and J^T J (m, 6, 6)."""
        m = poses.shape[0]
        pts = self.placed[placement].reshape(m, -1, 3)                # (m, N, 3)
        target = self.ideal.reshape(-1, 2)
        rot, t = poses[:, :3, :3].copy(), poses[:, :3, 3].copy()
        f = np.array([self.K[0, 0], self.K[1, 1]])
        c = np.array([self.K[0, 2], self.K[1, 2]])
        for it in range(iterations + 1):
            rx = pts @ rot.transpose(0, 2, 1)                          # R X, (m, N, 3)
            pc = rx + t[:, None, :]
            z = pc[..., 2:3]
            resid = f * pc[..., :2] / z + c - target                  # (m, N, 2)
            if it == iterations:
                break
            dproj = np.zeros(pc.shape[:2] + (2, 3))
            dproj[..., 0, 0] = f[0] / z[..., 0]
            dproj[..., 1, 1] = f[1] / z[..., 0]
            dproj[..., :, 2] = -f * pc[..., :2] / z ** 2
            # d pc / d theta = -[R X]x, so a row g of d proj / d pc gives (R X) x g.
            jac = np.concatenate([dproj, _cross(rx[:, :, None, :], dproj)], axis=3)
            jac = jac.reshape(m, -1, 6)
            # (matmul, not einsum: these small products are most of a GN step's cost)
            jac_t = jac.transpose(0, 2, 1)
            hess = jac_t @ jac
            grad = (jac_t @ resid.reshape(m, -1, 1))[..., 0]
            step = -np.linalg.solve(hess + 1e-9 * np.eye(6), grad[..., None])[..., 0]
            t += step[:, :3]
            rot = _exp_so3(step[:, 3:]) @ rot
            if np.abs(step).max(initial=0.0) < GN_TOLERANCE:
                iterations = it + 1
        rms = np.sqrt(np.mean(np.sum(resid.reshape(m, -1, 4, 2) ** 2, axis=3), axis=2))
        out = np.tile(np.eye(4), (m, 1, 1))
        out[:, :3, :3], out[:, :3, 3] = rot, t
        return out, rms, hess

    def fit(self):
        """(pose, placement, per-tag RMS, overall RMS, J^T J) of the best seed, or None.

        Seeds that put the tags in the same configuration (relative placements) would
        refine to the same pose: only the one that fits best before refinement is refined.
        """
        seeds = np.concatenate([np.asarray(c, dtype=np.float64).reshape(-1, 4, 4)
                                for c in self.candidates]) @ self.to_centre
        placement, err = self.place(seeds)
        finite = np.isfinite(err)
        if not finite.any():
            return None
        rel = _RELATIVE[placement[:, :1], placement]                  # (m, n) vs tag 0
        code = np.where(finite, rel @ (24 ** np.arange(rel.shape[1])), -1)
        order = np.argsort(err, kind='stable')                        # inf (unfinite) last
        _, first = np.unique(code[order], return_index=True)
        chosen = order[np.sort(first)]
        # Configurations whose seed fits far worse than the best seed's are not refined
        # (a mirrored seed typically misplaces the other tags by tens of px).
        seed_rms = np.sqrt(err[chosen] / (4 * placement.shape[1]))
        chosen = chosen[seed_rms <= max(SEED_RMS_RATIO * seed_rms[0], SEED_RMS_PX)]
        chosen = chosen[:MAX_CONFIGURATIONS]
        with np.errstate(all='ignore'):
            poses, rms, hess = self.refine(seeds[chosen], placement[chosen])
        total = np.sqrt(np.mean(rms ** 2, axis=1))
        ok = np.isfinite(total) & (poses[:, 2, 3] > 0) & np.isfinite(poses).all(axis=(1, 2))
        if not ok.any():
            return None
        k = int(np.flatnonzero(ok)[np.argmin(total[ok])])
        return poses[k], placement[chosen[k]], rms[k], float(total[k]), hess[k]


def _cross(a, b):
    """np.cross over the last axis, without its axis bookkeeping (broadcasting)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _exp_so3(v):
    """Rotation matrices (m, 3, 3) of rotation vectors (m, 3) (Rodrigues, batched)."""
    theta = np.sqrt(np.sum(v * v, axis=1))[:, None, None]
    k = _skew(v / np.maximum(theta[:, :, 0], 1e-300))
    return np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * (k @ k)


def _tag_covariance(cube_cov, cube_pose, placement):
    """Covariance of a tag's (centre, rotation) from the cube's (module docstring)."""
    a = np.eye(6)
    a[:3, 3:] = -_skew(cube_pose[:3, :3] @ placement[:3, 3])
    cov = a @ cube_cov @ a.T
    cov[:3, :3] += _POSITION_FLOOR ** 2 * np.eye(3)
    cov[3:, 3:] += _ROTATION_FLOOR ** 2 * np.eye(3)
    return 0.5 * (cov + cov.T)


# Faces of a cube seen at once from any viewpoint (its tags in one fit).
MAX_VISIBLE_FACES = 3


def fit_cubes(detections, candidates, camera_matrix, dist_coeffs, cube_size,
              object_points, max_reprojection_error=2.0, corner_sigma_px=0.08,
              small_tag_px2=40.0, max_reprojection_fraction=0.0):
    """Rigid cube poses of the groups of `detections` (camera frame) that fit.

    `candidates`: per detection, an (k, 4, 4) array of its single-tag pose solutions
    (IPPE's two, best first). A tag's RMS gate is the larger of `max_reprojection_error`
    and `max_reprojection_fraction` of its side, as for its single-tag pose. Returns
    (cubes, rigid) with `cubes` a list of CubePose and `rigid` a dict detection index ->
    (pose, covariance, RMS px, cube index)."""
    cubes, rigid = [], {}
    if len(detections) < 2 or not cube_size or cube_size <= 0:
        return cubes, rigid
    groups = group_tags([d.pose[:3, 3] for d in detections],
                        [d.covariance[:3, :3] for d in detections],
                        [d.marker_size for d in detections], cube_size)
    for group in groups:
        group = list(group)
        while len(group) >= 2:
            prob = _Problem([detections[i].corners for i in group],
                            [candidates[i] for i in group], object_points, cube_size,
                            camera_matrix, dist_coeffs)
            best = prob.fit()
            if best is None:
                break
            pose, placement, rms, total, hess = best
            limit = np.maximum(max_reprojection_error, max_reprojection_fraction * np.array(
                [detections[i].side_px for i in group]))
            if (rms <= limit).all() and len(set(placement)) == len(group):
                break
            if len(group) == 2:
                best = None
                break
            # A cube shows at most MAX_VISIBLE_FACES tags: of a larger group (a board or
            # sheet of tags whose spacing and pose noise link them all) the worst are
            # dropped at once, not refitted one by one (10 fits on an 11-tag board).
            worst = np.argsort(-(rms / limit), kind='stable')
            for k in sorted(worst[:max(1, len(group) - MAX_VISIBLE_FACES)], reverse=True):
                group.pop(int(k))
        if best is None or len(group) < 2:
            continue
        pose, placement, rms, total, hess = best
        side = min(detections[i].side_px for i in group)
        sigma = float(np.sqrt(corner_sigma_px ** 2 + (small_tag_px2 / max(side, 1.0) ** 2) ** 2
                              + total ** 2))
        cube_cov = sigma ** 2 * np.linalg.pinv(hess)
        cube_cov = 0.5 * (cube_cov + cube_cov.T)
        # Cube axes = the first tag's axes (origin stays at the cube centre).
        r0 = prob.placements[placement[0], :3, :3]
        pose_ref = pose.copy()
        pose_ref[:3, :3] = pose[:3, :3] @ r0
        placed = prob.placements[placement].copy()
        placed[:, :3, :3] = r0.T[None] @ placed[:, :3, :3]
        placed[:, :3, 3] = placed[:, :3, 3] @ r0
        k = len(cubes)
        cubes.append(CubePose(tuple(int(i) for i in group), pose_ref, cube_cov, placed,
                              total, float(cube_size)))
        for n, i in enumerate(group):
            tag_pose = pose @ prob.placements[placement[n]]
            rigid[i] = (tag_pose, _tag_covariance(cube_cov, pose, prob.placements[placement[n]]),
                        float(rms[n]), k)
    return cubes, rigid
