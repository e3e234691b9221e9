"""sensor_msgs/Image payloads as real camera drivers send them, to the grey uint8 image the
tag detector works on (plain NumPy + OpenCV, no rclpy, no cv_bridge).

Encodings (the names of sensor_msgs/image_encodings.hpp, Jazzy):

| encoding                                   | drivers             | to grey                    |
|--------------------------------------------|---------------------|----------------------------|
| mono8, 8UC1                                | mono cameras        | as is (no copy)            |
| bgr8, 8UC3, rgb8, bgra8, 8UC4, rgba8       | colour cameras      | cv2.cvtColor *2GRAY        |
| uyvy, yuv422 (= UYVY)                      | usb_cam, v4l2       | the Y bytes (YUV2GRAY_UYVY)|
| yuyv, yuv422_yuy2 (= YUYV)                 | usb_cam, v4l2       | the Y bytes (YUV2GRAY_YUY2)|
| mono16                                     | machine vision, IR  | scaled to 8 bits (below)   |
| bayer_rggb8, bayer_bggr8, bayer_gbrg8,     | raw machine-vision  | demosaiced to grey         |
| bayer_grbg8 (and the same ...16)           | and industrial cams | (cv2 Bayer*2GRAY)          |

8UC3 / 8UC4 are taken as BGR / BGRA, OpenCV's order. ROS names a Bayer pattern by its
first row from the top-left pixel (bayer_rggb8: R G / G B); OpenCV names it by the second
row's two middle pixels, so ROS `bayer_rggb8` is OpenCV's `COLOR_BayerBG2GRAY` (and bggr ->
RG, gbrg -> GR, grbg -> GB), the table cv_bridge converts with.

16-bit images (mono16, bayer_*16) are shifted right by the fewest bits that fit the frame's
brightest raw pixel into 8 bits: a 16-bit image loses its low byte, a 12-bit image stored in
16 bits its low 4 bits, and one whose values already fit in 8 bits is taken as is. Tag
detection thresholds locally, so a per-frame power-of-two gain does it no harm, where a
fixed 1/256 would leave a 10- or 12-bit camera's image nearly black. `is_bigendian` is
honoured for them.

Anything else (depth images such as 16UC1 / 32FC1, 16-bit colour, planar YUV) raises
`ImageEncodingError` naming the encodings accepted; a buffer whose size, step and length
disagree raises `ImageLayoutError`.

``sensor_msgs/CompressedImage`` payloads (JPEG or PNG, image_transport's ``compressed``
format strings such as ``'rgb8; jpeg compressed bgr8'``) are decoded by
``compressed_image_to_gray`` (``cv2.imdecode``); a corrupt payload raises
``ImageDecodeError`` (an ``ImageEncodingError``).

The detector's checks of what it is given: ``check_gray_image`` (a non-empty 2-D uint8
image, ``ValueError`` saying why not) and ``check_image_size`` (``ImageSizeError`` for an
image whose size is not the one the camera intrinsics are for: the scaled image of a 2x
resized camera would put every tag at twice its distance).
"""

import cv2
import numpy as np


class ImageEncodingError(ValueError):
    """The image cannot be converted (unsupported encoding or inconsistent buffer)."""


class ImageLayoutError(ImageEncodingError):
    """An image whose size, step and data length disagree."""


# The 8-bit encodings taken before drivers' encodings were (and what a CompressedImage's
# format may name): encoding -> (channels, cv2 conversion to grey or None).
EIGHT_BIT_ENCODINGS = {
    'mono8': (1, None),
    '8UC1': (1, None),
    'bgr8': (3, cv2.COLOR_BGR2GRAY),
    '8UC3': (3, cv2.COLOR_BGR2GRAY),
    'rgb8': (3, cv2.COLOR_RGB2GRAY),
    'bgra8': (4, cv2.COLOR_BGRA2GRAY),
    '8UC4': (4, cv2.COLOR_BGRA2GRAY),
    'rgba8': (4, cv2.COLOR_RGBA2GRAY),
}
YUV422_ENCODINGS = {
    'uyvy': cv2.COLOR_YUV2GRAY_UYVY,
    'yuv422': cv2.COLOR_YUV2GRAY_UYVY,          # ROS's older name of UYVY
    'yuyv': cv2.COLOR_YUV2GRAY_YUY2,
    'yuv422_yuy2': cv2.COLOR_YUV2GRAY_YUY2,     # ROS's older name of YUYV
}
# ROS pattern (first two pixels of the first row, then of the second) -> OpenCV code.
_BAYER_CODES = {'rggb': cv2.COLOR_BayerBG2GRAY, 'bggr': cv2.COLOR_BayerRG2GRAY,
                'gbrg': cv2.COLOR_BayerGR2GRAY, 'grbg': cv2.COLOR_BayerGB2GRAY}
BAYER_ENCODINGS = {f'bayer_{pattern}{bits}': code for bits in (8, 16)
                   for pattern, code in _BAYER_CODES.items()}
SIXTEEN_BIT_ENCODINGS = ('mono16',) + tuple(e for e in BAYER_ENCODINGS if e.endswith('16'))
SUPPORTED_ENCODINGS = (tuple(EIGHT_BIT_ENCODINGS) + tuple(YUV422_ENCODINGS) + ('mono16',)
                       + tuple(BAYER_ENCODINGS))


def bytes_per_pixel(encoding):
    """Bytes one pixel takes in a row of `encoding` (one of SUPPORTED_ENCODINGS)."""
    if encoding in EIGHT_BIT_ENCODINGS:
        return EIGHT_BIT_ENCODINGS[encoding][0]
    if encoding in YUV422_ENCODINGS or encoding in SIXTEEN_BIT_ENCODINGS:
        return 2
    if encoding in BAYER_ENCODINGS:
        return 1
    raise ImageEncodingError(
        f"unsupported image encoding {encoding!r}; supported: {', '.join(SUPPORTED_ENCODINGS)}")


def significant_bits(image16):
    """Bits the brightest pixel of a uint16 image needs (a 12-bit camera's: 12 or fewer)."""
    return int(image16.max()).bit_length()


def _rows(data, height, width, step, pixel_bytes, encoding):
    if height <= 0 or width <= 0:
        raise ImageLayoutError(f'empty image ({width} x {height})')
    if step < width * pixel_bytes:
        raise ImageLayoutError(f'step {step} is smaller than width x bytes per pixel = '
                               f'{width * pixel_bytes} for {encoding}')
    try:
        buf = np.frombuffer(memoryview(data), dtype=np.uint8)
    except TypeError:
        buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if buf.size != step * height:
        raise ImageLayoutError(
            f'image data has {buf.size} bytes, expected step x height = {step * height}')
    return buf.reshape(height, step)[:, :width * pixel_bytes]


def image_to_gray(encoding, height, width, step, data, is_bigendian=False) -> np.ndarray:
    """A (height, width) uint8 grey image from sensor_msgs/Image fields (no copy for mono8)."""
    pixel_bytes = bytes_per_pixel(encoding)
    height, width, step = int(height), int(width), int(step)
    rows = _rows(data, height, width, step, pixel_bytes, encoding)
    if encoding in EIGHT_BIT_ENCODINGS:
        channels, conversion = EIGHT_BIT_ENCODINGS[encoding]
        if channels == 1:
            return rows
        return cv2.cvtColor(np.ascontiguousarray(rows).reshape(height, width, channels),
                            conversion)
    if encoding in YUV422_ENCODINGS:
        return cv2.cvtColor(np.ascontiguousarray(rows).reshape(height, width, 2),
                            YUV422_ENCODINGS[encoding])
    if encoding in SIXTEEN_BIT_ENCODINGS:
        order = '>u2' if is_bigendian else '<u2'
        image = np.ascontiguousarray(rows).view(order).astype(np.uint16)
        shift = significant_bits(image) - 8
        if encoding in BAYER_ENCODINGS:
            image = cv2.cvtColor(image, BAYER_ENCODINGS[encoding])
        return (image >> max(0, shift)).astype(np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(rows), BAYER_ENCODINGS[encoding])


def image_msg_to_gray(msg) -> np.ndarray:
    """``image_to_gray`` of anything with sensor_msgs/Image's fields."""
    return image_to_gray(msg.encoding, msg.height, msg.width, msg.step, msg.data,
                         bool(msg.is_bigendian))


class ImageDecodeError(ImageEncodingError):
    """A compressed image payload that does not decode (corrupt, truncated, empty)."""


class ImageSizeError(ValueError):
    """The image's size is not the one the camera intrinsics are for."""


def check_image_size(width, height, expected):
    """Raise ImageSizeError unless (width, height) equals `expected` (None: anything)."""
    if expected is None:
        return
    ew, eh = expected
    if (int(width), int(height)) != (ew, eh):
        raise ImageSizeError(
            f'image is {int(width)}x{int(height)} px but the camera intrinsics (camera_info) '
            f'are for {ew}x{eh} px: poses would be wrong (a scaled image scales every '
            f'distance); resize the image or use the matching camera_info')


def _parse_format(fmt):
    """(original encoding or None, codec or None, transport encoding or None) of a
    CompressedImage format string."""
    fmt = (fmt or '').strip()
    original, _, rest = fmt.rpartition(';') if ';' in fmt else ('', '', fmt)
    tokens = rest.split()
    lowered = [t.lower() for t in tokens]
    if 'compresseddepth' in lowered:
        raise ImageEncodingError(
            f'compressed image format {fmt!r}: compressedDepth (depth images) is not '
            'supported; expected JPEG or PNG of an 8-bit image')
    codec = None
    if lowered:
        codec = {'jpeg': 'jpeg', 'jpg': 'jpeg', 'png': 'png'}.get(lowered[0])
        if codec is None:
            raise ImageEncodingError(
                f'compressed image format {fmt!r}: unsupported codec {tokens[0]!r}; '
                'expected jpeg or png')
    transport = tokens[2] if len(tokens) >= 3 and lowered[1] == 'compressed' else None
    return original.strip() or None, codec, transport


def parse_compressed_format(fmt):
    """``(original encoding, codec, transport encoding)`` of a sensor_msgs/CompressedImage
    format string in image_transport's ``compressed`` convention: ``'<encoding>; jpeg
    compressed <encoding>'``, ``'<encoding>; png compressed <encoding>'`` or the legacy
    ``'jpeg'`` / ``'png'``; parts that are absent are None (an empty format: the codec is
    read from the payload). Raises ImageEncodingError for other codecs, compressedDepth
    and original encodings that are not 8-bit images (image_encodings.EIGHT_BIT_ENCODINGS)."""
    original, codec, transport = _parse_format(fmt)
    for enc in (original, transport):
        if enc is not None and enc not in EIGHT_BIT_ENCODINGS:
            raise ImageEncodingError(
                f'compressed image format {fmt!r}: unsupported image encoding {enc!r}; '
                f"supported: {', '.join(EIGHT_BIT_ENCODINGS)}")
    return original, codec, transport


_MAGIC = {'jpeg': b'\xff\xd8', 'png': b'\x89PNG'}


def compressed_image_to_gray(fmt, data) -> np.ndarray:
    """A (height, width) uint8 grey image from a CompressedImage's format and data.

    JPEG and PNG, decoded with ``cv2.imdecode`` straight to grey, except when the payload
    holds RGB-ordered channels (transport encoding rgb8 / rgba8), which are decoded in
    colour and converted as RGB. Raises ImageEncodingError for an unsupported format and
    ImageDecodeError for a payload that does not decode."""
    _, codec, transport = parse_compressed_format(fmt)
    try:
        buf = np.frombuffer(memoryview(data), dtype=np.uint8)
    except TypeError:
        buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if buf.size == 0:
        raise ImageDecodeError(f'empty compressed image payload (format {fmt!r})')
    if codec is not None and not buf[:len(_MAGIC[codec])].tobytes() == _MAGIC[codec]:
        raise ImageDecodeError(
            f'compressed image payload of {buf.size} bytes is not {codec.upper()} data '
            f'(format {fmt!r})')
    rgb_order = transport in ('rgb8', 'rgba8')
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR if rgb_order else cv2.IMREAD_GRAYSCALE)
    except cv2.error as error:
        raise ImageDecodeError(f'compressed image payload of {buf.size} bytes does not '
                               f'decode (format {fmt!r}): {error.msg.strip()}') from None
    if img is None or img.size == 0:
        raise ImageDecodeError(f'compressed image payload of {buf.size} bytes is corrupt or '
                               f'truncated (format {fmt!r})')
    if rgb_order:
        # IMREAD_COLOR returns the payload's channels as stored, read as BGR.
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img


def compressed_msg_to_gray(msg) -> np.ndarray:
    """``compressed_image_to_gray`` of anything with sensor_msgs/CompressedImage's fields."""
    return compressed_image_to_gray(msg.format, msg.data)

def check_gray_image(gray, image_size=None) -> np.ndarray:
    """`gray` as a C-contiguous (height, width) uint8 array, or ValueError saying why
    not: empty, not 2-D (colour: convert it first), not uint8, or not `image_size`
    ((width, height) px; None: any size)."""
    if not isinstance(gray, np.ndarray):
        try:
            gray = np.asarray(gray)
        except (TypeError, ValueError) as error:
            raise ValueError(f'expected a 2-D uint8 grey image, got {type(gray).__name__}'
                             f' ({error})') from None
    if gray.ndim == 3 and gray.shape[2] == 1:
        gray = gray[:, :, 0]
    if gray.ndim == 3 and gray.shape[2] in (3, 4):
        raise ValueError(
            f'expected a 2-D uint8 grey image, got {gray.shape[2]} channels '
            f'{gray.shape} {gray.dtype}: convert it first (image_to_gray, or '
            f'cv2.cvtColor with COLOR_BGR2GRAY / COLOR_BGRA2GRAY)')
    if gray.ndim != 2:
        raise ValueError(f'expected a 2-D uint8 grey image, got a {gray.ndim}-D array '
                         f'{gray.shape} {gray.dtype}')
    if gray.size == 0:
        raise ValueError(f'empty image ({gray.shape[1]}x{gray.shape[0]} px)')
    if gray.dtype != np.uint8:
        raise ValueError(f'expected a 2-D uint8 grey image, got dtype {gray.dtype} '
                         f'{gray.shape}: scale to 0..255 and convert to uint8 first')
    check_image_size(gray.shape[1], gray.shape[0], image_size)
    return np.ascontiguousarray(gray)


__all__ = ['BAYER_ENCODINGS', 'EIGHT_BIT_ENCODINGS', 'ImageDecodeError', 'ImageEncodingError',
           'ImageLayoutError', 'ImageSizeError', 'SIXTEEN_BIT_ENCODINGS', 'SUPPORTED_ENCODINGS',
           'YUV422_ENCODINGS', 'bytes_per_pixel', 'check_gray_image', 'check_image_size',
           'compressed_image_to_gray', 'compressed_msg_to_gray', 'image_msg_to_gray',
           'image_to_gray', 'parse_compressed_format', 'significant_bits']
