"""The rclpy side of bags, shared by bag_recorder and bag_player: message classes by type
name, the graph's QoS per topic (for bags that store none), conversions between
rclpy's QoSProfile and the `rosbags` profiles a bag stores (bag_qos), and messages
recorded with an older definition of their type made current (`current_message`)."""

import importlib
import re

from rclpy.duration import Duration
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSLivelinessPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
)

from abp_common import qos

from . import bag_qos
from .bag import LATCHED_TOPICS, SENSOR_TOPICS, graph_name

# Depth of the reliable event topics: the writer must not drop a burst.
EVENT_DEPTH = 100


def message_class(msgtype):
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def current_message(recorded, cls):
    """A `cls` (rclpy) message from a rosbags message recorded with another definition of
    its type: the fields both definitions have are copied, nested messages field by field;
    a field the recording lacks keeps its default (an empty track id: the single object)."""
    msg = cls()
    for name, kind in cls.get_fields_and_field_types().items():
        if not hasattr(recorded, name):
            continue
        value = getattr(recorded, name)
        if hasattr(value, '__msgtype__'):
            value = current_message(value, type(getattr(msg, name)))
        elif isinstance(value, (list, tuple)) and value and hasattr(value[0], '__msgtype__'):
            element = message_class(_element_type(kind))
            value = [current_message(v, element) for v in value]
        elif hasattr(value, 'tolist'):   # rosbags reads arrays of numbers as NumPy arrays
            value = value.tolist()
        setattr(msg, name, value)
    return msg


def _element_type(kind):
    """'abp_msgs/msg/AspectHypothesis' from an rclpy field type such as
    'sequence<abp_msgs/AspectHypothesis>' or 'abp_msgs/AspectHypothesis[3]'."""
    package, name = re.sub(r'^sequence<|, ?\d+>$|>$|\[\d*\]$', '', kind).split('/')
    return f'{package}/msg/{name}'


def graph_qos(topic):
    """The QoS the graph uses on `topic` (absolute, in any namespace): what abp replays a
    bag without stored QoS with."""
    name = graph_name(topic)
    if name in SENSOR_TOPICS:
        return qos.SENSOR_DATA
    if name in LATCHED_TOPICS:
        return qos.LATCHED
    return qos.reliable(EVENT_DEPTH)


def recording_depth(topic):
    """Subscription depth of the recorder: small for camera streams (a late frame is
    worth nothing, a queue of images is large), deep elsewhere (no burst lost)."""
    return qos.SENSOR_DATA.depth if graph_name(topic) in SENSOR_TOPICS else EVENT_DEPTH


def to_bag_qos(profile):
    """A bag profile (rosbags Qos) from an rclpy QoSProfile, e.g. a publisher's endpoint
    info (which reports history UNKNOWN and depth 0: DDS discovery does not carry them)."""
    return bag_qos.profile(
        profile.history.name, profile.depth, profile.reliability.name, profile.durability.name,
        profile.deadline.nanoseconds, profile.lifespan.nanoseconds, profile.liveliness.name,
        profile.liveliness_lease_duration.nanoseconds,
        profile.avoid_ros_namespace_conventions)


def to_rclpy_qos(profile, depth):
    """An rclpy QoSProfile (keep last `depth`) with a bag profile's policies. A duration
    of 0 or infinite is left unset (rclpy's default: the RMW's, which is infinite)."""
    def duration(time):
        ns = bag_qos.nanoseconds(time)
        return Duration(nanoseconds=0 if ns >= bag_qos.INFINITE_NS else ns)

    return QoSProfile(
        history=QoSHistoryPolicy.KEEP_LAST, depth=depth,
        reliability=QoSReliabilityPolicy[profile.reliability.name],
        durability=QoSDurabilityPolicy[profile.durability.name],
        deadline=duration(profile.deadline), lifespan=duration(profile.lifespan),
        liveliness=QoSLivelinessPolicy[profile.liveliness.name],
        liveliness_lease_duration=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions)


def recording_qos(topic, offers):
    """(QoSProfile, warnings): the subscription that records `topic` from publishers
    offering `offers` (bag profiles), by rosbag2's rules (bag_qos.recording_request)."""
    reliable, transient_local, warnings = bag_qos.recording_request(topic, offers)
    profile = QoSProfile(
        history=QoSHistoryPolicy.KEEP_LAST, depth=recording_depth(topic),
        reliability=(QoSReliabilityPolicy.RELIABLE if reliable
                     else QoSReliabilityPolicy.BEST_EFFORT),
        durability=(QoSDurabilityPolicy.TRANSIENT_LOCAL if transient_local
                    else QoSDurabilityPolicy.VOLATILE))
    return profile, warnings
