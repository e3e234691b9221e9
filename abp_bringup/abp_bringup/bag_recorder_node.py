"""`bag_recorder`: records the graph's topics into a rosbag2 bag (MCAP by default).

Like `ros2 bag record`, it subscribes to a topic once its publishers are discovered (the
graph is polled every DISCOVERY_PERIOD s), with a QoS that matches all of them: reliable
if they all are, transient local if they all are (rosbag2's adaptive QoS, bag_qos). A
latched topic's last message is then recorded even if it was published before the
recorder started. The publishers' QoS profiles are stored with the topic
(`offered_qos_profiles` in metadata.yaml and in the MCAP channel), so that `ros2 bag play`
and abp's bag_player replay latched topics latched. A topic no publisher ever offered is
not in the bag (it would have no QoS to replay with).

Messages are taken serialized from DDS (no deserialisation) and written with the
node's clock as receive time, so with use_sim_time the bag is in sim time.
It logs `recording <topic> (<reliability>, <durability>) from N publishers` when it
subscribes, `publisher matched on <topic>` when a publisher is matched (a volatile topic's
earlier messages are not in the bag) and `first message on <topic>`.
Parameters (bag.RECORDER_SPECS): output (a new directory), topics (names; empty = the
graph's topics), record_images, storage (mcap | sqlite3). Topics are resolved in the
node's namespace and written to the bag with their absolute names (a graph under
/robot1 gives /robot1/abp/belief). The bag is closed on Ctrl-C / shutdown.
"""

import sys

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import qos_policy_name_from_kind

from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_common.tolerant_subscriptions import TolerantNode

from . import bag_qos
from .bag import RECORDER_SPECS, BagError, BagWriter, recorded_topics
from .bag_ros import message_class, recording_qos, to_bag_qos

# rosbag2's default topic polling interval.
DISCOVERY_PERIOD = 0.1


class BagRecorder(TolerantNode):
    def __init__(self, **node_options):
        """`node_options`: rclpy Node options (a context, parameter overrides), for a
        recorder inside another process."""
        super().__init__('bag_recorder', **node_options)
        values = declare_all(self, RECORDER_SPECS)
        output = values['output']
        if not output:
            raise ValueError('parameter output (the bag directory) is required')
        topics = recorded_topics(values['topics'], values['record_images'],
                                 self.get_namespace())
        self.writer = BagWriter(output, topics, values['storage'])
        self._waiting = dict(topics)  # topics whose publishers are not discovered yet
        self._wrong_type = set()
        self._topics_heard = set()
        self._discovery = self.create_timer(DISCOVERY_PERIOD, self._discover)
        self.get_logger().info(f'recording {len(topics)} topics to {output}')
        self._discover()

    def _discover(self):
        for topic, msgtype in list(self._waiting.items()):
            publishers = self.get_publishers_info_by_topic(topic)
            offers = [to_bag_qos(p.qos_profile) for p in publishers if p.topic_type == msgtype]
            if not offers:
                others = sorted({p.topic_type for p in publishers} - {msgtype})
                if others and topic not in self._wrong_type:
                    self._wrong_type.add(topic)
                    self.get_logger().error(f'{topic} is published as {", ".join(others)}, '
                                            f'not {msgtype}: not recorded')
                continue
            self._subscribe(topic, msgtype, offers)
            del self._waiting[topic]
        if not self._waiting:
            self._discovery.cancel()

    def _subscribe(self, topic, msgtype, offers):
        # The topic enters the bag with its publishers' QoS before its first message.
        self.writer.add_topic(topic, offers)
        profile, warnings = recording_qos(topic, offers)
        for warning in warnings:
            self.get_logger().warning(warning)
        # DDS matches the subscription to its publishers some time after this. A volatile
        # topic's messages published before the match never reach the bag, so each match
        # is logged as it happens (what a caller waits for before starting an episode),
        # and so is the first message per topic.
        self.create_subscription(
            message_class(msgtype), topic, lambda data, t=topic: self._write(t, data),
            profile, raw=True,
            event_callbacks=SubscriptionEventCallbacks(
                matched=lambda status, t=topic: self._on_matched(t, status),
                incompatible_qos=lambda status, t=topic: self._on_incompatible(t, status)))
        self.get_logger().info(
            f'recording {topic} ({bag_qos.describe(to_bag_qos(profile))}) from '
            f'{len(offers)} publisher{"s" if len(offers) > 1 else ""}')

    def _write(self, topic, data):
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
        if topic not in self._topics_heard:
            self._topics_heard.add(topic)
            self.get_logger().info(f'first message on {topic}')

    def _on_matched(self, topic, status):
        if status.current_count_change > 0:
            self.get_logger().info(f'publisher matched on {topic} '
                                   f'({status.current_count} matched)')

    def _on_incompatible(self, topic, status):
        # A publisher that appeared after the subscription, with a weaker QoS (rosbag2
        # warns the same way and does not resubscribe).
        self.get_logger().warning(
            f'a publisher on {topic} offers a QoS the recording subscription cannot match '
            f'({qos_policy_name_from_kind(status.last_policy_kind)}): its messages are not '
            'recorded')

    def close(self):
        self.writer.close()
        missing = f'; no publisher seen on {", ".join(sorted(self._waiting))}' \
            if self._waiting else ''
        self.get_logger().info(f'bag closed with {self.writer.count} messages{missing}')


def main(args=None):
    # An unclosed MCAP bag loses its index: always close it.
    return run_node('bag_recorder', BagRecorder, args, config_errors=(BagError,),
                    on_exit=BagRecorder.close)


if __name__ == '__main__':
    sys.exit(main())
