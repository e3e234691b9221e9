"""Tag detection without rendered scenes: image conversions, refusals, the covariance model,
drops, object points. Detection on rendered ARcube images: abp_bench/test."""

import cv2
import numpy as np
import pytest

from abp_perception.detector import (
    ImageEncodingError,
    TagDetector,
    dictionary_id,
    image_to_gray,
    marker_object_points,
    pose_covariance,
    transform_covariance,
)

FACES = np.array([0, 1, 2, 3, 4, 5])


def angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


# -- image conversion ---------------------------------------------------------------------

@pytest.fixture
def gray_image():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=(6, 5), dtype=np.uint8)


@pytest.mark.parametrize('encoding, code', [
    ('bgr8', cv2.COLOR_GRAY2BGR), ('rgb8', cv2.COLOR_GRAY2RGB),
    ('bgra8', cv2.COLOR_GRAY2BGRA), ('rgba8', cv2.COLOR_GRAY2RGBA),
])
def test_colour_encodings_convert_to_the_same_grey(gray_image, encoding, code):
    colour = cv2.cvtColor(gray_image, code)
    h, w, c = colour.shape
    out = image_to_gray(encoding, h, w, w * c, colour.tobytes())
    np.testing.assert_array_equal(out, gray_image)


def test_channel_order_matters():
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[..., 2] = 200                                   # pure red in BGR
    as_bgr = image_to_gray('bgr8', 2, 2, 6, bgr.tobytes())
    as_rgb = image_to_gray('rgb8', 2, 2, 6, bgr.tobytes())
    assert as_bgr[0, 0] == cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[0, 0]
    assert as_bgr[0, 0] != as_rgb[0, 0]


def test_mono8_with_row_padding_and_array_data(gray_image):
    import array
    h, w = gray_image.shape
    padded = np.zeros((h, w + 3), np.uint8)
    padded[:, :w] = gray_image
    out = image_to_gray('mono8', h, w, w + 3, array.array('B', padded.tobytes()))
    np.testing.assert_array_equal(out, gray_image)


@pytest.mark.parametrize('encoding, step, size, message', [
    ('yuv422', 10, 60, "unsupported image encoding 'yuv422'"),
    ('mono16', 10, 60, "unsupported image encoding 'mono16'"),
    ('bayer_rggb8', 5, 30, 'unsupported'),
    ('bgr8', 5, 30, 'step 5 is smaller'),
    ('mono8', 5, 20, 'expected step x height = 30'),
])
def test_bad_images_are_refused_clearly(encoding, step, size, message):
    with pytest.raises(ImageEncodingError, match=message):
        image_to_gray(encoding, 6, 5, step, bytes(size))


def test_unknown_dictionary_is_refused():
    assert dictionary_id('DICT_4X4_50') == cv2.aruco.DICT_4X4_50
    with pytest.raises(ValueError, match='unknown ArUco dictionary'):
        TagDetector(np.eye(3), dictionary='DICT_BOGUS')


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


def test_empty_image_gives_no_detections(detector):
    result = detector.detect(np.full((480, 640), 128, np.uint8))
    assert result.detections == [] and result.dropped == []


def test_degenerate_and_non_finite_quads_are_dropped_with_a_reason(detector):
    nan_quad = np.full((4, 2), np.nan)
    assert 'non-finite' in detector._pose(3, nan_quad).reason
    tiny = np.array([[10.0, 10.0], [12.0, 10.0], [12.0, 12.0], [10.0, 12.0]])
    assert 'degenerate' in detector._pose(3, tiny).reason
    mirrored = tiny[::-1] * 20
    assert 'non-convex or mirrored' in detector._pose(3, mirrored).reason


def test_non_image_input_is_refused(detector):
    with pytest.raises(ValueError, match='2-D uint8'):
        detector.detect(np.zeros((4, 4, 3), np.uint8))


def test_ippe_square_object_points_follow_the_documented_order():
    pts = marker_object_points(0.08)
    np.testing.assert_allclose(pts, [[-0.04, 0.04, 0], [0.04, 0.04, 0], [0.04, -0.04, 0],
                                     [-0.04, -0.04, 0]])
