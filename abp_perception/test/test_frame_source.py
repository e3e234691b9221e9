"""The camera node's science without ROS: frame sources (real OpenCV files) and
camera_calibration YAML files."""

import cv2
import numpy as np
import pytest

from abp_description import camera_yaml_path
from abp_perception.camera_calibration_file import (
    CalibrationFileError,
    check_image_size,
    save,
)
from abp_perception.camera_calibration_file import load as load_calibration
from abp_perception.frame_source import (
    FrameSourceError,
    jpeg_payload,
    open_frame_source,
)


def frames(n, width=64, height=48):
    """n distinct BGR frames (frame i is filled with grey level 20 * i + 10)."""
    return [np.full((height, width, 3), 20 * i + 10, np.uint8) for i in range(n)]


def write_folder(folder, images, suffix='.png'):
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f'frame_{i:03d}{suffix}'), image)
    return folder


def test_a_folder_plays_in_name_order_and_ends_or_loops(tmp_path):
    folder = write_folder(tmp_path / 'f', frames(3))
    (folder / 'notes.txt').write_text('not an image')       # ignored: not an image suffix
    source = open_frame_source(folder, 'mono8')
    assert source.size == (64, 48) and source.kind == 'folder'
    levels = [int(source.read()[0, 0]) for _ in range(3)]
    assert levels == [10, 30, 50]
    assert source.read() is None and source.frames_read == 3
    looping = open_frame_source(folder, 'bgr8', loop=True)
    got = [looping.read() for _ in range(7)]
    assert [int(f[0, 0, 0]) for f in got] == [10, 30, 50, 10, 30, 50, 10]
    assert got[0].shape == (48, 64, 3)


def test_a_folder_skips_a_broken_or_resized_image_once(tmp_path):
    folder = write_folder(tmp_path / 'f', frames(2) + [np.zeros((10, 10, 3), np.uint8)])
    (folder / 'frame_001b.png').write_bytes(b'\x89PNG broken')
    source = open_frame_source(folder, 'mono8', loop=True)
    levels = [int(source.read()[0, 0]) for _ in range(5)]
    assert levels == [10, 30, 10, 30, 10]
    assert sorted(p.name for p, _ in source.skipped) == ['frame_001b.png', 'frame_002.png']
    assert '10x10 px, not 64x48' in dict((p.name, w) for p, w in source.skipped)[
        'frame_002.png']


def test_a_video_file_plays_and_loops(tmp_path):
    path = tmp_path / 'clip.avi'
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*'MJPG'), 10, (64, 48))
    assert writer.isOpened()
    for image in frames(4):
        writer.write(image)
    writer.release()
    source = open_frame_source(path, 'bgr8')
    assert source.kind == 'video file' and source.size == (64, 48)
    got = [source.read() for _ in range(4)]
    assert [abs(int(f[0, 0, 0]) - (20 * i + 10)) <= 3 for i, f in enumerate(got)] == [True] * 4
    assert source.read() is None
    source.close()
    looping = open_frame_source(path, 'bgr8', loop=True)
    assert all(looping.read() is not None for _ in range(9))


@pytest.mark.parametrize('make, expected', [
    (lambda p: p / 'missing', 'does not exist'),
    (lambda p: (p / 'empty').mkdir() or p / 'empty', 'has no images'),
    (lambda p: (p / 'bad.mp4').write_text('not a video') and p / 'bad.mp4',
     'cannot open video file'),
    (lambda p: (p / 'bad.png').write_bytes(b'junk') and p / 'bad.png', 'no readable image'),
    (lambda p: '/dev/video97', 'no camera device /dev/video97'),
    (lambda p: '', 'no source given'),
])
def test_bad_sources_are_refused_with_the_reason(tmp_path, make, expected):
    with pytest.raises(FrameSourceError, match=expected):
        open_frame_source(make(tmp_path))


def test_a_device_index_without_a_camera_is_refused():
    # Index 97: no machine this runs on has 98 cameras.
    with pytest.raises(FrameSourceError, match='no camera device /dev/video97'):
        open_frame_source('97')


def test_jpeg_payload_follows_the_compressed_transport():
    image = frames(1)[0]
    fmt, data = jpeg_payload(image, 'bgr8', 95)
    assert fmt == 'bgr8; jpeg compressed bgr8' and data[:2] == b'\xff\xd8'
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert np.abs(decoded.astype(int) - image).max() <= 2


def test_the_sim_camera_calibration_loads_and_round_trips(tmp_path):
    calibration = load_calibration(camera_yaml_path())
    assert calibration.size == (640, 480) and calibration.distortion_model == 'plumb_bob'
    assert calibration.K[0, 0] == pytest.approx(554.256) and calibration.P.shape == (3, 4)
    path = tmp_path / 'cam.yaml'
    save(str(path), calibration)
    again = load_calibration(path)
    for field in ('K', 'D', 'R', 'P'):
        assert np.array_equal(getattr(again, field), getattr(calibration, field)), field
    assert again.size == calibration.size

    class Info:                        # anything with CameraInfo's fields
        pass
    info = calibration.fill(Info())
    assert (info.width, info.height, list(info.k)) == (640, 480,
                                                       calibration.K.ravel().tolist())
    check_image_size(calibration, (640, 480))
    with pytest.raises(CalibrationFileError, match='calibration is for 640x480 px but '
                                                   'the frames are 320x240 px'):
        check_image_size(calibration, (320, 240))


@pytest.mark.parametrize('text, expected', [
    ('image_width: 640\n', 'image_width and image_height must be integers'),
    ('image_width: 640\nimage_height: 480\n', 'camera_matrix is missing'),
    ('image_width: 640\nimage_height: 480\ncamera_matrix: {data: [1, 2]}\n',
     'camera_matrix needs 9 finite numbers, has 2'),
    ('image_width: 640\nimage_height: 480\ncamera_matrix: {data: [0,0,1,0,0,1,0,0,1]}\n'
     'distortion_coefficients: {data: []}\n', 'focal lengths must be > 0'),
    ('image_width: 640\nimage_height: 480\ncamera_matrix: {data: [5,0,1,0,5,1,0,0,1]}\n'
     'distortion_model: fisheye9\n', "distortion_model 'fisheye9' is not one of"),
    ('image_width: 640\nimage_height: 480\ncamera_matrix: {data: [5,0,1,0,5,1,0,0,1]}\n'
     'distortion_coefficients: {data: [1, 2, 3]}\n', 'plumb_bob has 5 distortion '
     'coefficients, the file gives 3'),
    ('[1, 2', 'not YAML'),
])
def test_bad_calibration_files_are_refused_naming_the_field(tmp_path, text, expected):
    path = tmp_path / 'cam.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match=expected):
        load_calibration(path)
    with pytest.raises(CalibrationFileError, match='cannot read'):
        load_calibration(tmp_path / 'nope.yaml')


def test_a_minimal_calibration_gets_identity_r_and_p_from_k(tmp_path):
    path = tmp_path / 'cam.yaml'
    path.write_text('image_width: 8\nimage_height: 6\n'
                    'camera_matrix: {rows: 3, cols: 3, data: [5, 0, 4, 0, 6, 3, 0, 0, 1]}\n'
                    'distortion_coefficients: {data: []}\n')
    calibration = load_calibration(path)
    assert np.array_equal(calibration.R, np.eye(3))
    assert np.array_equal(calibration.P, [[5, 0, 4, 0], [0, 6, 3, 0], [0, 0, 1, 0]])
