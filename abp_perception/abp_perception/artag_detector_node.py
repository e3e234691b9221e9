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
Between full-frame passes (every `full_frame_every` frames) the last frame's tags are
found again where they were (`track_tags`) and ArUco searches only around them when one
is lost (`detector.RegionSearch`).
The science lives in `abp_perception.detector`; the camera pose in the base frame comes
from `abp_description.kinematics.RobotKinematics` (Pinocchio over joint_states, no tf2).
Inputs are rejected, never crash the node, counted in /diagnostics by topic and kind
(`abp_common.health`) and logged at most once per few seconds per kind, saying why and
how many so far. Frames: no camera_info yet (`no_camera_info`), a size other than
camera_info's, both sizes named (`size`), size, step and data length that disagree
(`size_mismatch`), an unsupported encoding or compressed format (`encoding`), a
compressed payload that does not decode (`decode`), a frame id that is not in the URDF
(`frame`), a stamp from the past or the future (`stamp_past`, `stamp_future`), or an
image the detector refuses (`image`). camera_info and joint_states: the kinds of
`abp_common.input_checks`.
"""

import sys

import cv2
import numpy as np
from geometry_msgs.msg import Point32
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState

from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.frames import quaternion_from_rotation
from abp_description.kinematics import RobotKinematics
from abp_msgs.msg import TagDetection, TagDetectionArray

from .detector import (
    ImageDecodeError,
    ImageEncodingError,
    ImageLayoutError,
    ImageSizeError,
    RegionSearch,
    TagDetector,
    check_image_size,
    compressed_msg_to_gray,
    image_msg_to_gray,
)
from .node_parameters import DETECTOR_PARAMETERS, DETECTOR_SPECS

THROTTLE_S = 5.0
# distortion model -> the numbers of coefficients it takes ('' = none given)
DISTORTION_MODELS = {'plumb_bob': (0, 4, 5), 'rational_polynomial': (0, 8), '': (0,)}
COMPRESSED_SUFFIX = '/compressed'     # image_transport's topic of the compressed transport


class ArtagDetectorNode(ManagedNode):
    """Configure reads the parameters and the URDF; activate opens the topics."""

    def __init__(self):
        super().__init__('artag_detector')

    def configure(self):
        self._values = declare_all(self, DETECTOR_SPECS)
        self.kinematics = RobotKinematics(self._values['urdf_file'] or None)
        self.base_frame = self._values['base_frame']
        self.camera_frame = self._values['camera_frame']
        if not self.kinematics.has_frame(self.camera_frame):
            raise ValueError(f'parameter camera_frame: no frame {self.camera_frame!r} in '
                             f'{self.kinematics.urdf_path}')
        self._config = {name: self._values[name] for name in DETECTOR_PARAMETERS}
        self.detector = None                 # built at the first camera_info
        self.search = RegionSearch(self._values['full_frame_every'],
                                   track=self._values['track_tags'])
        self._camera_key = None
        self._joints = None
        self.health = NodeHealth(self)
        self.health.add_values(lambda: [(f'frames searched: {kind}', count)
                                        for kind, count in self.search.frames.items()])
        self._image_stamps = self.health.stamp_check()
        self.image_transport = self._values['image_transport']
        self.image_topic = names.IMAGE + (COMPRESSED_SUFFIX if self.image_transport ==
                                          'compressed' else '')
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"detecting {self._values['dictionary']} tags of {self._config['marker_size']} m "
            f'in {self.image_transport} images on {self.resolve_topic_name(self.image_topic)}; '
            f'poses in {self.base_frame} via {self.camera_frame} forward kinematics')

    def activate(self):
        self._pub = self.create_publisher(TagDetectionArray, names.TAG_DETECTIONS,
                                          qos.RELIABLE)
        if self.image_transport == 'compressed':
            self.health.subscribe(CompressedImage, self.image_topic,
                                  self._on_compressed_image, qos.SENSOR_DATA)
        else:
            self.health.subscribe(Image, self.image_topic, self._on_image, qos.SENSOR_DATA)
        self.health.subscribe(CameraInfo, names.CAMERA_INFO, self._on_camera_info,
                              qos.SENSOR_DATA)
        self.health.subscribe(JointState, names.JOINT_STATES, self._on_joint_state,
                              qos.SENSOR_DATA)

    # -- parameters ---------------------------------------------------------------
    def _build_detector(self, config, camera_matrix, dist_coeffs, image_size=None):
        return TagDetector(camera_matrix, dist_coeffs, dictionary=self._values['dictionary'],
                           camera_frame=self.camera_frame, image_size=image_size, **config)

    def _on_set_parameters(self, params):
        every = [int(p.value) for p in params if p.name == 'full_frame_every']
        if every and every[-1] < 1:
            return SetParametersResult(successful=False, reason='full_frame_every must be >= 1')
        track = [bool(p.value) for p in params if p.name == 'track_tags']
        changes = {p.name: p.value for p in params if p.name in DETECTOR_PARAMETERS}
        if not changes:
            self._set_search(every, track)
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
        self._set_search(every, track)
        return SetParametersResult(successful=True)

    def _set_search(self, every, track):
        """Apply accepted full_frame_every / track_tags values (lists, last one wins)."""
        if every:
            self.search.full_frame_every = every[-1]
        if track:
            self.search.track = track[-1]

    # -- callbacks ----------------------------------------------------------------
    def _on_camera_info(self, msg: CameraInfo):
        """Raises input_checks.Rejected for a malformed camera_info (NodeHealth counts it)."""
        k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
        d = np.asarray(msg.d, dtype=np.float64)
        if msg.distortion_model not in DISTORTION_MODELS:
            raise Rejected('unknown_id', f'distortion model {msg.distortion_model[:40]!r} is '
                                         'not supported (use '
                                         f"{', '.join(m for m in DISTORTION_MODELS if m)})")
        if d.size not in DISTORTION_MODELS[msg.distortion_model]:
            raise Rejected('size_mismatch', f'{d.size} distortion coefficients for '
                                            f'{msg.distortion_model!r}')
        input_checks.finite('camera matrix K', k)
        input_checks.finite('distortion coefficients', d)
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise Rejected('empty', 'camera matrix K without positive focal lengths')
        if msg.header.frame_id and not self.kinematics.has_frame(msg.header.frame_id):
            raise Rejected('frame', f'camera_info frame {msg.header.frame_id[:40]!r} is not in '
                                    'the URDF')
        key = (tuple(k.ravel()), tuple(d), msg.distortion_model)
        # A camera_info without a size (0 x 0) leaves the image size unchecked.
        size = (int(msg.width), int(msg.height)) if msg.width and msg.height else None
        key += (size,)
        if key == self._camera_key:
            return
        try:
            self.detector = self._build_detector(self._config, k, d if d.size else None, size)
        except ValueError as error:
            raise Rejected('out_of_range', f'camera_info refused: {error}') from None
        self._camera_key = key

    def _on_joint_state(self, msg: JointState):
        input_checks.joint_state(msg)
        joints = dict(zip(msg.name, msg.position))
        if not any(self.kinematics.has_joint(n) for n in joints):
            raise Rejected('unknown_id', 'joint_states names no joint of the robot')
        self._joints = self.kinematics.q_from_mapping(
            joints, default=self._joints if self._joints is not None else None)

    def _ready(self):
        if self.detector is None:
            raise Rejected('no_camera_info', 'no valid camera_info on '
                                             f'{self.resolve_topic_name(names.CAMERA_INFO)} yet')

    def _check_header(self, header):
        if header.frame_id and not self.kinematics.has_frame(header.frame_id):
            raise Rejected('frame', f'image frame {header.frame_id[:40]!r} is not in the URDF')
        self._image_stamps.check(header.stamp, self.health.now_ns())

    def _on_image(self, msg: Image):
        """Raises input_checks.Rejected for a frame it cannot use (NodeHealth counts it)."""
        self._ready()
        self._check_header(msg.header)
        try:
            # Before converting: a mismatched frame costs nothing.
            check_image_size(msg.width, msg.height, self.detector.image_size)
            gray = image_msg_to_gray(msg)
        except ImageSizeError as error:
            raise Rejected('size', str(error)) from None
        except ImageLayoutError as error:
            raise Rejected('size_mismatch', str(error)) from None
        except ImageEncodingError as error:
            raise Rejected('encoding', str(error)) from None
        self._image_stamps.taken(msg.header.stamp)
        self._detect_and_publish(gray, msg.header)

    def _on_compressed_image(self, msg: CompressedImage):
        self._ready()
        self._check_header(msg.header)
        try:
            gray = compressed_msg_to_gray(msg)
        except ImageDecodeError as error:
            raise Rejected('decode', str(error)) from None
        except ImageEncodingError as error:
            raise Rejected('encoding', str(error)) from None
        self._image_stamps.taken(msg.header.stamp)
        self._detect_and_publish(gray, msg.header)

    def _detect_and_publish(self, gray, header):
        try:
            with self.health.timed():
                result = self.search.detect(self.detector, gray)
        except ImageSizeError as error:
            raise Rejected('size', str(error)) from None
        except ValueError as error:
            raise Rejected('image', str(error)) from None
        except cv2.error as error:                # not expected: a frame never ends the node
            raise Rejected('image', f'OpenCV failed on the image: {error.msg.strip()}') \
                from None
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
        """The image's frame (checked to be in the URDF), or camera_frame when it has none."""
        return frame_id or self.camera_frame

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
