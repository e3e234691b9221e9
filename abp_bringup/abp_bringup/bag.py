"""rosbag2 files (MCAP by default) for abp episodes, with the `rosbags` library.

Plain module (no rclpy): the typestore with abp_msgs registered from the
installed .msg files, the graph's topic list, a writer that takes serialized
(CDR) messages as DDS delivers them, and a reader. Bags written here are
ordinary rosbag2 bags: `ros2 bag info` / `ros2 bag play` read them on a robot.

Topics in a bag are absolute, as rosbag2 records them: a graph under the namespace
/robot1 gives /robot1/abp/belief. The graph's own names are relative
(abp_common.names); `graph_topics(namespace)` resolves them, `graph_name(topic)` maps
an absolute topic back to the graph's name (for its QoS).

A bag holds the definitions of the types it was recorded with. When abp_msgs has gained
fields since (issue 37 added track ids), `read_messages` reads a bag with its own
definitions (the fields it lacks are absent), `outdated_types` names the types whose
recorded definition is not the current one (the player converts those), while
`deserialize` with `typestore()` reads only bags of the current definitions.

Each topic carries the QoS profiles its publishers offered (`offered_qos_profiles`, see
bag_qos), as rosbag2 records them: `ros2 bag play` and abp's bag_player replay a latched
topic latched. Bags recorded before abp stored QoS have none (`offered_qos`: []).
"""

import pathlib

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from abp_common import bag_types, names
from abp_common.param_spec import BOOL, STRING, STRING_ARRAY, ParamSpec

# The graph's topics (relative names) and types; images are large and recorded only
# on request.
GRAPH_TOPICS = {
    names.TAG_DETECTIONS: 'abp_msgs/msg/TagDetectionArray',
    names.ASPECT_OBSERVATION: 'abp_msgs/msg/AspectObservation',
    names.BELIEF: 'abp_msgs/msg/Belief',
    names.BELIEFS: 'abp_msgs/msg/SceneBelief',   # every object's belief (scene_bag reads it)
    names.EXECUTED_ACTION: 'abp_msgs/msg/ExecutedAction',
    names.PLAN: 'abp_msgs/msg/PlanStep',
    names.GROUND_TRUTH: 'abp_msgs/msg/SimGroundTruth',
    names.JOINT_STATES: 'sensor_msgs/msg/JointState',
    names.ODOM: 'nav_msgs/msg/Odometry',
    names.CAMERA_INFO: 'sensor_msgs/msg/CameraInfo',
    # tf: absolute, as tf2_ros publishes and reads them (a namespaced robot remaps them).
    '/tf': 'tf2_msgs/msg/TFMessage',
    '/tf_static': 'tf2_msgs/msg/TFMessage',
}
IMAGE_TOPICS = {names.IMAGE: 'sensor_msgs/msg/Image'}
# The graph's latched topics: only for replaying bags that store no QoS (the recorder
# takes durability from what the publishers offer).
LATCHED_TOPICS = {names.BELIEF, names.BELIEFS, names.GROUND_TRUTH}
SENSOR_TOPICS = {names.IMAGE, names.CAMERA_INFO}
STORAGE = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}

# The bag_recorder node's parameters (declared with abp_common.parameters.declare_all).
RECORDER_SPECS = (
    ParamSpec('output', STRING, '', 'Directory of the new bag (must not exist).',
              read_only=True),
    ParamSpec('topics', STRING_ARRAY, None, "Topics to record, relative (resolved in the "
              "recorder's namespace) or absolute; empty = the graph's topics (see "
              "abp_bringup.bag).", read_only=True),
    ParamSpec('record_images', BOOL, False, f'Also record {names.IMAGE} (large).',
              read_only=True),
    ParamSpec('storage', STRING, 'mcap', 'rosbag2 storage.', read_only=True,
              choices=tuple(STORAGE)),
)


def graph_topics(namespace='', images=False):
    """{absolute topic: msgtype} of the graph's topics under `namespace`."""
    topics = {**GRAPH_TOPICS, **(IMAGE_TOPICS if images else {})}
    return {names.absolute(name, namespace): msgtype for name, msgtype in topics.items()}


def graph_name(topic):
    """The graph's (relative) name that the absolute `topic` resolves, in any namespace;
    '' for a topic that is not the graph's."""
    for name in (*GRAPH_TOPICS, *IMAGE_TOPICS):
        if topic == name or topic.endswith('/' + name):
            return name
    return ''


def recorded_topics(wanted=(), record_images=False, namespace=''):
    """{absolute topic: msgtype} a recorder in `namespace` records: the `wanted` topics
    (relative names resolved in the namespace), else the graph's topics."""
    known = graph_topics(namespace, images=True)
    wanted = [names.absolute(t, namespace) for t in (wanted or ()) if t]
    if not wanted:
        return graph_topics(namespace, images=record_images)
    unknown = [t for t in wanted if t not in known]
    if unknown:
        raise ValueError(f"topics {unknown} are not graph topics; known: "
                         f"{', '.join(sorted(known))}")
    return {t: known[t] for t in wanted}


class BagError(Exception):
    """A bag cannot be written or read; the message says which and why."""


def typestore():
    """Jazzy's standard types plus every abp_msgs message (abp_common.bag_types)."""
    try:
        return bag_types.typestore()
    except FileNotFoundError as error:
        raise BagError(str(error)) from None


class BagWriter:
    """Writes serialized messages to a new rosbag2 bag (the path must not exist).

    `topics` ({topic: msgtype}) are the topics the bag may hold. Those in `offered_qos`
    ({topic: [Qos]}) are added at once with their publishers' profiles, the others with
    `add_topic` when their publishers are known (as rosbag2 does on discovery), or, with
    `add_all=True`, at once without QoS."""

    def __init__(self, path, topics, storage='mcap', store=None, offered_qos=None,
                 add_all=False):
        path = pathlib.Path(path)
        if path.exists():
            raise BagError(f'bag {path} already exists: choose a new directory '
                           '(rosbag2 never overwrites a bag)')
        if storage not in STORAGE:
            raise BagError(f"storage {storage!r} unknown: use one of {', '.join(STORAGE)}")
        self.store = store or typestore()
        unknown = sorted(t for t in topics.values() if t not in self.store.types)
        if unknown:
            raise BagError(f"no message definition for {', '.join(unknown)}")
        self.topics = dict(topics)
        self._writer = Writer(path, version=9, storage_plugin=STORAGE[storage])
        self._writer.open()
        self._connections = {}
        offered_qos = offered_qos or {}
        for topic in topics:
            if add_all or topic in offered_qos:
                self.add_topic(topic, offered_qos.get(topic, ()))
        self.count = 0

    def add_topic(self, topic, offered_qos=()):
        """Add `topic` (one of `topics`) with the QoS profiles its publishers offer."""
        if topic in self._connections:
            raise BagError(f'topic {topic} is already in the bag')
        self._connections[topic] = self._writer.add_connection(
            topic, self.topics[topic], typestore=self.store,
            offered_qos_profiles=list(offered_qos))

    def added(self, topic):
        return topic in self._connections

    def write(self, topic, timestamp_ns, data):
        self._writer.write(self._connections[topic], int(timestamp_ns), bytes(data))
        self.count += 1

    def close(self):
        self._writer.close()


def _connections(path):
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f'bag {path} does not exist')
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            return list(reader.connections)
    except Exception as error:
        raise BagError(f'cannot read bag {path}: {error}') from error


def bag_topics(path):
    """{topic: msgtype} of every connection in the bag."""
    return {c.topic: c.msgtype for c in _connections(path)}


def offered_qos(path):
    """{topic: [Qos]}: the QoS profiles recorded per topic ([] when the bag has none)."""
    profiles = {}
    for connection in _connections(path):
        profiles.setdefault(connection.topic, []).extend(
            getattr(connection.ext, 'offered_qos_profiles', None) or [])
    return profiles


def read_bag(path, topics=None):
    """Yield (topic, msgtype, timestamp_ns, serialized bytes) in time order."""
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f'bag {path} does not exist')
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, timestamp, data in reader.messages(connections=connections):
                yield connection.topic, connection.msgtype, timestamp, data
    except BagError:
        raise
    except Exception as error:  # rosbags raises several types for unreadable bags
        raise BagError(f'cannot read bag {path}: {error}') from error


def deserialize(store, data, msgtype):
    """A rosbags message object (attributes as in the .msg) from CDR bytes."""
    return store.deserialize_cdr(data, msgtype)


def bag_typestore(path):
    """The message definitions the bag was recorded with (the current ones for a bag that
    stores none)."""
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f'bag {path} does not exist')
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            return reader.typestore
    except Exception as error:
        raise BagError(f'cannot read bag {path}: {error}') from error


def read_messages(path, topics=None):
    """Yield (topic, msgtype, timestamp_ns, message) in time order, each message read
    with the definition it was recorded with (a field added since is not there)."""
    store = bag_typestore(path)
    for topic, msgtype, timestamp, data in read_bag(path, topics):
        yield topic, msgtype, timestamp, deserialize(store, data, msgtype)


def outdated_types(path):
    """{msgtype: the bag's typestore} for each type of the bag recorded with another
    definition than the current one (e.g. abp_msgs before a field was added)."""
    current, recorded = typestore(), bag_typestore(path)
    outdated = {}
    for msgtype in set(bag_topics(path).values()):
        if msgtype in current.types and msgtype in recorded.types \
                and recorded.hash_rihs01(msgtype) != current.hash_rihs01(msgtype):
            outdated[msgtype] = recorded
    return outdated
