"""ROS 2 wiring of the tag detector: the `artag_detector` node.

Subscribes:  camera/image_raw   (sensor_msgs/Image, sensor-data QoS), with
             `image_transport: raw` (the default), or
             camera/image_raw/compressed (sensor_msgs/CompressedImage, JPEG or PNG,
             image_transport's `compressed` convention, e.g. format
             'rgb8; jpeg compressed bgr8'; decoded with cv2.imdecode), with
             `image_transport: compressed`
             camera/camera_info (sensor_msgs/CameraInfo, sensor-data QoS)
             joint_states       (sensor_msgs/JointState; camera pose by forward kinematics)
Publishes:   abp/tag_detections (abp_msgs/TagDetectionArray, stamped with the image's
             header stamp; poses in `base_frame` once a joint state has arrived, else in
             the camera frame)

Topic names are relative (abp_common.names): under a namespace the node reads and
writes that namespace's topics. Parameters: `node_parameters.DETECTOR_SPECS`.
The science lives in `abp_perception.detector`; the camera pose in the base frame comes
from `abp_description.kinematics.RobotKinematics` (Pinocchio over joint_states, no tf2).
Frames are rejected, never crash the node, with a throttled warning that says why and
how many frames were rejected for that reason so far (`ArtagDetectorNode.rejected`):
no camera_info yet (`no_camera_info`), a size other than camera_info's, both sizes named
(`size`), an unsupported encoding or compressed format (`encoding`), a compressed
payload that does not decode (`decode`), or an image the detector refuses (`image`).
"""

import sys
import time
from collections import Counter

import cv2
import numpy as np
from geometry_msgs.msg import Point32
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState

from abp_common import names, qos
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.frames import quaternion_from_rotation
from abp_description.kinematics import RobotKinematics
from abp_msgs.msg import TagDetection, TagDetectionArray

from .detector import (
    ImageDecodeError,
    ImageEncodingError,
    ImageSizeError,
    TagDetector,
    check_image_size,
    compressed_msg_to_gray,
    image_msg_to_gray,
)
from .node_parameters import DETECTOR_PARAMETERS, DETECTOR_SPECS

THROTTLE_S = 5.0
DISTORTION_MODELS = ('plumb_bob', 'rational_polynomial', '')
COMPRESSED_SUFFIX = '/compressed'     # image_transport's topic of the compressed transport


class ArtagDetectorNode(Node):
    def __init__(self):
        super().__init__('artag_detector')
        self._values = declare_all(self, DETECTOR_SPECS)
        self.kinematics = RobotKinematics(self._values['urdf_file'] or None)
        self.base_frame = self._values['base_frame']
        self.camera_frame = self._values['camera_frame']
        if not self.kinematics.has_frame(self.camera_frame):
            raise ValueError(f'parameter camera_frame: no frame {self.camera_frame!r} in '
                             f'{self.kinematics.urdf_path}')
        self._config = {name: self._values[name] for name in DETECTOR_PARAMETERS}
        self.detector = None                 # built at the first camera_info
        self._camera_key = None
        self._joints = None
        self._warned_frames = set()
        self.rejected = Counter()            # reason -> frames rejected so far
        self._last_reject_log = {}           # reason -> time.monotonic() of its last line
        self._pub = self.create_publisher(TagDetectionArray, names.TAG_DETECTIONS,
                                          qos.RELIABLE)
        self.image_transport = self._values['image_transport']
        if self.image_transport == 'compressed':
            self.image_topic = names.IMAGE + COMPRESSED_SUFFIX
            self.create_subscription(CompressedImage, self.image_topic,
                                     self._on_compressed_image, qos.SENSOR_DATA)
        else:
            self.image_topic = names.IMAGE
            self.create_subscription(Image, self.image_topic, self._on_image,
                                     qos.SENSOR_DATA)
        self.create_subscription(CameraInfo, names.CAMERA_INFO, self._on_camera_info,
                                 qos.SENSOR_DATA)
        self.create_subscription(JointState, names.JOINT_STATES, self._on_joint_state,
                                 qos.SENSOR_DATA)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"detecting {self._values['dictionary']} tags of {self._config['marker_size']} m "
            f'in {self.image_transport} images on {self.resolve_topic_name(self.image_topic)}; '
            f'poses in {self.base_frame} via {self.camera_frame} forward kinematics')

    # -- parameters ---------------------------------------------------------------
    def _build_detector(self, config, camera_matrix, dist_coeffs, image_size=None):
        return TagDetector(camera_matrix, dist_coeffs, dictionary=self._values['dictionary'],
                           camera_frame=self.camera_frame, image_size=image_size, **config)

    def _on_set_parameters(self, params):
        changes = {p.name: p.value for p in params if p.name in DETECTOR_PARAMETERS}
        if not changes:
            return SetParametersResult(successful=True)
        config = dict(self._config, **changes)
        try:
            if self.detector is not None:
                detector = self._build_detector(config, self.detector.camera_matrix,
                                                self.detector.dist_coeffs,
                                                self.detector.image_size)
            else:
                detector = None
                self._build_detector(config, np.diag([500.0, 500.0, 1.0]), None)
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        self._config = config
        if detector is not None:
            self.detector = detector
        return SetParametersResult(successful=True)

    # -- callbacks ----------------------------------------------------------------
    def _on_camera_info(self, msg: CameraInfo):
        k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
        d = np.asarray(msg.d, dtype=np.float64)
        key = (tuple(k.ravel()), tuple(d), msg.distortion_model)
        if msg.distortion_model not in DISTORTION_MODELS:
            self.get_logger().warning(
                f"camera_info distortion model {msg.distortion_model!r} is not supported "
                f"(use {', '.join(m for m in DISTORTION_MODELS if m)}); images skipped",
                throttle_duration_sec=THROTTLE_S)
            return
        # A camera_info without a size (0 x 0) leaves the image size unchecked.
        size = (int(msg.width), int(msg.height)) if msg.width and msg.height else None
        key += (size,)
        if key == self._camera_key:
            return
        try:
            self.detector = self._build_detector(self._config, k, d if d.size else None, size)
        except ValueError as error:
            self.get_logger().warning(f'camera_info refused: {error}; images skipped',
                                      throttle_duration_sec=THROTTLE_S)
            return
        self._camera_key = key

    def _on_joint_state(self, msg: JointState):
        if len(msg.name) != len(msg.position):
            self.get_logger().warning('joint_states with names and positions of different '
                                      'lengths ignored', throttle_duration_sec=THROTTLE_S)
            return
        joints = dict(zip(msg.name, msg.position))
        self._joints = self.kinematics.q_from_mapping(
            joints, default=self._joints if self._joints is not None else None)

    def _reject(self, reason, text, error=False):
        """Count a rejected frame and say why, at most once per THROTTLE_S per reason
        (rclpy's own throttle is per call site: one reason would hide the others)."""
        self.rejected[reason] += 1
        now = time.monotonic()
        if now - self._last_reject_log.get(reason, -np.inf) < THROTTLE_S:
            return
        self._last_reject_log[reason] = now
        n = self.rejected[reason]
        line = f'{text}: frame rejected ({n} {reason} rejection{"s" if n > 1 else ""} so far)'
        # Two call sites: rclpy refuses one call site logging at two severities.
        if error:
            self.get_logger().error(line)
        else:
            self.get_logger().warning(line)

    def _ready(self):
        if self.detector is None:
            self._reject('no_camera_info', 'no valid camera_info on '
                         f'{self.resolve_topic_name(names.CAMERA_INFO)} yet')
            return False
        return True

    def _on_image(self, msg: Image):
        if not self._ready():
            return
        try:
            # Before converting: a mismatched frame costs nothing.
            check_image_size(msg.width, msg.height, self.detector.image_size)
            gray = image_msg_to_gray(msg)
        except ImageSizeError as error:
            self._reject('size', str(error))
            return
        except ImageEncodingError as error:
            self._reject('encoding', str(error), error=True)
            return
        self._detect_and_publish(gray, msg.header)

    def _on_compressed_image(self, msg: CompressedImage):
        if not self._ready():
            return
        try:
            gray = compressed_msg_to_gray(msg)
        except ImageDecodeError as error:
            self._reject('decode', str(error))
            return
        except ImageEncodingError as error:
            self._reject('encoding', str(error), error=True)
            return
        self._detect_and_publish(gray, msg.header)

    def _detect_and_publish(self, gray, header):
        try:
            result = self.detector.detect(gray)
        except ImageSizeError as error:
            self._reject('size', str(error))
            return
        except ValueError as error:
            self._reject('image', str(error))
            return
        except cv2.error as error:                # not expected: a frame never ends the node
            self._reject('image', f'OpenCV failed on the image: {error.msg.strip()}',
                         error=True)
            return
        for dropped in result.dropped:
            self.get_logger().debug(f'tag {dropped.tag_id} dropped: {dropped.reason}')
        frame = self._camera_frame_of(header.frame_id)
        if self._joints is not None:
            result = result.in_frame(self.kinematics.frame_pose(self._joints, frame),
                                     self.base_frame)
            out_frame = self.base_frame
        else:
            self.get_logger().warning(
                f'no {self.resolve_topic_name(names.JOINT_STATES)} yet: detections published '
                'in the camera frame', throttle_duration_sec=THROTTLE_S)
            out_frame = header.frame_id or frame
        self._pub.publish(self._to_msg(result, header, out_frame))

    def _camera_frame_of(self, frame_id):
        if frame_id and self.kinematics.has_frame(frame_id):
            return frame_id
        if frame_id not in self._warned_frames:
            self._warned_frames.add(frame_id)
            self.get_logger().warning(f'image frame {frame_id!r} is not in the URDF; using '
                                      f'{self.camera_frame}')
        return self.camera_frame

    @staticmethod
    def _to_msg(result, header, frame):
        out = TagDetectionArray()
        out.header.stamp = header.stamp
        out.header.frame_id = frame
        out.camera_frame_id = header.frame_id
        for det in result.detections:
            msg = TagDetection()
            msg.id = int(det.tag_id)
            p = msg.pose.pose
            p.position.x, p.position.y, p.position.z = (float(v) for v in det.pose[:3, 3])
            qx, qy, qz, qw = quaternion_from_rotation(det.pose[:3, :3])
            p.orientation.x, p.orientation.y = float(qx), float(qy)
            p.orientation.z, p.orientation.w = float(qz), float(qw)
            msg.pose.covariance = [float(v) for v in det.covariance.ravel()]
            msg.corners = [Point32(x=float(x), y=float(y), z=0.0) for x, y in det.corners]
            msg.marker_size = float(det.marker_size)
            msg.reprojection_error = float(det.reprojection_error)
            msg.confidence = float(det.confidence)
            out.detections.append(msg)
        return out


def main(args=None):
    return run_node('artag_detector', ArtagDetectorNode, args,
                    config_errors=(FileNotFoundError,))


if __name__ == '__main__':
    sys.exit(main())
