"""Where a detected tag's cube should show other tags: a targeted search for blurred ones.

Plain NumPy + OpenCV, no rclpy.

Under motion blur and strong JPEG, most tags the detector misses are not rejected by
decoding: ArUco never sees a quad there, because blur rounds the black border into a
contour of more than four vertices and the smeared bits merge with it (or with the next
face's tag across the thin cube edge). Most of those tags sit on a cube face next to a
tag that was found (issue 16). So ``adjacent_face_boxes`` predicts, from each found
tag's pose(s), where its cube's adjacent faces that face the camera and hold no found
tag are: their image boxes and (``with_quads``) the projected marker quads, which
``search_faces`` refines and decodes directly, with no contour search at all (a found
tag's pose puts the next face's marker within a pixel or two; the edge fit of
``corners.refine_quads`` recovers that, and ``blur_decode`` reads markers too blurred
for their bits), for ``TagDetector.detect`` and ``track``.
"""

from __future__ import annotations

import cv2
import numpy as np

from .blur_decode import MIN_DARKNESS, darkness, decode_blurred
from .corners import decode_quads, inside_any_quad, quad_areas, refine_quads
from .tag_pose import DroppedDetection

__all__ = ['adjacent_face_boxes', 'copy_parameters', 'search_faces', 'FACE_SEARCH_AMBIGUITY',
           'FACE_SEARCH_ROUNDS']

# Rounds of prediction (the second from the tags the first found: a cube's third face).
FACE_SEARCH_ROUNDS = 2
# Best / second IPPE reprojection error above which the face search also trusts a tag's
# mirrored pose (below it, the mirrored pose only adds boxes on faces with no tag).
FACE_SEARCH_AMBIGUITY = 0.6

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


def search_faces(gray, detections, pose_model, dictionary, cube_size, blur_decode=True,
                 budget=None):
    """Detections on the cube faces (edge `cube_size`) next to found tags that should show
    a tag and hold none found (``adjacent_face_boxes`` from both IPPE poses of each tag):
    the predicted marker quads themselves, decoded (``_decode_predicted``) and given poses
    by `pose_model` (``tag_pose.TagPoseModel``); then once more from the tags this found
    (a cube's third face). `budget` (``blur_decode.DecodeBudget`` or None: unlimited)
    bounds the blurred-code decoding's CPU time."""
    found, seeds = [], list(detections)
    for _ in range(FACE_SEARCH_ROUNDS):
        if not seeds:
            break
        boxes, quads = _face_boxes(gray, seeds, detections + found, pose_model, cube_size)
        if not len(boxes):
            break
        seeds = _decode_predicted(gray, quads, detections + found, pose_model, dictionary,
                                  blur_decode, budget)
        found += seeds
    return found


def _face_boxes(gray, seeds, detections, pose_model, cube_size):
    # The mirrored IPPE pose too where it is nearly as good (it puts the faces elsewhere).
    boxes, quads = adjacent_face_boxes(
        np.concatenate([d.candidates if d.ambiguity > FACE_SEARCH_AMBIGUITY
                        else d.candidates[:1] for d in seeds]),
        np.array([d.pose[:3, 3] for d in detections]), pose_model.camera_matrix,
        pose_model.dist_coeffs, cube_size, pose_model.marker_size, gray.shape, with_quads=True)
    keep = boxes[:, 4] >= pose_model.min_side_px
    return boxes[keep], quads[keep]


def _decode_predicted(gray, quads, detections, pose_model, dictionary, blur_decode,
                      budget=None):
    """Detections at predicted marker quads (K, 4, 2): those dark inside against their
    quiet zone (``blur_decode.darkness``; no marker otherwise), one per place, refined
    and decoded by bits (``decode_quads``) or else, refined or as predicted, by
    correlation with blurred codes (``decode_blurred``)."""
    # Screen order: clockwise, as ArUco orders markers.
    quads = quads.copy()
    flip = quad_areas(quads) < 0
    quads[flip] = quads[flip][:, ::-1]
    cells = int(dictionary.markerSize) + 2
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
    res = decode_quads(gray, refined, dictionary)
    out = [(np.roll(refined[k], res[k][1], axis=0), res[k][0])
           for k in range(len(quads)) if ok[k] and res[k] is not None]
    left = [k for k in range(len(quads)) if not (ok[k] and res[k] is not None)]
    if blur_decode and left:
        tries = [refined[k] for k in left if ok[k]] + [quads[k] for k in left]
        owner = [k for k in left if ok[k]] + left
        done = set()
        for k, quad, r in zip(owner, tries, decode_blurred(gray, np.array(tries), dictionary,
                                                           budget=budget)):
            if r is not None and k not in done:
                done.add(k)
                out.append((np.roll(quad, r[1], axis=0), r[0]))
    known = np.array([d.corners for d in detections], dtype=np.float64)
    dets = []
    for quad, tag_id in out:
        centre = quad.mean(axis=0)[None]
        if inside_any_quad(centre, known)[0] or (
                dets and inside_any_quad(centre, np.array([d.corners for d in dets]))[0]):
            continue
        det = pose_model.pose(tag_id, quad, 'face_search')
        if not isinstance(det, DroppedDetection):
            dets.append(det)
    return dets
