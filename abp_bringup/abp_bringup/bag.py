"""rosbag2 files (MCAP by default) for abp episodes, with the `rosbags` library.

Plain module (no rclpy): the typestore with abp_msgs registered from the
installed .msg files, the graph's topic list, a writer that takes serialized
(CDR) messages as DDS delivers them, and a reader. Bags written here are
ordinary rosbag2 bags: `ros2 bag info` / `ros2 bag play` read them on a robot.
"""

import pathlib

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# The graph's topics and types; images are large and recorded only on request.
GRAPH_TOPICS = {
    "/abp/tag_detections": "abp_msgs/msg/TagDetectionArray",
    "/abp/aspect_observation": "abp_msgs/msg/AspectObservation",
    "/abp/belief": "abp_msgs/msg/Belief",
    "/abp/executed_action": "abp_msgs/msg/ExecutedAction",
    "/abp/plan": "abp_msgs/msg/PlanStep",
    "/abp/sim/ground_truth": "abp_msgs/msg/SimGroundTruth",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/odom": "nav_msgs/msg/Odometry",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
}
IMAGE_TOPICS = {"/camera/image_raw": "sensor_msgs/msg/Image"}
LATCHED_TOPICS = {"/abp/belief", "/abp/sim/ground_truth"}
SENSOR_TOPICS = {"/camera/image_raw", "/camera/camera_info"}
STORAGE = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}


class BagError(Exception):
    """A bag cannot be written or read; the message says which and why."""


def abp_msgs_dir():
    """The installed abp_msgs share directory (ament index), or the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return pathlib.Path(get_package_share_directory("abp_msgs"))
    except (ImportError, LookupError):
        return pathlib.Path(__file__).resolve().parents[2] / "abp_msgs"


def typestore():
    """Jazzy's standard types plus every abp_msgs message."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    msg_dir = abp_msgs_dir() / "msg"
    for path in sorted(msg_dir.glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"abp_msgs/msg/{path.stem}"))
    if not types:
        raise BagError(f"no abp_msgs message definitions found in {msg_dir}")
    store.register(types)
    return store


class BagWriter:
    """Writes serialized messages to a new rosbag2 bag (the path must not exist)."""

    def __init__(self, path, topics, storage="mcap", store=None):
        path = pathlib.Path(path)
        if path.exists():
            raise BagError(f"bag {path} already exists: choose a new directory "
                           "(rosbag2 never overwrites a bag)")
        if storage not in STORAGE:
            raise BagError(f"storage {storage!r} unknown: use one of {', '.join(STORAGE)}")
        self.store = store or typestore()
        unknown = sorted(t for t in topics.values() if t not in self.store.types)
        if unknown:
            raise BagError(f"no message definition for {', '.join(unknown)}")
        self._writer = Writer(path, version=9, storage_plugin=STORAGE[storage])
        self._writer.open()
        self._connections = {
            topic: self._writer.add_connection(topic, msgtype, typestore=self.store)
            for topic, msgtype in topics.items()
        }
        self.count = 0

    def write(self, topic, timestamp_ns, data):
        self._writer.write(self._connections[topic], int(timestamp_ns), bytes(data))
        self.count += 1

    def close(self):
        self._writer.close()


def bag_topics(path):
    """{topic: msgtype} of every connection in the bag."""
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except Exception as error:
        raise BagError(f"cannot read bag {path}: {error}") from error


def read_bag(path, topics=None):
    """Yield (topic, msgtype, timestamp_ns, serialized bytes) in time order."""
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, timestamp, data in reader.messages(connections=connections):
                yield connection.topic, connection.msgtype, timestamp, data
    except BagError:
        raise
    except Exception as error:  # rosbags raises several types for unreadable bags
        raise BagError(f"cannot read bag {path}: {error}") from error


def deserialize(store, data, msgtype):
    """A rosbags message object (attributes as in the .msg) from CDR bytes."""
    return store.deserialize_cdr(data, msgtype)
