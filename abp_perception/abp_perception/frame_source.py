"""Where the camera node's frames come from (OpenCV, no rclpy): a V4L2 device, a video
file, or a folder of images played in sorted order.

`open_frame_source(source, ...)` decides by the string: digits (`0`) are a device index,
`/dev/...` a device path, a folder a folder of images, an image file a one-image folder,
any other file a video. It opens the source and reads its first frame, so a missing
device, an unreadable file and an empty folder fail here (`FrameSourceError`, a
ValueError), at the node's configure, not at the first timer tick.

Frames are HxWx3 BGR uint8 (OpenCV's order) or HxW mono8 (`encoding`). A file or folder
ends (`read()` returns None) unless `loop` is true; a device never ends, but a frame it
fails to deliver is None too (`FrameSource.failed` counts them). In a folder, a file that
does not decode, or an image of another size than the first, is skipped and named in
`skipped` (the caller logs it): a folder is played as one camera of one size.
"""

import pathlib

import cv2
import numpy as np

IMAGE_SUFFIXES = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff', '.pgm', '.ppm', '.webp')
ENCODINGS = ('bgr8', 'mono8')


class FrameSourceError(ValueError):
    """A frame source that cannot be opened or read; the message says which and why."""


def _convert(image, encoding):
    """BGR (or grey, or BGRA) uint8 image -> the published encoding."""
    if image.ndim == 2:
        return image if encoding == 'mono8' else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if encoding == 'mono8' else image


def _size(image):
    return int(image.shape[1]), int(image.shape[0])


class FrameSource:
    """Common part: the first frame is read at open and returned by the first read()."""

    kind = 'source'

    def __init__(self, name, encoding, loop):
        if encoding not in ENCODINGS:
            raise FrameSourceError(f"encoding must be one of {', '.join(ENCODINGS)}, "
                                   f'got {encoding!r}')
        self.name, self.encoding, self.loop = str(name), encoding, bool(loop)
        self.size = None             # (width, height), from the first frame
        self.frames_read = 0
        self.failed = 0              # device frames that did not come
        self.skipped = []            # (file, reason) of folder images left out
        self._first = None

    def _open_first(self, image):
        self.size = _size(image)
        self._first = _convert(image, self.encoding)

    def read(self):
        """The next frame, or None (end of a file or folder without loop; a device frame
        that did not come)."""
        if self._first is not None:
            frame, self._first = self._first, None
        else:
            frame = self._next()
        if frame is not None:
            self.frames_read += 1
        return frame

    def _next(self):
        raise NotImplementedError

    def close(self):
        """Release the device or file."""

    def describe(self):
        return f'{self.kind} {self.name} ({self.size[0]}x{self.size[1]} px)'


class CaptureSource(FrameSource):
    """A V4L2 device or a video file through cv2.VideoCapture."""

    def __init__(self, target, name, kind, encoding, loop, width=0, height=0):
        super().__init__(name, encoding, loop and kind == 'video file')
        self.kind = kind
        if kind == 'device':
            self.capture = cv2.VideoCapture(target, cv2.CAP_V4L2)
            if width and height and self.capture.isOpened():
                self.capture.set(cv2.CAP_PROP_FRAME_WIDTH, width)
                self.capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        else:
            self.capture = cv2.VideoCapture(target)
        if not self.capture.isOpened():
            self.capture.release()
            what = ('no camera device' if kind == 'device' else 'cannot open video file')
            raise FrameSourceError(f'{what} {name}' + (
                ' (is it plugged in, and may this user read it? `v4l2-ctl --list-devices` '
                'lists the cameras)' if kind == 'device' else
                ' (not a video OpenCV can decode)'))
        ok, image = self.capture.read()
        if not ok or image is None:
            self.capture.release()
            raise FrameSourceError(f'{kind} {name} opened but gave no frame' + (
                ' (is another program using it?)' if kind == 'device' else
                ' (empty, or not a video OpenCV can decode)'))
        self._open_first(image)

    def _next(self):
        ok, image = self.capture.read()
        if (not ok or image is None) and self.loop:
            self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self.capture.read()
        if not ok or image is None:
            if self.kind == 'device':
                self.failed += 1
            return None
        if _size(image) != self.size:
            self.failed += 1
            return None
        return _convert(image, self.encoding)

    def close(self):
        self.capture.release()


class FolderSource(FrameSource):
    """Image files played in sorted (name) order."""

    kind = 'folder'

    def __init__(self, files, name, encoding, loop):
        super().__init__(name, encoding, loop)
        self.files = list(files)
        self._index = 0
        while self._index < len(self.files):
            image = self._load(self.files[self._index])
            if image is not None:
                self._index += 1
                self._open_first(image)
                return
            del self.files[self._index]
        raise FrameSourceError(f'no readable image in {name}: '
                               + '; '.join(f'{f.name}: {why}' for f, why in self.skipped[:5]))

    def _load(self, path):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint8:
            self.skipped.append((path, 'not an 8-bit image OpenCV can read'))
            return None
        if self.size is not None and _size(image) != self.size:
            self.skipped.append((path, f'{_size(image)[0]}x{_size(image)[1]} px, not '
                                       f'{self.size[0]}x{self.size[1]}'))
            return None
        return image

    def _next(self):
        # A file that fails is dropped from the list, so a looping folder names it once
        # and a folder whose every file became unreadable ends instead of spinning.
        while self.files:
            if self._index >= len(self.files):
                if not self.loop:
                    return None
                self._index = 0
            image = self._load(self.files[self._index])
            if image is None:
                del self.files[self._index]
                continue
            self._index += 1
            return _convert(image, self.encoding)
        return None


def jpeg_payload(frame, encoding, quality=90):
    """(format, bytes) of a frame as image_transport's `compressed` transport sends it:
    JPEG, format '<encoding>; jpeg compressed <encoding>' (bgr8 or mono8)."""
    ok, buf = cv2.imencode('.jpg', frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise FrameSourceError(f'JPEG encoding of a {encoding} frame failed')
    return f'{encoding}; jpeg compressed {encoding}', buf.tobytes()


def device_target(source):
    """cv2 target of a device source (int index or /dev path), or None if not a device."""
    text = str(source).strip()
    if text.isdigit():
        return int(text)
    if text.startswith('/dev/'):
        return text
    return None


def open_frame_source(source, encoding='bgr8', loop=False, width=0, height=0):
    """Open `source` (see the module docstring); raises FrameSourceError."""
    text = str(source).strip()
    if not text:
        raise FrameSourceError('no source given: a device (/dev/video0 or 0), a video '
                               'file or a folder of images')
    device = device_target(text)
    if device is not None:
        if isinstance(device, str) and not pathlib.Path(device).exists():
            raise FrameSourceError(f'no camera device {device} (`v4l2-ctl --list-devices` '
                                   'lists the cameras)')
        name = f'/dev/video{device}' if isinstance(device, int) else device
        return CaptureSource(device, name, 'device', encoding, loop, width, height)
    path = pathlib.Path(text).expanduser()
    if path.is_dir():
        files = sorted(p for p in path.iterdir()
                       if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise FrameSourceError(f'folder {path} has no images '
                                   f"({', '.join(IMAGE_SUFFIXES)})")
        return FolderSource(files, str(path), encoding, loop)
    if not path.exists():
        raise FrameSourceError(f'{path} does not exist (a device, video file or folder '
                               'of images)')
    if not path.is_file():
        raise FrameSourceError(f'{path} is neither a file nor a folder')
    try:
        with open(path, 'rb') as stream:
            stream.read(1)
    except OSError as error:
        raise FrameSourceError(f'cannot read {path}: {error.strerror}') from None
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return FolderSource([path], str(path), encoding, loop)
    return CaptureSource(str(path), str(path), 'video file', encoding, loop)


__all__ = ['ENCODINGS', 'IMAGE_SUFFIXES', 'CaptureSource', 'FolderSource', 'FrameSource',
           'FrameSourceError', 'device_target', 'jpeg_payload', 'open_frame_source']
