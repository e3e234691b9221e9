"""Driver encodings to grey (abp_perception.image_encodings): each encoding is built from a
known image the way a camera would send it and must come back as the grey image."""

import cv2
import numpy as np
import pytest

from abp_perception.image_encodings import (
    BAYER_ENCODINGS,
    SUPPORTED_ENCODINGS,
    ImageEncodingError,
    ImageLayoutError,
    image_msg_to_gray,
    image_to_gray,
)


@pytest.fixture
def gray():
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, size=(8, 10), dtype=np.uint8)


def test_yuv422_gives_the_luma_of_opencvs_own_encoding(gray):
    # OpenCV encodes a BGR image to UYVY / YUYV (video range: Y = 16 + 219 grey / 255);
    # the grey image out is that luma, whatever the chroma.
    bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    luma = np.rint(16 + gray * (219 / 255)).astype(int)
    for encodings, code in ((('uyvy', 'yuv422'), cv2.COLOR_BGR2YUV_UYVY),
                            (('yuyv', 'yuv422_yuy2'), cv2.COLOR_BGR2YUV_YUY2)):
        packed = cv2.cvtColor(bgr, code)                       # (h, w, 2)
        h, w = gray.shape
        for encoding in encodings:
            out = image_to_gray(encoding, h, w, 2 * w, packed.tobytes())
            assert np.abs(out.astype(int) - luma).max() <= 1, encoding


def test_yuv422_byte_order_matters(gray):
    h, w = gray.shape
    uyvy = np.empty((h, w, 2), np.uint8)
    uyvy[..., 0] = 128                                         # U, V
    uyvy[..., 1] = gray                                        # Y
    np.testing.assert_array_equal(image_to_gray('yuv422', h, w, 2 * w, uyvy.tobytes()), gray)
    assert not np.array_equal(image_to_gray('yuv422_yuy2', h, w, 2 * w, uyvy.tobytes()), gray)


@pytest.mark.parametrize('scale', [256, 16, 1])                # 16-, 12- and 8-bit cameras
@pytest.mark.parametrize('bigendian', [False, True])
def test_mono16_comes_back_at_eight_bits(gray, scale, bigendian):
    h, w = gray.shape
    mono16 = gray.astype(np.uint16) * scale
    data = mono16.astype('>u2' if bigendian else '<u2').tobytes()
    out = image_to_gray('mono16', h, w, 2 * w, data, is_bigendian=bigendian)
    assert out.dtype == np.uint8
    np.testing.assert_array_equal(out, gray)


def _mosaic(bgr, pattern):
    """The Bayer mosaic a sensor with `pattern` (ROS name: rows 'rg'/'gb'...) records."""
    channel = {'r': 2, 'g': 1, 'b': 0}
    out = np.empty(bgr.shape[:2], bgr.dtype)
    for dy in (0, 1):
        for dx in (0, 1):
            c = channel[pattern[2 * dy + dx]]
            out[dy::2, dx::2] = bgr[dy::2, dx::2, c]
    return out


@pytest.mark.parametrize('encoding', sorted(BAYER_ENCODINGS))
def test_bayer_of_a_grey_image_comes_back(encoding):
    # A grey scene: every photosite sees the grey level, whatever its colour filter.
    # Demosaicing interpolates each colour from its neighbours, which is exact on a
    # linear shading (away from the 2-pixel border, replicated at the edges).
    v, u = np.mgrid[0:24, 0:32]
    shade = np.rint(20 + 5 * u + 3 * v).astype(np.uint8)
    mosaic = _mosaic(cv2.cvtColor(shade, cv2.COLOR_GRAY2BGR), encoding[6:10])
    if encoding.endswith('16'):
        mosaic = mosaic.astype(np.uint16) * 256
    h, w = shade.shape
    out = image_to_gray(encoding, h, w, mosaic.strides[0], mosaic.tobytes())
    assert out.dtype == np.uint8 and out.shape == (h, w)
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(out[inner].astype(int) - shade[inner]).max() <= 1


@pytest.mark.parametrize('encoding', sorted(BAYER_ENCODINGS))
def test_bayer_pattern_is_read_as_ros_names_it(encoding):
    # A saturated colour: the grey level tells red from blue, so a pattern read with the
    # wrong OpenCV code (ROS and OpenCV name Bayer patterns differently) is caught.
    bgr = np.zeros((8, 8, 3), np.uint8)
    bgr[...] = (30, 90, 220)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[0, 0]
    mosaic = _mosaic(bgr, encoding[6:10])
    if encoding.endswith('16'):
        mosaic = mosaic.astype(np.uint16) * 256
    out = image_to_gray(encoding, 8, 8, mosaic.strides[0], mosaic.tobytes())
    assert abs(int(out[4, 4]) - int(expected)) <= 1, (out[4, 4], expected)


def test_row_padding_is_skipped_for_two_byte_pixels(gray):
    h, w = gray.shape
    padded = np.zeros((h, 2 * w + 6), np.uint8)
    padded[:, 0:2 * w:2] = gray                                # little-endian low byte
    out = image_to_gray('mono16', h, w, 2 * w + 6, padded.tobytes())
    np.testing.assert_array_equal(out, gray)


def test_message_fields_are_read():
    class Msg:
        encoding, height, width, step, is_bigendian = 'mono16', 1, 2, 4, 1
        data = bytes([0x12, 0x34, 0xff, 0x00])
    # big-endian 0x1234 and 0xff00: 16 significant bits -> shifted by 8
    np.testing.assert_array_equal(image_msg_to_gray(Msg), [[0x12, 0xff]])


@pytest.mark.parametrize('encoding', ['16UC1', '32FC1', 'rgb16', 'nv21', 'bogus'])
def test_other_encodings_are_refused_naming_the_accepted_ones(encoding):
    with pytest.raises(ImageEncodingError, match=f"unsupported image encoding '{encoding}'") \
            as info:
        image_to_gray(encoding, 2, 2, 8, bytes(16))
    for accepted in ('mono16', 'yuv422', 'bayer_rggb8', 'bgr8'):
        assert accepted in str(info.value)
    assert set(SUPPORTED_ENCODINGS) >= {'uyvy', 'yuyv', 'yuv422_yuy2', 'bayer_grbg16'}


@pytest.mark.parametrize('encoding, step, size, message', [
    ('yuv422', 8, 48, 'step 8 is smaller than width x bytes per pixel = 10'),
    ('mono16', 10, 50, 'expected step x height = 60'),
    ('bayer_rggb8', 5, 20, 'expected step x height = 30'),
])
def test_bad_layouts_are_refused_clearly(encoding, step, size, message):
    with pytest.raises(ImageLayoutError, match=message):
        image_to_gray(encoding, 6, 5, step, bytes(size))
