"""The `camera` node: frames from a folder or video file published over real DDS with
their camera_info (and JPEG), and the error paths (a missing device, an unreadable file,
an empty folder, a calibration of another image size) refused at configure: in the
test's own process through the lifecycle, and as `configuration error:` with exit code 2
from the installed executable. The MuJoCo frames through detector, matcher and belief:
abp_bench/test/test_camera_node_on_mujoco.py."""

import os

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # noqa: E402

from abp_common import names, qos  # noqa: E402
from abp_common.node_runner import CONFIGURATION_ERROR_EXIT_CODE  # noqa: E402
from abp_description import camera_yaml_path  # noqa: E402
from abp_perception.camera_node import CameraNode  # noqa: E402

WIDTH, HEIGHT = 640, 480


def executable():
    prefix = ament_index.get_package_prefix('abp_perception')
    return os.path.join(prefix, 'lib', 'abp_perception', 'camera')


def write_frames(folder, n, size=(WIDTH, HEIGHT)):
    """n frames whose pixel (0, 0) has blue level 10 + 20 i (frame i)."""
    folder.mkdir()
    for i in range(n):
        image = np.zeros((size[1], size[0], 3), np.uint8)
        image[..., 0] = 10 + 20 * i
        image[100:200, 100:300] = (0, 255, 255)
        cv2.imwrite(str(folder / f'{i:04d}.png'), image)
    return folder


@pytest.fixture
def bad_sources(tmp_path):
    """{case: (source, calibration, text the refusal must contain)}."""
    empty = tmp_path / 'empty'
    empty.mkdir()
    broken = tmp_path / 'broken.mp4'
    broken.write_bytes(b'\x00\x01 this is no video')
    small = write_frames(tmp_path / 'small', 2, (320, 240))
    calibration = str(camera_yaml_path())
    return {
        'missing device': ('/dev/video97', calibration, 'no camera device /dev/video97'),
        'missing index': ('97', calibration, 'no camera device /dev/video97'),
        'unreadable file': (str(broken), calibration, f'cannot open video file {broken}'),
        'empty folder': (str(empty), calibration, f'folder {empty} has no images'),
        'size mismatch': (str(small), calibration,
                          'the calibration is for 640x480 px but the frames of '
                          f'{small} are 320x240 px'),
        'missing calibration': (str(small), str(tmp_path / 'none.yaml'),
                                f"{tmp_path / 'none.yaml'}: cannot read"),
    }


CASES = ('missing device', 'missing index', 'unreadable file', 'empty folder',
         'size mismatch', 'missing calibration')


@pytest.mark.parametrize('case', CASES)
def test_configure_fails_with_the_reason(rclpy_context, bad_sources, case):
    source, calibration, expected = bad_sources[case]
    node = CameraNode(context=rclpy_context, parameter_overrides=[
        Parameter('autostart', value=False), Parameter('source', value=source),
        Parameter('calibration_file', value=calibration)])
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert expected in str(node.configuration_error)
        assert node.state_label() == 'unconfigured'
        assert node.source is None           # nothing left open
    finally:
        node.destroy_node()


def test_an_integer_source_is_a_device_index(rclpy_context):
    # `-p source:=0` gives an integer parameter: taken as /dev/video0's index.
    node = CameraNode(context=rclpy_context, parameter_overrides=[
        Parameter('autostart', value=False), Parameter('source', value=97)])
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert 'no camera device /dev/video97' in str(node.configuration_error)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('case', ('missing device', 'unreadable file', 'size mismatch'))
def test_the_executable_exits_with_a_configuration_error(bad_sources, case, main_in_process):
    """The executable's main() in this process (the exit code of a process start-up is
    checked once, in test_sim_bridge_node.py)."""
    from abp_perception.camera_node import main
    source, calibration, expected = bad_sources[case]
    code, stderr = main_in_process(main, '-p', f'source:={source}',
                                   '-p', f'calibration_file:={calibration}')
    assert code == CONFIGURATION_ERROR_EXIT_CODE, stderr
    assert f'[camera] configuration error: {expected}' in stderr


def test_a_folder_is_published_with_camera_info_and_jpeg(ros_processes, tester, spin,
                                                         tmp_path):
    folder = write_frames(tmp_path / 'frames', 3)
    proc = ros_processes.start([
        executable(), '--ros-args', '-p', f'source:={folder}',
        '-p', f'calibration_file:={camera_yaml_path()}', '-p', 'rate:=10.0',
        '-p', 'frame_id:=webcam_optical', '-p', 'publish_compressed:=true',
        '-p', 'loop:=true'])
    node, executor = tester
    images, infos, jpegs = [], [], []
    # Reliable readers, as the camera publishes (keep last 5: a loaded machine can still
    # overwrite a sample before this process takes it).
    node.create_subscription(Image, names.IMAGE, images.append, qos.CAMERA_PUBLISHER)
    node.create_subscription(CameraInfo, names.CAMERA_INFO, infos.append,
                             qos.CAMERA_PUBLISHER)
    node.create_subscription(CompressedImage, names.IMAGE + '/compressed', jpegs.append,
                             qos.CAMERA_PUBLISHER)

    def paired():
        """Images whose camera_info (same stamp) has arrived: the two topics come in
        either order, and a loaded machine may drop a sample of either (keep last 5)."""
        info_stamps = [i.header.stamp for i in infos]
        return [m for m in images if m.header.stamp in info_stamps]

    assert spin(executor, lambda: len(paired()) >= 8 and len(jpegs) >= 8, 60), \
        f'{len(images)} images, {len(infos)} infos, {len(jpegs)} jpegs: {proc.poll()}'
    image = images[-1]
    assert (image.width, image.height, image.encoding) == (WIDTH, HEIGHT, 'bgr8')
    assert image.header.frame_id == 'webcam_optical' and image.step == 3 * WIDTH
    pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(HEIGHT, WIDTH, 3)
    # Blue levels cycle through the folder in name order (loop): each frame is the next
    # file's, but for a rare sample lost under load.
    blues = [int(np.frombuffer(bytes(m.data[:1]), np.uint8)[0]) for m in images]
    assert set(blues) == {10, 30, 50}
    steps = [(b - a) // 20 % 3 for a, b in zip(blues, blues[1:])]
    assert steps.count(1) >= len(steps) - 2, blues
    assert tuple(pixels[150, 200]) == (0, 255, 255)
    info = [i for i in infos if i.header.stamp == paired()[-1].header.stamp]
    assert info and info[0].header.frame_id == 'webcam_optical'
    assert (info[0].width, info[0].height) == (WIDTH, HEIGHT)
    assert info[0].k[0] == pytest.approx(554.256) and info[0].distortion_model == 'plumb_bob'
    jpeg = jpegs[-1]
    assert jpeg.format == 'bgr8; jpeg compressed bgr8'
    decoded = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (HEIGHT, WIDTH, 3)
    stamps = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in images]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_a_file_without_loop_ends_after_its_frames(ros_processes, tester, spin, tmp_path):
    folder = write_frames(tmp_path / 'frames', 3)
    proc = ros_processes.start([
        executable(), '--ros-args', '-p', f'source:={folder}', '-p', 'encoding:=mono8',
        '-p', 'rate:=20.0'])
    # What the node says, read as its /rosout messages.
    node, executor = tester
    logs = []
    node.create_subscription(Log, '/rosout', lambda m: m.name == 'camera' and logs.append(m.msg),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    assert spin(executor, lambda: any(f'end of {folder}: 3 frames published' in line
                                      for line in logs), 60), logs
    assert any('no calibration_file' in line for line in logs)
    assert proc.poll() is None               # the node stays up, as a driver does
