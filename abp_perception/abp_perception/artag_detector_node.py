"""ROS 2 wiring of the tag detector: the `artag_detector` node.

Subscribes:  camera/image_raw   (sensor_msgs/Image, sensor-data QoS of depth 1: a frame
             that comes while the detector is busy replaces the waiting one), with
             `image_transport: raw` (the default), or
             camera/image_raw/compressed (sensor_msgs/CompressedImage, JPEG or PNG,
             image_transport's `compressed` convention, e.g. format
             'rgb8; jpeg compressed bgr8'; decoded with cv2.imdecode), with
             `image_transport: compressed`
             camera/camera_info (sensor_msgs/CameraInfo, sensor-data QoS)
             joint_states       (sensor_msgs/JointState, sensor-data QoS, on a thread
                                of its own (abp_common.input_node), so that a detection
                                in progress does not make the queue drop them; camera
                                pose by forward kinematics)
Publishes:   abp/tag_detections (abp_msgs/TagDetectionArray, stamped with the image's
             header stamp; poses in `base_frame` once a joint state has arrived, else in
             the camera frame)

Camera drivers as they are (docs/CAMERA.md): a frame_id is resolved to a URDF frame by
`frame_map` (`camera_model.FrameMap`); `image_is_rectified` takes P as the intrinsics and
leaves D out; the encodings of `image_encodings` are converted; the camera pose is the
forward kinematics of the joint state interpolated at the image stamp from the last
`joint_state_buffer_s` of joint_states (`joint_state_buffer.JointStateBuffer`; only the
joints that move the camera frame must be buffered around the stamp).

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
compressed payload that does not decode (`decode`), a frame id neither mapped by
`frame_map` nor in the URDF (`frame`), a stamp from the past or the future (`stamp_past`,
`stamp_future`), a stamp the buffered joint states do not reach (`joint_state_stamp`), or
an image the detector refuses (`image`). camera_info and joint_states: the kinds of
`abp_common.input_checks`.
"""

import sys

import cv2
import numpy as np
from geometry_msgs.msg import Point32
from rcl_interfaces.msg import SetParametersResult
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
)
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState

from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected, stamp_ns
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.frames import quaternion_from_rotation
from abp_description.kinematics import RobotKinematics
from abp_description.robot_profile import load_profile
from abp_msgs.msg import TagDetection, TagDetectionArray

from .camera_model import (
    FrameMap,
    UnknownFrame,
    fixed_camera_pose,
    intrinsics_from_camera_info,
    rectified_to_camera,
)
from .camera_pose_lookup import CameraPoseLookup, OutsideBuffer
from .detector import TagDetector
from .image_encodings import (
    ImageDecodeError,
    ImageEncodingError,
    ImageLayoutError,
    ImageSizeError,
    check_image_size,
    compressed_msg_to_gray,
    image_msg_to_gray,
)
from .node_parameters import DETECTOR_PARAMETERS, DETECTOR_SPECS
from .region_search import RegionSearch

THROTTLE_S = 5.0
# Images: sensor-data QoS keeping only the newest frame. A frame that arrives while the
# detector is busy replaces the one waiting: a queue of five (sensor data's depth) made the
# detector work through stale frames, and the newest one waited for all of them.
LATEST_FRAME = QoSProfile(depth=1, history=QoSHistoryPolicy.KEEP_LAST,
                          reliability=QoSReliabilityPolicy.BEST_EFFORT,
                          durability=QoSDurabilityPolicy.VOLATILE)
# distortion model -> the numbers of coefficients it takes ('' = none given)
DISTORTION_MODELS = {'plumb_bob': (0, 4, 5), 'rational_polynomial': (0, 8), '': (0,)}
COMPRESSED_SUFFIX = '/compressed'     # image_transport's topic of the compressed transport


class ArtagDetectorNode(ManagedNode):
    """Configure reads the parameters and the URDF; activate opens the topics."""

    def __init__(self):
        super().__init__('artag_detector')

    def configure(self):
        self._values = declare_all(self, DETECTOR_SPECS)
        profile = load_profile(self._values['robot_profile'])
        self.kinematics = RobotKinematics(self._values['urdf_file'] or None, profile=profile)
        self.base_frame = self._values['base_frame'] or profile.frames.base
        self.camera_frame = self._values['camera_frame'] or profile.frames.camera_optical
        if not self.kinematics.has_frame(self.camera_frame):
            raise ValueError(f'parameter camera_frame: no frame {self.camera_frame!r} in '
                             f'{self.kinematics.urdf_path}')
        self.frames = FrameMap(self._values['frame_map'], self.kinematics.has_frame,
                               self.camera_frame)
        self.fixed_pose = fixed_camera_pose(self._values['fixed_camera_pose'])
        self.poses = CameraPoseLookup(
            self.kinematics, self._values['joint_state_lookup'],
            self._values['joint_state_buffer_s'], self._values['joint_state_tolerance_s'],
            self.fixed_pose)
        self.rectified = self._values['image_is_rectified']
        self._rectified_pose = None          # rectified frame in the camera frame (stereo R)
        # An image stamped after the newest joint state waits here (one at most) for the
        # joint state that reaches its stamp, as tf2's message filter waits for a transform.
        self._waiting = None
        self._config = {name: self._values[name] for name in DETECTOR_PARAMETERS}
        self.detector = None                 # built at the first camera_info
        self.search = RegionSearch(self._values['full_frame_every'],
                                   track=self._values['track_tags'])
        self._camera_key = None
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
            + (f'poses in {self.base_frame} from the fixed camera pose '
               f'{list(self._values["fixed_camera_pose"])}' if self.fixed_pose is not None else
               f'poses in {self.base_frame} via forward kinematics of the camera frame '
               f'(default {self.camera_frame}'
               + (f', mapped: {self.frames.mapping}' if self.frames.mapping else '')
               + f') at the joint state {self._lookup_text()}')
            + ('; rectified images (P, no distortion)' if self.rectified else ''))

    def _lookup_text(self):
        return ('newest at each image' if self.poses.lookup == 'latest' else
                'interpolated at each image stamp')

    def activate(self):
        self._pub = self.create_publisher(TagDetectionArray, names.TAG_DETECTIONS,
                                          qos.RELIABLE)
        if self.image_transport == 'compressed':
            self.health.subscribe(CompressedImage, self.image_topic,
                                  self._on_compressed_image, LATEST_FRAME)
        else:
            self.health.subscribe(Image, self.image_topic, self._on_image, LATEST_FRAME)
        self.health.subscribe(CameraInfo, names.CAMERA_INFO, self._on_camera_info,
                              qos.SENSOR_DATA)
        # joint_states (100-500 Hz from a joint_state_broadcaster) on a thread of their
        # own: on this node's executor a detection of tens of ms let the depth-5 sensor
        # queue drop all but the last five, and the pose at an image stamp was then
        # interpolated across the gap. A deeper queue on this executor is no cure: a
        # detector slower than the joint-state rate then worked through a backlog
        # seconds old. The thread only buffers; a frame waiting for its joint state is
        # detected back on this executor, woken by the guard condition.
        self._joints_arrived = self.create_guard_condition(self._on_joints_arrived)
        self.health.subscribe(JointState, names.JOINT_STATES, self._on_joint_state,
                              qos.SENSOR_DATA, node=self.create_input_node().node)

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
        self._urdf_frame('camera_info', msg.header.frame_id)
        if self.rectified:
            k, d, rect = self._rectified_intrinsics(msg)
        else:
            k, d = self._raw_intrinsics(msg)
            rect = None
        key = (tuple(k.ravel()), tuple(d), msg.distortion_model, rect)
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
        self._rectified_pose = None if rect is None else rectified_to_camera(
            np.reshape(rect, (3, 3)))

    @staticmethod
    def _raw_intrinsics(msg):
        """K and D of a raw image's camera_info (checked)."""
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
        return k, d

    @staticmethod
    def _rectified_intrinsics(msg):
        """P's 3x3 (no distortion: the image is rectified) and R (None: identity)."""
        input_checks.finite('projection matrix P', msg.p)
        input_checks.finite('rectification matrix R', msg.r)
        try:
            intrinsics = intrinsics_from_camera_info(msg.k, msg.d, msg.r, msg.p, True)
        except ValueError as error:
            raise Rejected('empty', str(error)) from None
        rect = intrinsics.rectification
        return (intrinsics.camera_matrix, np.zeros(0),
                None if rect is None else tuple(rect.ravel()))

    def _on_joint_state(self, msg: JointState):
        """On the input node's thread (activate)."""
        input_checks.joint_state(msg)
        try:
            self.poses.add(stamp_ns(msg.header.stamp), msg.name, msg.position)
        except ValueError as error:
            raise Rejected('unknown_id', str(error)) from None
        waiting = self._waiting
        if waiting is not None and not self._must_wait(*waiting[1:]):
            self._joints_arrived.trigger()

    def _on_joints_arrived(self):
        """On this node's executor: the waiting frame's joint states have come."""
        if self._waiting is not None and not self._must_wait(*self._waiting[1:]):
            self._detect_waiting()

    def _must_wait(self, header, frame):
        return self.poses.must_wait(stamp_ns(header.stamp), frame)

    def _take_frame(self, gray, header, frame):
        """Detect now, or keep the frame until the joint states reach its stamp (a frame
        already waiting goes first, with the joint states there are)."""
        if self._waiting is not None:
            self._detect_waiting()
        if self._must_wait(header, frame):
            self._waiting = (gray, header, frame)
            # The joint state may have come between the check and the line above, when
            # the input thread saw no waiting frame.
            if not self._must_wait(header, frame):
                self._detect_waiting()
            return
        self._detect_and_publish(gray, header, frame, self._pose_at(frame, header))

    def _detect_waiting(self):
        gray, header, frame = self._waiting
        self._waiting = None
        try:
            self._detect_and_publish(gray, header, frame, self._pose_at(frame, header))
        except Rejected as rejected:            # counted on the image topic, as it came
            self.health.reject(self.image_topic, rejected.kind, rejected.detail)

    def _pose_at(self, frame, header):
        """Pose of URDF `frame` in the base frame at the image's stamp (camera_pose_lookup);
        Rejected('joint_state_stamp') when the buffered joint states do not reach it."""
        t_ns = stamp_ns(header.stamp)
        if t_ns == 0 and self.poses.lookup == 'interpolate' and self.fixed_pose is None \
                and self.poses.has_joint_states:
            self.get_logger().warning(
                'image without a stamp: camera pose from the newest joint state',
                throttle_duration_sec=THROTTLE_S)
        try:
            pose, unstamped = self.poses.pose_at(frame, t_ns)
        except OutsideBuffer as error:
            raise Rejected('joint_state_stamp', f'image {error}: do the camera and '
                           f'{self.resolve_topic_name(names.JOINT_STATES)} share a clock? '
                           '(joint_state_lookup:=latest takes the newest joint state '
                           'instead)') from None
        if unstamped:
            self.get_logger().warning(
                f'joint_states of {", ".join(unstamped)} are unstamped: camera pose from '
                'the newest of them, not at the image stamp', throttle_duration_sec=THROTTLE_S)
        return pose

    def _ready(self):
        if self.detector is None:
            raise Rejected('no_camera_info', 'no valid camera_info on '
                                             f'{self.resolve_topic_name(names.CAMERA_INFO)} yet')

    def _urdf_frame(self, what, frame_id):
        """The URDF frame of a header's frame_id (frame_map, the URDF, camera_frame); with
        a fixed camera pose, any frame_id is that camera's."""
        if self.fixed_pose is not None:
            return frame_id or self.camera_frame
        try:
            return self.frames.resolve(frame_id)
        except UnknownFrame as error:
            raise Rejected('frame', f'{what} {error}') from None

    def _check_header(self, header):
        """The image's URDF frame (its stamp checked)."""
        frame = self._urdf_frame('image', header.frame_id)
        self._image_stamps.check(header.stamp, self.health.now_ns())
        return frame

    def _on_image(self, msg: Image):
        """Raises input_checks.Rejected for a frame it cannot use (NodeHealth counts it)."""
        self._ready()
        frame = self._check_header(msg.header)
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
        self._take_frame(gray, msg.header, frame)

    def _on_compressed_image(self, msg: CompressedImage):
        self._ready()
        frame = self._check_header(msg.header)
        try:
            gray = compressed_msg_to_gray(msg)
        except ImageDecodeError as error:
            raise Rejected('decode', str(error)) from None
        except ImageEncodingError as error:
            raise Rejected('encoding', str(error)) from None
        self._image_stamps.taken(msg.header.stamp)
        self._take_frame(gray, msg.header, frame)

    def _detect_and_publish(self, gray, header, frame, camera_pose):
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
        rectified = self._rectified_pose         # poses of a rectified stereo image: by R^T
        if camera_pose is not None:
            result = result.in_frame(camera_pose if rectified is None else
                                     camera_pose @ rectified, self.base_frame)
            out_frame = self.base_frame
        else:
            self.get_logger().warning(
                f'no {self.resolve_topic_name(names.JOINT_STATES)} yet: detections published '
                'in the camera frame', throttle_duration_sec=THROTTLE_S)
            out_frame = header.frame_id or frame
            if rectified is not None:
                result = result.in_frame(rectified, out_frame)
        self._pub.publish(self._to_msg(result, header, out_frame))

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
