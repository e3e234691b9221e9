"""`bag_recorder`: records the graph's topics into a rosbag2 bag (MCAP by default).

Messages are taken serialized from DDS (no deserialisation) and written with the
node's clock as receive time, so with use_sim_time the bag is in sim time.
Parameters: output (a new directory), topics (names; empty = the graph's topics),
record_images, storage (mcap | sqlite3). The bag is closed on Ctrl-C / shutdown.
"""

import importlib
import sys

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
    qos_profile_sensor_data,
)

from abp_belief.node_main import run_node

from .bag import GRAPH_TOPICS, IMAGE_TOPICS, LATCHED_TOPICS, SENSOR_TOPICS, BagError, BagWriter


def message_class(msgtype):
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def topic_qos(topic):
    if topic in SENSOR_TOPICS:
        return qos_profile_sensor_data
    if topic in LATCHED_TOPICS:
        return QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                          durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(depth=100, reliability=QoSReliabilityPolicy.RELIABLE)


class BagRecorder(Node):
    def __init__(self):
        super().__init__("bag_recorder")
        self.declare_parameter("output", "", ParameterDescriptor(
            description="Directory of the new bag (must not exist).", read_only=True))
        self.declare_parameter("topics", [""], ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
            description="Topics to record; empty = the graph's topics (see abp_bringup.bag)."))
        self.declare_parameter("record_images", False, ParameterDescriptor(
            description="Also record /camera/image_raw (large).", read_only=True))
        self.declare_parameter("storage", "mcap", ParameterDescriptor(
            description="rosbag2 storage: mcap or sqlite3.", read_only=True))
        output = self.get_parameter("output").value
        if not output:
            raise ValueError("parameter output (the bag directory) is required")
        known = {**GRAPH_TOPICS, **IMAGE_TOPICS}
        wanted = [t for t in self.get_parameter("topics").value if t]
        if wanted:
            unknown = [t for t in wanted if t not in known]
            if unknown:
                raise ValueError(f"topics {unknown} are not graph topics; known: "
                                 f"{', '.join(sorted(known))}")
            topics = {t: known[t] for t in wanted}
        else:
            topics = dict(GRAPH_TOPICS)
            if self.get_parameter("record_images").value:
                topics.update(IMAGE_TOPICS)
        self.writer = BagWriter(output, topics, self.get_parameter("storage").value)
        # DDS matches each subscription to its publishers some time after this, so
        # the first message per topic is logged: it says that topic is being recorded.
        self._topics_heard = set()
        for topic, msgtype in topics.items():
            self.create_subscription(message_class(msgtype), topic,
                                     lambda data, t=topic: self._write(t, data),
                                     topic_qos(topic), raw=True)
        self.get_logger().info(f"recording {len(topics)} topics to {output}")

    def _write(self, topic, data):
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
        if topic not in self._topics_heard:
            self._topics_heard.add(topic)
            self.get_logger().info(f"first message on {topic}")

    def close(self):
        self.writer.close()
        self.get_logger().info(f"bag closed with {self.writer.count} messages")


def main(args=None):
    # An unclosed MCAP bag loses its index: always close it.
    return run_node("bag_recorder", BagRecorder, args, config_errors=(BagError,),
                    on_exit=BagRecorder.close)


if __name__ == "__main__":
    sys.exit(main())
