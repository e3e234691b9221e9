"""`bag_recorder`: records the graph's topics into a rosbag2 bag (MCAP by default).

Messages are taken serialized from DDS (no deserialisation) and written with the
node's clock as receive time, so with use_sim_time the bag is in sim time.
It logs `publisher matched on <topic>` when a publisher of a recorded topic is matched
(a volatile topic's earlier messages are not in the bag) and `first message on <topic>`.
Parameters (bag.RECORDER_SPECS): output (a new directory), topics (names; empty = the
graph's topics), record_images, storage (mcap | sqlite3). Topics are resolved in the
node's namespace and written to the bag with their absolute names (a graph under
/robot1 gives /robot1/abp/belief). The bag is closed on Ctrl-C / shutdown.
"""

import importlib
import sys

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node

from abp_common import qos
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all

from .bag import (
    LATCHED_TOPICS,
    RECORDER_SPECS,
    SENSOR_TOPICS,
    BagError,
    BagWriter,
    graph_name,
    recorded_topics,
)

# Depth of the reliable event topics: the writer must not drop a burst.
EVENT_DEPTH = 100


def message_class(msgtype):
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def topic_qos(topic):
    """The QoS the graph uses on `topic` (absolute, in any namespace)."""
    name = graph_name(topic)
    if name in SENSOR_TOPICS:
        return qos.SENSOR_DATA
    if name in LATCHED_TOPICS:
        return qos.LATCHED
    return qos.reliable(EVENT_DEPTH)


class BagRecorder(Node):
    def __init__(self):
        super().__init__('bag_recorder')
        values = declare_all(self, RECORDER_SPECS)
        output = values['output']
        if not output:
            raise ValueError('parameter output (the bag directory) is required')
        topics = recorded_topics(values['topics'], values['record_images'],
                                 self.get_namespace())
        self.writer = BagWriter(output, topics, values['storage'])
        # DDS matches each subscription to its publishers some time after this. A
        # volatile topic's messages published before the match never reach the bag, so
        # each match is logged as it happens (what a caller waits for before starting an
        # episode), and so is the first message per topic.
        self._topics_heard = set()
        for topic, msgtype in topics.items():
            self.create_subscription(
                message_class(msgtype), topic, lambda data, t=topic: self._write(t, data),
                topic_qos(topic), raw=True,
                event_callbacks=SubscriptionEventCallbacks(
                    matched=lambda status, t=topic: self._on_matched(t, status)))
        self.get_logger().info(f'recording {len(topics)} topics to {output}')

    def _write(self, topic, data):
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
        if topic not in self._topics_heard:
            self._topics_heard.add(topic)
            self.get_logger().info(f'first message on {topic}')

    def _on_matched(self, topic, status):
        if status.current_count_change > 0:
            self.get_logger().info(f'publisher matched on {topic} '
                                   f'({status.current_count} matched)')

    def close(self):
        self.writer.close()
        self.get_logger().info(f'bag closed with {self.writer.count} messages')


def main(args=None):
    # An unclosed MCAP bag loses its index: always close it.
    return run_node('bag_recorder', BagRecorder, args, config_errors=(BagError,),
                    on_exit=BagRecorder.close)


if __name__ == '__main__':
    sys.exit(main())
