"""`python -m abp_bench.link_meter --side robot|workstation [--out FILE]`: what one part of
a split graph sends across the link, per topic, until SIGINT/SIGTERM (then it writes a
JSON report).

Runs beside one part (in its network namespace, abp_bench.link_benchmark). It subscribes,
serialized (`raw=True`, nothing decoded), to each topic whose publishers are all nodes of
its own part and that a node of the other part subscribes to: those messages cross the
link. The meter's subscription is local to the publisher, so it adds no traffic to the
link. Per topic: messages, serialized bytes (the CDR payload: the link also carries
RTPS/UDP/IP headers, discovery, heartbeats and acknowledgements; the interface counters
give the total), and the first and last arrival.

For the latency from image to belief, it also records the wall time (CLOCK_REALTIME, the
same on both sides: one machine) at which each stamp first arrived on the topics of
`--stamps` (by default camera_info, published with each image, on the robot side; the
belief on the workstation side): the stamp is read from the message's std_msgs/Header,
which every such message starts with.

With discovery through a Fast DDS discovery server, a plain client learns only the
endpoints of the topics it uses itself: the meter must run as a super client (a Fast DDS
profile, abp_bench.link_benchmark writes one) to see every topic.
"""

import argparse
import importlib
import json
import signal
import struct
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from abp_common import names
from abp_common.graph_nodes import PERCEPTION_PARTS, ROBOT_PART, WORKSTATION_PART, graph_nodes

SIDES = ('robot', 'workstation')
# Nodes of the workstation part besides the graph's: the manager and the clients that
# run beside it (the goal's client, this meter).
WORKSTATION_EXTRA = ('lifecycle_manager', 'recognize_client', 'soak_driver', 'link_wait',
                     'link_meter_workstation')
DEFAULT_STAMPS = {'robot': ['/camera/camera_info'],
                  'workstation': [names.absolute(names.BELIEF, '')]}
SCAN_PERIOD_S = 1.0
INPUT_NODE_SUFFIX = '_inputs'
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


def side_of(node_name, perception=ROBOT_PART):
    """The part a node of the graph runs in, by its name (the detector and matcher in
    `perception`)."""
    workstation = ({n.name for n in graph_nodes(part=WORKSTATION_PART, perception=perception)}
                   | set(WORKSTATION_EXTRA))
    # A node's hidden input node (abp_common.input_node, `_<owner>_inputs`) is its owner's.
    if node_name.startswith('_') and node_name.endswith(INPUT_NODE_SUFFIX):
        node_name = node_name[1:-len(INPUT_NODE_SUFFIX)]
    return 'workstation' if node_name in workstation else 'robot'


def message_class(type_name):
    """The Python class of a ROS type name such as 'std_msgs/msg/Bool'."""
    package, kind, name = type_name.split('/')
    module = importlib.import_module(f'{package}.{kind}')
    if kind == 'action' and not hasattr(module, name):
        # An action's hidden topics: 'pkg/action/Flip_FeedbackMessage' is Flip.Impl's.
        action, _, part = name.partition('_')
        return getattr(getattr(module, action).Impl, part)
    return getattr(module, name)


def header_stamp_ns(serialized):
    """The stamp of a CDR-serialized message that starts with std_msgs/Header (after the
    4-byte encapsulation header: int32 sec, uint32 nanosec, little endian)."""
    sec, nanosec = struct.unpack_from('<iI', serialized, 4)
    return sec * 1_000_000_000 + nanosec


class TopicMeter:
    def __init__(self, node, side, stamp_topics, perception=ROBOT_PART):
        self.node = node
        self.side = side
        self.perception = perception
        self.stamp_topics = set(stamp_topics)
        self.lock = threading.Lock()
        self.topics = {}        # topic -> {'type', 'messages', 'bytes', 'first', 'last', ...}
        self.stamps = {}        # topic -> {stamp ns: wall time of first arrival}
        self._subscriptions = {}
        self.qos = QoSProfile(depth=200, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.BEST_EFFORT)
        self.started = time.time()
        node.create_timer(SCAN_PERIOD_S, self.scan)

    def crossing(self, topic):
        """(whether `topic` goes from this part to the other, the remote subscribers)."""
        own = self.node.get_name()
        publishers = [i.node_name for i in self.node.get_publishers_info_by_topic(topic)
                      if i.node_name != own]
        subscribers = [i.node_name for i in self.node.get_subscriptions_info_by_topic(topic)
                       if i.node_name != own]
        if not publishers or UNKNOWN_NODE in publishers + subscribers:
            return False, []
        remote = sorted({s for s in subscribers
                         if side_of(s, self.perception) != self.side})
        return all(side_of(p, self.perception) == self.side for p in publishers) \
            and bool(remote), remote

    def scan(self):
        for topic, types in self.node.get_topic_names_and_types():
            wanted = topic in self.stamp_topics
            if topic in self._subscriptions:
                continue
            crosses, remote = self.crossing(topic)
            if not (crosses or wanted):
                continue
            try:
                kind = message_class(types[0])
            except (ImportError, AttributeError, ValueError) as error:
                self.node.get_logger().warning(f'{topic}: type {types[0]} not found ({error})')
                self._subscriptions[topic] = None
                continue
            with self.lock:
                self.topics[topic] = {'type': types[0], 'crosses': crosses,
                                      'remote_subscribers': remote, 'messages': 0,
                                      'bytes': 0, 'first': None, 'last': None}
            self._subscriptions[topic] = self.node.create_subscription(
                kind, topic, lambda data, topic=topic: self.on_message(topic, data), self.qos,
                raw=True)

    def on_message(self, topic, data):
        now = time.time()
        with self.lock:
            entry = self.topics[topic]
            entry['messages'] += 1
            entry['bytes'] += len(data)
            entry['first'] = entry['first'] or now
            entry['last'] = now
            if topic in self.stamp_topics:
                self.stamps.setdefault(topic, {}).setdefault(header_stamp_ns(data), now)

    def report(self):
        with self.lock:
            return {'side': self.side, 'started': self.started, 'ended': time.time(),
                    'topics': self.topics,
                    'stamps': {t: {str(k): v for k, v in s.items()}
                               for t, s in self.stamps.items()}}


def main(argv=None):
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog='python -m abp_bench.link_meter',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--side', choices=SIDES, required=True)
    parser.add_argument('--out', help='the JSON report (default: stdout)')
    parser.add_argument('--perception', choices=PERCEPTION_PARTS, default=ROBOT_PART,
                        help='the part the detector and matcher run in (default robot)')
    parser.add_argument('--stamps', nargs='*', default=None,
                        help='topics whose header stamps are timed (default: camera_info on '
                             'the robot, the belief on the workstation)')
    args = parser.parse_args(remove_ros_args(argv)[1:])
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f'link_meter_{args.side}')
    meter = TopicMeter(node, args.side, DEFAULT_STAMPS[args.side] if args.stamps is None
                       else args.stamps, args.perception)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print('metering', flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        report = meter.report()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    text = json.dumps(report)
    if args.out:
        with open(args.out, 'w') as out:
            out.write(text)
    else:
        print(text, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
