"""Where a detected tag's cube should show other tags: a targeted search for blurred ones.

Plain NumPy + OpenCV, no rclpy.

Under motion blur and strong JPEG, most tags the detector misses are not rejected by
decoding: ArUco never sees a quad there, because blur rounds the black border into a
contour of more than four vertices and the smeared bits merge with it (or with the next
face's tag across the thin cube edge). Most of those tags sit on a cube face next to a
tag that was found (issue 16). So ``adjacent_face_boxes`` predicts, from each found
tag's pose(s), where its cube's adjacent faces that face the camera and hold no found
tag are: their image boxes and (``with_quads``) the projected marker quads, which the
detector refines and decodes directly, with no contour search at all (a found tag's
pose puts the next face's marker within a pixel or two; the edge fit of
``corners.refine_quads`` recovers that, and ``blur_decode`` reads markers too blurred
for their bits).
"""

from __future__ import annotations

import cv2
import numpy as np

from .corners import quad_areas

__all__ = ['adjacent_face_boxes', 'copy_parameters']

# The four faces next to a tag's face, in the tag frame (x right, y up, z out of the
# face): outward normal and the in-plane axis of that face other than z.
_NORMALS = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]])
_ACROSS = np.array([[0, 1.0, 0], [0, 1.0, 0], [1.0, 0, 0], [1.0, 0, 0]])
_Z = np.array([0.0, 0.0, 1.0])
_SQUARE = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def copy_parameters(base: "cv2.aruco.DetectorParameters"):
    """A copy of ArUco detector parameters (cv2's objects have no copy)."""
    p = cv2.aruco.DetectorParameters()
    for name in dir(base):
        if not name.startswith('_') and not callable(getattr(base, name)):
            try:
                setattr(p, name, getattr(base, name))
            except (AttributeError, TypeError):
                pass
    return p


def adjacent_face_boxes(poses, found_centres, camera_matrix, dist_coeffs, cube_size,
                        marker_size, shape, max_angle_deg=75.0, margin_px=6.0,
                        with_quads=False):
    """Image boxes of cube faces that should hold a tag nobody found.

    `poses` (N, 4, 4): tag -> camera poses of found tags (several per tag are fine, e.g.
    both IPPE solutions: a mirrored one only adds a box). Each tag is centred on a face
    of a cube of edge `cube_size`; of the four faces next to it, those seen within
    `max_angle_deg` of their normal, in front of the camera and with no
    `found_centres` (M, 3) point (camera frame) within a quarter cube edge of their centre
    are returned as (x0, y0, x1, y1, tag side px) rows (K, 5): the face's projected
    bounding box grown by `margin_px` and clipped to `shape` (rows, cols), and the
    apparent side of a marker of `marker_size` there (sqrt of its projected area).
    `with_quads`: also the projected marker corners (K, 4, 2), as (boxes, quads).
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if poses.shape[0] == 0:
        return (np.zeros((0, 5)), np.zeros((0, 4, 2))) if with_quads else np.zeros((0, 5))
    half = 0.5 * float(cube_size)
    rot, trans = poses[:, :3, :3], poses[:, :3, 3]
    # Face centres and outward normals in the camera frame, (N, 4, 3).
    centre_tag = (-half * _Z)[None] + half * _NORMALS
    centres = np.einsum('nij,fj->nfi', rot, centre_tag) + trans[:, None, :]
    normals = np.einsum('nij,fj->nfi', rot, _NORMALS)
    dist = np.linalg.norm(centres, axis=2)
    cos_view = -(normals * centres).sum(axis=2) / np.maximum(dist, 1e-9)
    wanted = (cos_view > np.cos(np.radians(max_angle_deg))) & (centres[..., 2] > 0)
    found = np.asarray(found_centres, dtype=np.float64).reshape(-1, 3)
    if found.shape[0]:
        gap = np.linalg.norm(centres[:, :, None, :] - found[None, None], axis=3)
        wanted &= gap.min(axis=2) > 0.5 * half
    n_idx, f_idx = np.nonzero(wanted)
    if n_idx.size == 0:
        return (np.zeros((0, 5)), np.zeros((0, 4, 2))) if with_quads else np.zeros((0, 5))
    # Face and marker corners (K, 4, 3): centre + a (across) + b (z) on each face.
    across = np.einsum('kij,kj->ki', rot[n_idx], _ACROSS[f_idx])
    up = rot[n_idx][:, :, 2]
    c = centres[n_idx, f_idx]
    square = _SQUARE[None, :, :, None]
    face = c[:, None] + half * (square[:, :, 0] * across[:, None] + square[:, :, 1] * up[:, None])
    m = 0.5 * float(marker_size)
    marker = c[:, None] + m * (square[:, :, 0] * across[:, None] + square[:, :, 1] * up[:, None])
    pts = np.concatenate([face, marker], axis=1).reshape(-1, 1, 3)
    px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.asarray(camera_matrix, float),
                              dist_coeffs)
    px = px.reshape(-1, 8, 2)
    lo = px[:, :4].min(axis=1) - margin_px
    hi = px[:, :4].max(axis=1) + margin_px
    area = np.abs(quad_areas(px[:, 4:]))
    h, w = int(shape[0]), int(shape[1])
    lo = np.clip(lo, 0, (w, h))
    hi = np.clip(hi, 0, (w, h))
    inside = (hi - lo >= 1.0).all(axis=1) & np.isfinite(px).all(axis=(1, 2))
    boxes = np.concatenate([lo, hi, np.sqrt(area)[:, None]], axis=1)[inside]
    return (boxes, px[inside, 4:]) if with_quads else boxes
