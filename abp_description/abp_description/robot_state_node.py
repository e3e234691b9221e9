"""ROS 2 wiring of the robot's tf tree: the `robot_state` node (robot_state_publisher's job).

Subscribes:  joint_states            (sensor_msgs/JointState, sensor-data QoS)
             odom                    (nav_msgs/Odometry, sensor-data QoS)
             abp/aspect_observation  (abp_msgs/AspectObservation: the cube estimate)
             robot_description       (std_msgs/String, latched; only with urdf_source topic)
Publishes:   /tf                     (tf2_msgs/TFMessage, reliable, depth 100, as tf2_ros)
             /tf_static              (tf2_msgs/TFMessage, latched, depth 1: one message with
                                      every fixed joint, as tf2_ros's static broadcaster)
             robot_description       (std_msgs/String, latched; with urdf_source file)

/tf carries, at each joint state's stamp, one transform per moving joint named in it (parent
link -> child link, abp_description.robot_state.KinematicTree); with enable_odom_tf, the
odometry's header.frame_id -> child_frame_id at each odometry stamp (the child must be the
URDF's root link); and, with cube_frame set, odom -> cube at each odometry stamp: the
aspect matcher's latest cube pose, seen in the base frame at its image stamp and placed in
odom with the odometry of that stamp, then held there (a cube sits still until it is seen
again). /tf and /tf_static are
absolute, as tf2_ros has them. Science in abp_description.robot_state; this module only
converts messages and parameters.
"""

import math
import sys

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected, stamp_ns
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_msgs.msg import AspectObservation

from . import urdf_path
from .kinematics import RobotKinematics
from .robot_profile import load_profile
from .robot_state import (
    KinematicTree,
    PoseHistory,
    PublishThrottle,
    matrix_from,
    translation_quaternion,
)
from .robot_state_config import ROBOT_STATE_SPECS, URDF_FROM_FILE

TF, TF_STATIC = '/tf', '/tf_static'
ROBOT_DESCRIPTION = 'robot_description'
# tf2_ros's DynamicBroadcasterQoS and StaticBroadcasterQoS (tf2_ros/qos.hpp).
TF_QOS = qos.reliable(100)
TF_STATIC_QOS = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                           durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)


def transform_msg(parent, child, translation, quaternion, stamp, msg=None):
    """geometry_msgs/TransformStamped of `child` in `parent` (a unit quaternion x, y, z,
    w); fills `msg` when given (a message reused at every joint state: faster)."""
    msg = TransformStamped() if msg is None else msg
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = float(translation[0]), float(translation[1]), float(translation[2])
    r.x, r.y, r.z, r.w = (float(quaternion[0]), float(quaternion[1]), float(quaternion[2]),
                          float(quaternion[3]))
    return msg


def pose_matrix(pose):
    """4x4 of a geometry_msgs/Pose."""
    p, o = pose.position, pose.orientation
    return matrix_from((p.x, p.y, p.z), (o.x, o.y, o.z, o.w))


class RobotStateNode(ManagedNode):
    """Configure loads the URDF (from a file); activate opens the topics and publishes the
    description and the static transforms (abp_common.lifecycle)."""

    def __init__(self):
        super().__init__('robot_state')

    def configure(self):
        self.values = declare_all(self, ROBOT_STATE_SPECS)
        self.tree = None
        self.urdf_text = None
        if self.values['urdf_source'] == URDF_FROM_FILE:
            path = self.values['urdf_file'] or urdf_path(load_profile(
                self.values['robot_profile']))
            try:
                with open(path) as stream:
                    self.urdf_text = stream.read()
            except OSError as error:
                raise ValueError(f'urdf_file {path!r} cannot be read: {error}') from None
            self.tree = self._tree_of(self.urdf_text, path)
        self._throttle = PublishThrottle(self.values['publish_frequency'])
        self._odometry = PoseHistory(self.values['odom_history'])
        self._odom_frame = None
        self._edge_msgs = {}         # Edge -> its TransformStamped, reused
        self._odom_msg = TransformStamped()
        self._cube = None            # the cube estimate in odom: (translation, quaternion)
        self._last_now_ns = 0
        self.health = NodeHealth(self)
        self.add_post_set_parameters_callback(self._after_set_parameters)

    def _tree_of(self, urdf_text, where):
        try:
            tree = KinematicTree(RobotKinematics(urdf_xml=urdf_text))
        except ValueError as error:
            raise ValueError(f'{where}: not a URDF abp can use ({error})') from None
        self.get_logger().info(
            f'robot {tree.root}: {len(tree.moving_edges)} moving and {len(tree.fixed_edges)} '
            f'fixed joints, {len(tree.links)} links')
        return tree

    def activate(self):
        self._tf_pub = self.create_publisher(TFMessage, TF, TF_QOS)
        self._static_pub = self.create_publisher(TFMessage, TF_STATIC, TF_STATIC_QOS)
        if self.urdf_text is not None:
            self._description_pub = self.create_publisher(String, ROBOT_DESCRIPTION,
                                                          qos.LATCHED)
            self._description_pub.publish(String(data=self.urdf_text))
            self._publish_static()
        else:
            self.health.subscribe(String, ROBOT_DESCRIPTION, self._on_description, qos.LATCHED)
        self.health.subscribe(JointState, names.JOINT_STATES, self._on_joint_state,
                              qos.SENSOR_DATA)
        self.health.subscribe(Odometry, names.ODOM, self._on_odometry, qos.SENSOR_DATA)
        if self.values['cube_frame']:
            self.health.subscribe(AspectObservation, names.ASPECT_OBSERVATION,
                                  self._on_observation, qos.RELIABLE)

    def _after_set_parameters(self, params):
        for param in params:
            if param.name == 'publish_frequency':
                self._throttle = PublishThrottle(param.value)
            elif param.name in ('ignore_timestamp', 'enable_odom_tf'):
                self.values[param.name] = bool(param.value)

    # -- inputs ---------------------------------------------------------------------------
    def _on_description(self, msg: String):
        """A robot_description from another node: the tree (and /tf_static) follow it."""
        try:
            tree = self._tree_of(msg.data, f'the {self.resolve_topic_name(ROBOT_DESCRIPTION)} '
                                           'topic')
        except ValueError as error:
            raise Rejected('malformed', str(error)) from None
        self.tree = tree
        self._throttle.reset()
        self._publish_static()

    def _on_joint_state(self, msg: JointState):
        if self.tree is None:
            raise Rejected('no_description', 'joint state before any robot_description')
        input_checks.joint_state(msg)
        self._clock_check()
        stamp = stamp_ns(msg.header.stamp)
        if not (self.values['ignore_timestamp'] or self._throttle.due(msg.name, stamp)):
            return
        with self.health.timed():
            transforms = self.tree.moving_transforms(dict(zip(msg.name, msg.position)))
            if not transforms:
                raise Rejected('unknown_id', 'joint_states names no moving joint of the robot')
            # One message object per edge, filled again each time (publish copies it out).
            self._tf_pub.publish(TFMessage(transforms=[
                transform_msg(e.parent, e.child, t, q, msg.header.stamp, self._edge_msg(e))
                for e, t, q in transforms]))
        self._throttle.published(msg.name, stamp)

    def _on_odometry(self, msg: Odometry):
        input_checks.odometry(msg)
        parent, child = msg.header.frame_id.lstrip('/'), msg.child_frame_id.lstrip('/')
        if not parent or not child:
            raise Rejected('frame', 'odometry without header.frame_id or child_frame_id')
        if self.tree is not None and child != self.tree.root:
            raise Rejected('frame', f"odometry of {child!r}, but the robot's root link is "
                                    f'{self.tree.root!r}: no transform published')
        if parent != self._odom_frame:
            self._odometry.clear()
            self._odom_frame = parent
        # Copied field by field (no matrix): this runs at the odometry's full rate.
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        norm = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
        translation, quaternion = (p.x, p.y, p.z), (o.x / norm, o.y / norm, o.z / norm,
                                                    o.w / norm)
        self._odometry.add(stamp_ns(msg.header.stamp), translation, quaternion)
        transforms = []
        if self.values['enable_odom_tf']:
            transforms.append(transform_msg(parent, child, translation, quaternion,
                                            msg.header.stamp, self._odom_msg))
        if self._cube is not None:
            transforms.append(self._cube_msg(msg.header.stamp))
        if transforms:
            self._tf_pub.publish(TFMessage(transforms=transforms))

    def _on_observation(self, msg: AspectObservation):
        """The best hypothesis's cube pose, placed in the odometry frame."""
        if not msg.hypotheses:
            return
        input_checks.aspect_observation(msg)
        frame = msg.header.frame_id.lstrip('/')
        cube = pose_matrix(msg.hypotheses[0].object_pose.pose)
        if self._odom_frame is None:
            raise Rejected('no_odometry', 'cube estimate before any odometry')
        if frame != self._odom_frame:
            base = self.tree.root if self.tree is not None else None
            if frame != base:
                raise Rejected('frame', f'cube estimate in {frame!r}: expected the base frame '
                                        f'{base!r} or the odometry frame {self._odom_frame!r}')
            seen = stamp_ns(msg.header.stamp)
            odom_to_base = self._odometry.at(seen)
            if odom_to_base is None:
                kept = self._odometry.span()
                kept = ('none' if kept is None else
                        f'{kept[0] * 1e-9:.3f} to {kept[1] * 1e-9:.3f} s')
                raise Rejected('no_odometry', f"no odometry at the cube estimate's stamp "
                                              f'{seen * 1e-9:.3f} s (odometry kept: {kept})')
            cube = odom_to_base @ cube
        # Published from the next odometry stamp on, not at the (older) image stamp: the
        # held estimate was already sent at later stamps, and the edge's samples must not
        # go back and forth between the old and the new estimate.
        self._cube = translation_quaternion(cube)

    # -- output ---------------------------------------------------------------------------
    def _edge_msg(self, edge):
        msg = self._edge_msgs.get(edge)
        if msg is None:
            msg = self._edge_msgs[edge] = TransformStamped()
        return msg

    def _cube_msg(self, stamp):
        return transform_msg(self._odom_frame, self.values['cube_frame'], *self._cube, stamp)

    def _publish_static(self):
        stamp = self.get_clock().now().to_msg()
        self._static_pub.publish(TFMessage(transforms=[
            transform_msg(e.parent, e.child, t, q, stamp)
            for e, t, q in self.tree.static_transforms()]))

    def _clock_check(self):
        """Time went back (a restarted simulation, a bag played again): publish the joints
        again from the new start, as robot_state_publisher does."""
        now = self.get_clock().now().nanoseconds
        if now < self._last_now_ns:
            self.get_logger().warning('time moved backwards: publishing the joints again')
            self._throttle.reset()
            self._odometry.clear()
        self._last_now_ns = now


def main(args=None):
    return run_node('robot_state', RobotStateNode, args)


if __name__ == '__main__':
    sys.exit(main())
