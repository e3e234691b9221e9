"""Face search (issue 16): boxes of a found tag's cube faces that should show another
tag, and the detector finding a tag there that its full-image ArUco pass misses."""

import cv2
import numpy as np
import pytest
from tag_scene import render_tags, tag_pose

from abp_perception.face_search import adjacent_face_boxes

CUBE, MARKER = 0.10, 0.08


def _cube_tags(distance=0.9, tilt_deg=30.0):
    """Tag 3 on a cube's face seen from the front and tag 7 on the face above it (its +y
    neighbour, normal along tag 3's y), the cube tilted about x by `tilt_deg` so both
    face the camera; (tag id, pose) pairs."""
    front = tag_pose([0.0, 0.0, distance], tilt_deg, tilt_axis=(1.0, 0.0, 0.0))
    h = 0.5 * CUBE
    to_top = np.eye(4)
    to_top[:3, :3] = cv2.Rodrigues(np.array([-np.pi / 2, 0.0, 0.0]))[0]   # z -> tag y
    to_top[:3, 3] = [0.0, h, -h]
    return [(3, front), (7, front @ to_top)]


@pytest.fixture(scope='module')
def camera():
    from abp_description import camera_intrinsics
    return camera_intrinsics()


def _angle_to_camera_deg(pose):
    centre, normal = pose[:3, 3], pose[:3, 2]
    return float(np.degrees(np.arccos(-normal @ centre / np.linalg.norm(centre))))


def test_the_missing_neighbour_face_gets_a_box_around_its_tag(camera):
    (_, front), (_, top) = _cube_tags()
    assert _angle_to_camera_deg(front) < 75 and _angle_to_camera_deg(top) < 75
    shape = (camera.height, camera.width)
    boxes = adjacent_face_boxes(front[None], np.zeros((0, 3)), camera.K, None, CUBE,
                                MARKER, shape)
    assert len(boxes) == 1                       # the top face only: the sides face away
    half = 0.5 * MARKER
    corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0],
                        [-half, -half, 0]])
    px, _ = cv2.projectPoints(corners, cv2.Rodrigues(top[:3, :3])[0], top[:3, 3],
                              camera.K, None)
    px = px.reshape(4, 2)
    x0, y0, x1, y1, side = boxes[0]
    assert x0 < px[:, 0].min() and px[:, 0].max() < x1
    assert y0 < px[:, 1].min() and px[:, 1].max() < y1
    # The predicted tag size is the projected marker's.
    assert side == pytest.approx(np.sqrt(cv2.contourArea(px.astype(np.float32))), rel=1e-6)


def test_found_faces_and_faces_turned_away_get_no_box(camera):
    (_, front), (_, top) = _cube_tags()
    shape = (camera.height, camera.width)
    # The top tag found already: nothing left to look for.
    assert len(adjacent_face_boxes(front[None], top[None, :3, 3], camera.K, None, CUBE,
                                   MARKER, shape)) == 0
    # Seen head-on, every neighbouring face is at 90 deg: none is searched.
    head_on = tag_pose([0.0, 0.0, 0.9])
    assert len(adjacent_face_boxes(head_on[None], np.zeros((0, 3)), camera.K, None, CUBE,
                                   MARKER, shape)) == 0
    assert adjacent_face_boxes(np.zeros((0, 4, 4)), [], camera.K, None, CUBE, MARKER,
                               shape).shape == (0, 5)


def test_with_quads_gives_the_neighbour_marker_corners(camera):
    (_, front), (_, top) = _cube_tags()
    shape = (camera.height, camera.width)
    boxes, quads = adjacent_face_boxes(front[None], np.zeros((0, 3)), camera.K, None, CUBE,
                                       MARKER, shape, with_quads=True)
    assert boxes.shape == (1, 5) and quads.shape == (1, 4, 2)
    half = 0.5 * MARKER
    corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0],
                        [-half, -half, 0]])
    px, _ = cv2.projectPoints(corners, cv2.Rodrigues(top[:3, :3])[0], top[:3, 3],
                              camera.K, None)
    # The same four corners (in some order and winding).
    d = np.linalg.norm(quads[0][:, None] - px.reshape(4, 2)[None], axis=2)
    assert d.min(axis=1).max() < 1e-6


def _side_px(camera, pose):
    half = 0.5 * MARKER
    corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0],
                        [-half, -half, 0]])
    px, _ = cv2.projectPoints(corners, cv2.Rodrigues(pose[:3, :3])[0], pose[:3, 3],
                              camera.K, None)
    return float(np.sqrt(cv2.contourArea(px.reshape(4, 2).astype(np.float32))))


def _detections(camera, image, min_side_px, face_search):
    """Tag ids found by a detector whose full-image ArUco pass ignores markers under
    `min_side_px` a side (standing in for the tags blur hides from it: its perimeter
    limit); the face search sets its own limits per box."""
    from abp_perception.detector import TagDetector
    detector = TagDetector(camera.K, second_pass=False, face_search=face_search)
    if min_side_px:
        params = TagDetector.default_parameters()
        params.minMarkerPerimeterRate = 4.0 * min_side_px / max(camera.width, camera.height)
        for aruco in detector.arucos:
            aruco.setDetectorParameters(params)
    result = detector.detect(image)
    return sorted(d.tag_id for d in result.detections), result


def test_a_tag_the_full_image_pass_misses_is_found_on_its_cube_face(camera):
    tags = _cube_tags()
    front_side, top_side = (_side_px(camera, pose) for _, pose in tags)
    assert top_side < 0.8 * front_side
    image = render_tags(camera.K, camera.width, camera.height, tags, MARKER)
    blind = 0.5 * (front_side + top_side)
    assert _detections(camera, image, blind, face_search=False)[0] == [3]
    ids, result = _detections(camera, image, blind, face_search=True)
    assert ids == [3, 7] and result.face_search == 1
    top = next(d for d in result.detections if d.tag_id == 7)
    np.testing.assert_allclose(top.single_tag_pose[:3, 3], tags[1][1][:3, 3], atol=3e-3)
    # Both tags on one cube: the rigid fit takes them (cube_size as rendered).
    assert len(result.cubes) == 1


def test_face_search_finds_no_tag_where_there_is_none(camera):
    tags = _cube_tags()[:1]                      # the top face left plain
    image = render_tags(camera.K, camera.width, camera.height, tags, MARKER)
    ids, result = _detections(camera, image, None, face_search=True)
    assert ids == [3] and result.face_search == 0
