"""Tag detection on rendered ARcube images: ids, poses, covariances, conversions, drops."""

import cv2
import numpy as np
import pytest

from abp_perception.corners import decode_quads, refine_quads
from abp_perception.detector import (
    ImageEncodingError,
    TagDetector,
    dictionary_id,
    image_to_gray,
    marker_object_points,
    pose_covariance,
    transform_covariance,
)
from abp_sim_bridge.renderer import Distractor

FACES = np.array([0, 1, 2, 3, 4, 5])


def angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


# -- image conversion ---------------------------------------------------------------------

@pytest.fixture
def gray_image():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=(6, 5), dtype=np.uint8)


@pytest.mark.parametrize("encoding, code", [
    ("bgr8", cv2.COLOR_GRAY2BGR), ("rgb8", cv2.COLOR_GRAY2RGB),
    ("bgra8", cv2.COLOR_GRAY2BGRA), ("rgba8", cv2.COLOR_GRAY2RGBA),
])
def test_colour_encodings_convert_to_the_same_grey(gray_image, encoding, code):
    colour = cv2.cvtColor(gray_image, code)
    h, w, c = colour.shape
    out = image_to_gray(encoding, h, w, w * c, colour.tobytes())
    np.testing.assert_array_equal(out, gray_image)


def test_channel_order_matters():
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[..., 2] = 200                                   # pure red in BGR
    as_bgr = image_to_gray("bgr8", 2, 2, 6, bgr.tobytes())
    as_rgb = image_to_gray("rgb8", 2, 2, 6, bgr.tobytes())
    assert as_bgr[0, 0] == cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[0, 0]
    assert as_bgr[0, 0] != as_rgb[0, 0]


def test_mono8_with_row_padding_and_array_data(gray_image):
    import array
    h, w = gray_image.shape
    padded = np.zeros((h, w + 3), np.uint8)
    padded[:, :w] = gray_image
    out = image_to_gray("mono8", h, w, w + 3, array.array("B", padded.tobytes()))
    np.testing.assert_array_equal(out, gray_image)


@pytest.mark.parametrize("encoding, step, size, message", [
    ("yuv422", 10, 60, "unsupported image encoding 'yuv422'"),
    ("mono16", 10, 60, "unsupported image encoding 'mono16'"),
    ("bayer_rggb8", 5, 30, "unsupported"),
    ("bgr8", 5, 30, "step 5 is smaller"),
    ("mono8", 5, 20, "expected step x height = 30"),
])
def test_bad_images_are_refused_clearly(encoding, step, size, message):
    with pytest.raises(ImageEncodingError, match=message):
        image_to_gray(encoding, 6, 5, step, bytes(size))


def test_unknown_dictionary_is_refused():
    assert dictionary_id("DICT_4X4_50") == cv2.aruco.DICT_4X4_50
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        TagDetector(np.eye(3), dictionary="DICT_BOGUS")


# -- detection on rendered scenes -----------------------------------------------------------

@pytest.mark.parametrize("state, distance", [(32, 1.0), (33, 1.0), (0, 0.7), (13, 1.5)])
def test_rendered_cube_tags_found_with_accurate_poses(scenes, detector, state, distance):
    scene = scenes.render(FACES, state, distance=distance, elevation_deg=35.0)
    result = detector.detect(scene.image).in_frame(scene.camera_pose, "base_link")
    expected = {t.tag_id: t for t in scene.expected(max_view_angle_deg=70.0)}
    found = {d.tag_id: d for d in result.detections}
    assert set(expected) <= set(found), (expected.keys(), found.keys())
    assert set(found) <= {int(t) for t in FACES}
    for tag_id, truth in expected.items():
        det = found[tag_id]
        err = np.linalg.norm(det.position - truth.centre)
        assert err < 0.004 * distance ** 2 + 0.002, (tag_id, err)
        assert angle_deg(det.normal, truth.normal) < 5.0
        assert det.frame == "base_link"
        assert np.all(np.linalg.eigvalsh(det.covariance) > 0)
        assert 0.5 < det.confidence <= 1.0
        assert det.reprojection_error < 0.5


def test_face_centre_error_at_1m_is_millimetres(scenes, detector):
    errors = []
    for state in range(0, 48, 5):
        scene = scenes.render(FACES, state, distance=1.0, elevation_deg=35.0)
        result = detector.detect(scene.image).in_frame(scene.camera_pose, "world")
        truth = {t.tag_id: t for t in scene.tags}
        errors += [np.linalg.norm(d.position - truth[d.tag_id].centre)
                   for d in result.detections if d.tag_id in truth]
    assert len(errors) >= 20
    assert np.median(errors) < 0.005


def test_corners_are_in_aruco_order(scenes, detector):
    scene = scenes.render(FACES, 32, distance=0.8, elevation_deg=35.0)
    truth = {t.tag_id: t for t in scene.tags}
    for det in detector.detect(scene.image).detections:
        np.testing.assert_allclose(det.corners, truth[det.tag_id].corners_px, atol=0.5)


def test_covariance_grows_with_distance(scenes, detector):
    sd = []
    for distance in (0.6, 1.2, 2.0):
        scene = scenes.render(FACES, 32, distance=distance, elevation_deg=35.0)
        top = [d for d in detector.detect(scene.image).detections if d.tag_id == FACES[4]][0]
        sd.append(np.sqrt(np.trace(top.covariance[:3, :3])))
    assert sd[0] < sd[1] < sd[2]


def test_covariance_model_grows_with_reprojection_error_and_rotates():
    rot = np.eye(3)
    t = np.array([0.0, 0.0, 1.0])
    small = pose_covariance(rot, t, 40.0, 0.1, 550.0, 0.08)
    large = pose_covariance(rot, t, 40.0, 1.5, 550.0, 0.08)
    assert np.trace(large) > 10 * np.trace(small)
    far = pose_covariance(rot, 2 * t, 20.0, 0.1, 550.0, 0.08)
    assert far[2, 2] > 4 * small[2, 2]                    # range ~ r^2
    assert small[2, 2] > small[0, 0]                      # along the ray > across it
    q = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = transform_covariance(small, q)
    np.testing.assert_allclose(moved[:3, :3], q @ small[:3, :3] @ q.T)
    np.testing.assert_allclose(np.trace(moved), np.trace(small))


def test_distractor_tags_are_reported_with_their_ids(scenes, detector):
    pose = np.eye(4)
    pose[:3, 3] = [0.8, 0.35, 0.0005]
    distractors = [Distractor(30, pose, 0.08)]
    scene = scenes.render(FACES, 32, distance=1.0, elevation_deg=35.0,
                          distractors=distractors)
    ids = sorted(d.tag_id for d in detector.detect(scene.image).detections)
    assert 30 in ids and FACES[4] in ids


def test_empty_image_gives_no_detections(detector):
    result = detector.detect(np.full((480, 640), 128, np.uint8))
    assert result.detections == [] and result.dropped == []


def test_degenerate_and_non_finite_quads_are_dropped_with_a_reason(detector):
    nan_quad = np.full((4, 2), np.nan)
    assert "non-finite" in detector._pose(3, nan_quad).reason
    tiny = np.array([[10.0, 10.0], [12.0, 10.0], [12.0, 12.0], [10.0, 12.0]])
    assert "degenerate" in detector._pose(3, tiny).reason
    mirrored = tiny[::-1] * 20
    assert "non-convex or mirrored" in detector._pose(3, mirrored).reason


def test_non_image_input_is_refused(detector):
    with pytest.raises(ValueError, match="2-D uint8"):
        detector.detect(np.zeros((4, 4, 3), np.uint8))


# -- corners ---------------------------------------------------------------------------

def test_edge_fit_removes_corner_errors(scenes):
    scene = scenes.render(FACES, 32, distance=0.9, elevation_deg=35.0)
    top = [t for t in scene.tags if t.tag_id == FACES[4]][0]
    rng = np.random.default_rng(1)
    noisy = top.corners_px + rng.uniform(-1.5, 1.5, size=(4, 2))
    refined, ok = refine_quads(scene.image, noisy[None])
    assert ok[0]
    assert np.abs(refined[0] - top.corners_px).max() < 0.3


def test_decoding_a_quad_reads_id_and_rotation(scenes):
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    scene = scenes.render(FACES, 32, distance=0.8, elevation_deg=35.0)
    top = [t for t in scene.tags if t.tag_id == FACES[4]][0]
    for shift in range(4):
        (tag_id, rotation), = decode_quads(scene.image, np.roll(top.corners_px, -shift, 0)[None],
                                           dictionary)
        assert tag_id == FACES[4]
        np.testing.assert_allclose(np.roll(np.roll(top.corners_px, -shift, 0), rotation, 0),
                                   top.corners_px)
    blank = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 140.0], [100.0, 140.0]])
    assert decode_quads(np.full((480, 640), 200, np.uint8), blank[None], dictionary) == [None]


def test_ippe_square_object_points_follow_the_documented_order():
    pts = marker_object_points(0.08)
    np.testing.assert_allclose(pts, [[-0.04, 0.04, 0], [0.04, 0.04, 0], [0.04, -0.04, 0],
                                     [-0.04, -0.04, 0]])
