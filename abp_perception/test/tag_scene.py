"""Synthetic tag images for the perception tests (no renderer package needed).

`paste_tag`: a cv2.aruco marker copied pixel for pixel into a plain image, i.e. a tag
exactly parallel to the image plane with noise-free, pixel-aligned edges.
`render_tags`: tags at given poses, projected with the camera intrinsics and drawn by a
4x supersampled perspective warp (anti-aliased edges, white quiet zone)."""

import cv2
import numpy as np

DICTIONARY = cv2.aruco.DICT_4X4_50
SUPERSAMPLE = 4


def marker(tag_id, side_px, dictionary=DICTIONARY):
    return cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(dictionary),
                                         int(tag_id), int(side_px))


def paste_tag(image, tag_id, centre_px, side_px):
    """Paste a marker of `side_px` with its centre at integer pixel `centre_px` (u, v);
    returns its outer corners (ArUco order, pixel-centre coordinates)."""
    u0, v0 = centre_px[0] - side_px // 2, centre_px[1] - side_px // 2
    image[v0:v0 + side_px, u0:u0 + side_px] = marker(tag_id, side_px)
    lo_u, lo_v, hi_u, hi_v = u0 - 0.5, v0 - 0.5, u0 + side_px - 0.5, v0 + side_px - 0.5
    return np.array([[lo_u, lo_v], [hi_u, lo_v], [hi_u, hi_v], [lo_u, hi_v]])


def tag_pose(position, tilt_deg=0.0, tilt_axis=(0.0, 1.0, 0.0), roll_deg=0.0):
    """4 x 4 tag -> camera pose: the tag at `position` facing the camera, then tilted."""
    facing = np.diag([1.0, -1.0, -1.0])                # tag z towards the camera, y up
    roll = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(roll_deg)]))[0]
    axis = np.asarray(tilt_axis, dtype=np.float64)
    tilt = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(tilt_deg))[0]
    pose = np.eye(4)
    pose[:3, :3] = tilt @ facing @ roll
    pose[:3, 3] = position
    return pose


def render_tags(K, width, height, tags, marker_size, background=190, dictionary=DICTIONARY):
    """A grey image of tags [(tag_id, pose)] (poses tag -> camera, tag z out of the face),
    each with a one-cell white quiet zone, on a plain background."""
    s = SUPERSAMPLE
    k_hi = np.array(K, dtype=np.float64).copy()
    k_hi[:2] *= s
    k_hi[:2, 2] += 0.5 * (s - 1)                       # pixel centres of the fine grid
    hi = np.full((height * s, width * s), background, np.uint8)
    cells = cv2.aruco.getPredefinedDictionary(dictionary).markerSize + 2   # + black border
    cell_px = 240 // cells
    side_px = cell_px * cells
    src = cv2.copyMakeBorder(marker(0, side_px, dictionary), cell_px, cell_px, cell_px, cell_px,
                             cv2.BORDER_CONSTANT, value=255)
    h = 0.5 * marker_size
    obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    lo, hi_edge = cell_px - 0.5, cell_px + side_px - 0.5
    src_quad = np.float32([[lo, lo], [hi_edge, lo], [hi_edge, hi_edge], [lo, hi_edge]])
    for tag_id, pose in tags:
        src[cell_px:cell_px + side_px, cell_px:cell_px + side_px] = marker(tag_id, side_px,
                                                                          dictionary)
        rvec, _ = cv2.Rodrigues(pose[:3, :3])
        dst, _ = cv2.projectPoints(obj, rvec, pose[:3, 3], k_hi, None)
        warp = cv2.getPerspectiveTransform(src_quad, dst.reshape(4, 2).astype(np.float32))
        size = (hi.shape[1], hi.shape[0])
        drawn = cv2.warpPerspective(src, warp, size, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.full(src.shape, 255, np.uint8), warp, size,
                                   flags=cv2.INTER_LINEAR)
        alpha = mask.astype(np.float32) / 255.0
        hi = np.rint(alpha * drawn + (1.0 - alpha) * hi).astype(np.uint8)
    return cv2.resize(hi, (width, height), interpolation=cv2.INTER_AREA)
