"""The perception nodes over real DDS: bad input is skipped, counted in /diagnostics and
logged clearly (both read as ROS messages: /diagnostics and /rosout); bad parameters are
refused; compressed images (image_transport's `compressed` topic) give
the same detections as raw ones. A rendered image in, the right aspect observation out:
abp_bench/test/test_perception_nodes_on_scenes.py."""

import importlib
import os
import time

import cv2
import numpy as np
import pytest
from tag_scene import render_tags, tag_pose

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')
if not hasattr(pytest.importorskip('abp_msgs.msg'), 'AspectObservation'):
    pytest.skip('abp_msgs is not built: run scripts/bootstrap.sh and source scripts/env.sh',
                allow_module_level=True)

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # noqa: E402

from abp_common import names, qos  # noqa: E402
from abp_common.health import DIAGNOSTICS  # noqa: E402
from abp_description import camera_intrinsics  # noqa: E402
from abp_msgs.msg import TagDetectionArray  # noqa: E402

# /diagnostics every 0.2 s (default 1 s): the tests wait for its counts; every rejected
# input logged (by default one per kind and topic every 5 s, as the count goes on).
FAST_DIAGNOSTICS = ['--ros-args', '-p', 'diagnostics_period:=0.2',
                    '-p', 'reject_log_period:=0.0']
# As rclpy's /rosout publisher: reliable, transient local.
ROSOUT = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)


def executable(name):
    prefix = ament_index.get_package_prefix('abp_perception')
    return os.path.join(prefix, 'lib', 'abp_perception', name)


def camera_info_msg(cam):
    msg = CameraInfo(width=cam.width, height=cam.height, distortion_model='plumb_bob')
    msg.header.frame_id = cam.frame_id
    msg.k = [float(v) for v in cam.K.ravel()]
    msg.d = [float(v) for v in cam.D]
    msg.p = [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def image_msg(gray, frame_id, stamp, encoding='mono8', bytes_per_pixel=1):
    h, w = gray.shape[0], gray.shape[1] // bytes_per_pixel
    msg = Image(height=h, width=w, encoding=encoding, step=gray.shape[1], is_bigendian=0)
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.data = gray.tobytes()
    return msg


def compressed_msg(payload, fmt, frame_id, stamp):
    msg = CompressedImage(format=fmt)
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.data = bytes(payload)
    return msg


class Rejections:
    """What the detector says of the input it rejects, as ROS messages: its counts by topic
    and kind on /diagnostics (abp_common.health: `rejected <topic> <kind>`) and its log
    lines on /rosout."""

    def __init__(self, node, name='artag_detector'):
        self.name = name
        self.counts = {}
        self.logs = []
        node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 10)
        node.create_subscription(Log, '/rosout', self._on_log, ROSOUT)

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.endswith(f'{self.name}: health'):
                self.counts.update({kv.key: int(kv.value) for kv in status.values
                                    if kv.key.startswith('rejected ')})

    def _on_log(self, msg):
        if msg.name == self.name:
            self.logs.append(msg.msg)

    def publish_until_rejected(self, executor, spin, publish, topic, kind, text,
                               timeout=60.0):
        """Publish until /diagnostics counts one more `kind` rejected on `topic` (large
        best-effort samples can be lost, right after discovery or on a loaded machine,
        so one publish may not do); returns the log line with `text` that said why."""
        key = f'rejected {topic} {kind}'
        before = self.counts.get(key, 0)

        def said():
            return next((line for line in self.logs if text in line), None)

        def done():
            return self.counts.get(key, 0) > before and said() is not None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not done():
            publish()
            spin(executor, done, 0.3)
        assert self.counts.get(key, 0) > before, f'no {kind} rejection counted on {topic}'
        assert said() is not None, f'no log line with {text!r}: {self.logs}'
        return said()


def test_bad_input_is_skipped_with_a_clear_message(ros_processes, tester, spin):
    cam = camera_intrinsics()
    proc = ros_processes.start([executable('artag_detector'), *FAST_DIAGNOSTICS])
    node, executor = tester
    image_pub = node.create_publisher(Image, names.IMAGE, qos.SENSOR_DATA)
    info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA)
    detections = []
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    rejections = Rejections(node)
    assert spin(executor, lambda: image_pub.get_subscription_count() > 0, 30)
    gray = np.full((cam.height, cam.width), 128, np.uint8)

    def publish_until_logged(publish, kind, text):
        return rejections.publish_until_rejected(executor, spin, publish, names.IMAGE, kind,
                                                 text)

    # No camera_info yet: skipped with a warning.
    assert publish_until_logged(
        lambda: image_pub.publish(image_msg(gray, cam.frame_id, Time(sec=1))),
        'no_camera_info', 'no valid camera_info')

    # Unsupported encoding (a depth image): skipped with an error naming it.
    def bad_encoding():
        info_pub.publish(camera_info_msg(cam))
        image_pub.publish(image_msg(np.zeros((cam.height, cam.width * 4), np.uint8),
                                    cam.frame_id, Time(sec=2), encoding='32FC1',
                                    bytes_per_pixel=4))

    assert publish_until_logged(bad_encoding, 'encoding', "unsupported image encoding '32FC1'")

    # An image of another size than camera_info's: rejected naming both, and counted.
    def scaled():
        info_pub.publish(camera_info_msg(cam))
        image_pub.publish(image_msg(np.full((2 * cam.height, 2 * cam.width), 128, np.uint8),
                                    cam.frame_id, Time(sec=2)))

    line = publish_until_logged(
        scaled, 'size', f'image is {2 * cam.width}x{2 * cam.height} px but the camera '
        f'intrinsics (camera_info) are for {cam.width}x{cam.height} px')
    assert 'size on this topic so far' in line
    assert detections == []
    # A good image without joint states: published in the camera frame, still running.
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        info_pub.publish(camera_info_msg(cam))
        image_pub.publish(image_msg(gray, cam.frame_id, Time(sec=3)))
        if spin(executor, lambda: detections, 0.3):
            break
    assert detections and detections[-1].header.frame_id == cam.frame_id
    assert detections[-1].detections == []
    assert proc.poll() is None


def test_compressed_images_give_detections_and_bad_ones_are_rejected(ros_processes, tester,
                                                                     spin):
    cam = camera_intrinsics()
    proc = ros_processes.start([executable('artag_detector'), *FAST_DIAGNOSTICS,
                                '-p', 'image_transport:=compressed'])
    node, executor = tester
    topic = names.IMAGE + '/compressed'
    image_pub = node.create_publisher(CompressedImage, topic, qos.SENSOR_DATA)
    info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA)
    detections = []
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    assert spin(executor, lambda: image_pub.get_subscription_count() > 0
                and info_pub.get_subscription_count() > 0
                and node.count_publishers(names.TAG_DETECTIONS) > 0, 30)
    assert node.count_subscribers(names.IMAGE) == 0             # not the raw topic

    tags = {3: tag_pose([-0.1, 0.0, 0.7], 25.0), 8: tag_pose([0.12, 0.05, 0.9], -15.0)}
    scene = render_tags(cam.K, cam.width, cam.height, list(tags.items()), 0.08)
    colour = cv2.cvtColor(scene, cv2.COLOR_GRAY2RGB)             # an rgb8 camera
    _, jpeg = cv2.imencode('.jpg', colour[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 80])
    _, big = cv2.imencode('.png', cv2.resize(scene, (2 * cam.width, 2 * cam.height)))

    def publish(payload, fmt, sec):
        info_pub.publish(camera_info_msg(cam))
        image_pub.publish(compressed_msg(payload, fmt, cam.frame_id, Time(sec=sec)))

    rejections = Rejections(node)

    def publish_until_logged(publish, kind, text):
        return rejections.publish_until_rejected(executor, spin, publish, topic, kind, text)

    # A corrupt payload (a truncated JPEG): rejected with a warning and counted.
    line = publish_until_logged(
        lambda: publish(jpeg.tobytes()[:5000], 'rgb8; jpeg compressed bgr8', 1),
        'decode', 'is corrupt or truncated')
    assert 'decode on this topic so far' in line
    # Garbage that is not JPEG at all, and a frame of another size than camera_info's.
    assert publish_until_logged(
        lambda: publish(bytes(range(256)) * 40, 'mono8; jpeg compressed mono8', 2),
        'decode', 'is not JPEG data')
    assert publish_until_logged(
        lambda: publish(big.tobytes(), 'mono8; png compressed mono8', 3),
        'size', f'image is {2 * cam.width}x{2 * cam.height} px but the camera intrinsics')
    assert detections == [] and proc.poll() is None

    # A good JPEG frame: both tags, where they are (camera frame: no joint states).
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and not detections:
        publish(jpeg.tobytes(), 'rgb8; jpeg compressed bgr8', 4)
        spin(executor, lambda: detections, 0.3)
    assert detections, 'no detections from compressed frames'
    out = detections[-1]
    assert out.header.stamp.sec == 4 and out.header.frame_id == cam.frame_id
    found = {d.id: d for d in out.detections}
    assert sorted(found) == [3, 8]
    for tag_id, pose in tags.items():
        p = found[tag_id].pose.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], pose[:3, 3], atol=0.01)
    assert proc.poll() is None


def test_frames_between_full_searches_are_tracked_and_counted(ros_processes, tester, spin):
    cam = camera_intrinsics()
    proc = ros_processes.start([executable('artag_detector'), *FAST_DIAGNOSTICS,
                                '-p', 'full_frame_every:=4'])
    node, executor = tester
    image_pub = node.create_publisher(Image, names.IMAGE, qos.SENSOR_DATA)
    info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA)
    detections, frames = [], {}

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name.endswith('artag_detector: health'):
                frames.update({kv.key: int(kv.value) for kv in status.values
                               if kv.key.startswith('frames searched: ')})

    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diagnostics, 10)
    assert spin(executor, lambda: image_pub.get_subscription_count() > 0
                and info_pub.get_subscription_count() > 0
                and node.count_publishers(names.TAG_DETECTIONS) > 0, 30)
    tags = {3: tag_pose([-0.1, 0.0, 0.7], 25.0), 8: tag_pose([0.12, 0.05, 0.9], -15.0)}
    scene = render_tags(cam.K, cam.width, cam.height, list(tags.items()), 0.08)
    # A still camera: the same view, frame after frame, until the node has reported
    # frames it tracked (3 of every 4) and whole-image searches (1 of every 4).
    sec = 10
    deadline = time.monotonic() + 90.0
    while time.monotonic() < deadline and not (
            frames.get('frames searched: tracked', 0) >= 3
            and frames.get('frames searched: whole image', 0) >= 1):
        sec += 1
        info_pub.publish(camera_info_msg(cam))
        image_pub.publish(image_msg(scene, cam.frame_id, Time(sec=sec)))
        spin(executor, lambda: False, 0.1)
    assert frames.get('frames searched: tracked', 0) >= 3, frames
    assert frames.get('frames searched: region', 0) == 0, frames   # nothing was lost
    # Every frame, tracked or searched, gave both tags where they are.
    assert len(detections) >= 4
    for out in detections:
        found = {d.id: d.pose.pose.position for d in out.detections}
        assert sorted(found) == [3, 8]
        for tag_id, pose in tags.items():
            p = found[tag_id]
            np.testing.assert_allclose([p.x, p.y, p.z], pose[:3, 3], atol=0.01)
    # track_tags off at run time: the frames between are searched with ArUco again.
    client = node.create_client(SetParameters, '/artag_detector/set_parameters')
    assert spin(executor, client.service_is_ready, 30)
    future = client.call_async(SetParameters.Request(parameters=[
        Parameter('track_tags', value=False).to_parameter_msg()]))
    assert spin(executor, future.done, 30) and future.result().results[0].successful
    deadline = time.monotonic() + 90.0
    while time.monotonic() < deadline and frames.get('frames searched: region', 0) < 3:
        sec += 1
        image_pub.publish(image_msg(scene, cam.frame_id, Time(sec=sec)))
        spin(executor, lambda: False, 0.1)
    assert frames.get('frames searched: region', 0) >= 3, frames
    assert proc.poll() is None


def test_a_driver_frame_yuv422_and_rectified_images_give_the_right_poses(ros_processes,
                                                                        tester, spin):
    # A camera driver's own frame name, mapped; UYVY (yuv422) frames; image_proc's
    # rectified images: P is the camera, and the (large) D must not be applied again.
    cam = camera_intrinsics()
    driver_frame = 'camera_color_optical_frame'
    proc = ros_processes.start([
        executable('artag_detector'), *FAST_DIAGNOSTICS,
        '-p', f"frame_map:=['{driver_frame}:camera_optical_frame']",
        '-p', 'image_is_rectified:=true'])
    node, executor = tester
    image_pub = node.create_publisher(Image, names.IMAGE, qos.SENSOR_DATA)
    info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA)
    detections = []
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    assert spin(executor, lambda: image_pub.get_subscription_count() > 0
                and info_pub.get_subscription_count() > 0
                and node.count_publishers(names.TAG_DETECTIONS) > 0, 30)
    info = camera_info_msg(cam)
    info.header.frame_id = driver_frame
    info.k = [float(v) for v in (cam.K * [[0.8], [0.8], [1.0]]).ravel()]  # the raw camera
    info.d = [0.3, -0.2, 0.0, 0.0, 0.0]
    tags = {3: tag_pose([-0.1, 0.0, 0.7], 25.0), 8: tag_pose([0.12, 0.05, 0.9], -15.0)}
    scene = render_tags(cam.K, cam.width, cam.height, list(tags.items()), 0.08)
    uyvy = np.empty((cam.height, cam.width, 2), np.uint8)
    uyvy[..., 0], uyvy[..., 1] = 128, scene                     # U/V, Y
    packed = uyvy.reshape(cam.height, 2 * cam.width)

    def publish(frame_id, sec):
        info_pub.publish(info)
        image_pub.publish(image_msg(packed, frame_id, Time(sec=sec), encoding='yuv422',
                                    bytes_per_pixel=2))

    # A frame neither mapped nor in the URDF: refused, naming the parameter to set.
    assert Rejections(node).publish_until_rejected(
        executor, spin, lambda: publish('usb_cam', 1), names.IMAGE, 'frame',
        "frame 'usb_cam' is not a frame of the URDF: map it")
    assert detections == []
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and not detections:
        publish(driver_frame, 2)
        spin(executor, lambda: detections, 0.3)
    assert detections, 'no detections from yuv422 frames in the driver frame'
    out = detections[-1]
    assert out.header.frame_id == driver_frame and out.camera_frame_id == driver_frame
    found = {d.id: d.pose.pose.position for d in out.detections}
    assert sorted(found) == [3, 8]
    for tag_id, pose in tags.items():
        p = found[tag_id]
        np.testing.assert_allclose([p.x, p.y, p.z], pose[:3, 3], atol=0.01)
    assert proc.poll() is None


NODE_MODULES = {'artag_detector': 'abp_perception.artag_detector_node',
                'aspect_matcher': 'abp_perception.aspect_matcher_node'}


@pytest.mark.parametrize('name, override, expected', [
    ('artag_detector', 'dictionary:=DICT_BOGUS', 'DICT_APRILTAG_36h11'),
    ('artag_detector', 'image_transport:=theora', 'image_transport'),
    ('artag_detector', 'marker_size:=0.0', 'marker_size'),
    ('artag_detector', 'full_frame_every:=0', 'full_frame_every'),
    ('artag_detector', "frame_map:=['cam:no_such_link']", 'frame_map'),
    ('artag_detector', 'joint_state_lookup:=nearest', 'joint_state_lookup'),
    ('aspect_matcher', 'model_set:=bogus', 'model_set'),
    ('aspect_matcher', 'model_file:=/nonexistent/models.npz', 'models.npz'),
])
def test_bad_parameters_are_refused_clearly(name, override, expected, main_in_process):
    """The executable's main() in this process (the exit code of a process start-up is
    checked once, in test_sim_bridge_node.py)."""
    main = importlib.import_module(NODE_MODULES[name]).main
    code, stderr = main_in_process(main, '-p', override)
    assert code == 2, stderr
    assert 'configuration error' in stderr and expected in stderr
    assert 'Traceback' not in stderr


def test_nodes_under_a_namespace_use_its_topics(ros_processes, tester, spin):
    ros_processes.start([executable('artag_detector'), '--ros-args', '-r', '__ns:=/robot1'])
    ros_processes.start([executable('aspect_matcher'), '--ros-args', '-r', '__ns:=/robot1'])
    node, executor = tester
    assert spin(executor, lambda: node.count_publishers('/robot1/abp/aspect_observation') > 0
                and node.count_publishers('/robot1/abp/tag_detections') > 0
                and node.count_subscribers('/robot1/camera/image_raw') > 0, 30)
    assert node.count_publishers('/abp/tag_detections') == 0
    assert node.count_subscribers('/camera/image_raw') == 0
