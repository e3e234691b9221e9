"""`bag_player`: replays a rosbag2 bag (MCAP or sqlite3) into the graph.

    bag_player BAG [--topics T ...] [--rate R | --fast] [--wait-for TOPIC ...] [--hold]
               [--ros-args ...]

Messages are published serialized, as recorded, on the bag's (absolute) topics, with
the QoS stored in the bag for each topic, as `ros2 bag play` does (bag_qos.playback_offer):
a latched (transient local) topic is replayed latched, so a subscriber that joins after
the message was replayed still gets it. A bag without stored QoS (recorded before abp
stored it) or with disagreeing publishers on a topic is replayed with the QoS the graph
uses on that topic, and the player says so. --hold keeps the publishers, and so the
latched topics' last messages, until Ctrl-C. Topic names given here may be relative: they are
resolved in the player's namespace (`--ros-args -r __ns:=/robot1`). --rate 1 keeps the
recorded timing; --fast publishes as fast as the subscribers take it. DDS keeps the
order within a topic only, so with --fast a subscriber that falls behind may take
messages of two topics out of their recorded order; replay at a rate when that order
matters. --wait-for waits until each named topic has a subscriber before the first
message is sent. A topic recorded with an older definition of its type (abp_msgs before
a field was added) is replayed converted to the current one, the new fields at their
defaults (bag_ros.current_message), and the player says so.
"""

import argparse
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.utilities import remove_ros_args

from abp_common import names

from . import bag_qos
from .bag import BagError, bag_topics, deserialize, offered_qos, outdated_types, read_bag
from .bag_ros import current_message, graph_qos, message_class, to_rclpy_qos

# rosbag2's replay history depth (rmw_qos_profile_default): a late subscriber of a latched
# topic gets up to this many of its last messages.
REPLAY_DEPTH = 10


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='bag_player', description=__doc__.split('\n\n')[0])
    parser.add_argument('bag', help='bag directory')
    parser.add_argument('--topics', nargs='*', default=None, help='topics to replay (default all)')
    timing = parser.add_mutually_exclusive_group()
    timing.add_argument('--rate', type=float, default=1.0, help='time scale (1 = as recorded)')
    timing.add_argument('--fast', action='store_true', help='as fast as possible')
    parser.add_argument('--wait-for', nargs='*', default=[], metavar='TOPIC',
                        help='wait until these topics have a subscriber')
    parser.add_argument('--wait-timeout', type=float, default=30.0,
                        help='seconds to wait for subscribers (--wait-for) and, at the end, '
                        'for the reliable subscribers to acknowledge every message')
    parser.add_argument('--gap', type=float, default=0.002,
                        help='seconds between messages with --fast (lets DDS deliver in order)')
    parser.add_argument('--hold', action='store_true',
                        help='after the last message, keep publishing latched topics to late '
                        'subscribers until Ctrl-C')
    args = parser.parse_args(argv)
    if args.rate <= 0:
        parser.error('--rate must be > 0')
    return args


def replay_qos(topic, profiles):
    """The QoSProfile to replay `topic` with, from its recorded `profiles`; the graph's
    QoS (with a line on stderr saying why) when the bag has no single profile."""
    offer = bag_qos.playback_offer(profiles)
    if offer is not None:
        depth = max(REPLAY_DEPTH, graph_qos(topic).depth)
        print(f'[bag_player] {topic}: recorded QoS ({bag_qos.describe(offer)})', flush=True)
        return to_rclpy_qos(offer, depth)
    fallback = graph_qos(topic)
    why = ('its publishers offered different QoS' if profiles else
           'the bag stores no QoS for it (recorded before abp stored QoS)')
    print(f"[bag_player] {topic}: {why}; replaying with the graph's QoS "
          f'({fallback.reliability.name.lower()}, {fallback.durability.name.lower()})',
          file=sys.stderr, flush=True)
    return fallback


def play(publishers, messages, rate, fast, gap):
    first_stamp = None
    started = time.monotonic()
    count = 0
    for topic, _msgtype, stamp, data in messages:
        if fast:
            time.sleep(gap)
        else:
            first_stamp = stamp if first_stamp is None else first_stamp
            delay = (stamp - first_stamp) / 1e9 / rate - (time.monotonic() - started)
            if delay > 0:
                time.sleep(delay)
        publishers[topic].publish(data)
        count += 1
    return count


def current_messages(messages, outdated):
    """The bag's (topic, msgtype, stamp, data), with the data of an `outdated` type
    ({msgtype: the bag's typestore}) made a message of the current definition."""
    for msgtype in sorted(outdated):
        print(f'[bag_player] {msgtype} was recorded with another definition: replayed '
              'converted to the current one (fields the bag lacks at their defaults)',
              flush=True)
    classes = {}
    for topic, msgtype, stamp, data in messages:
        if msgtype in outdated:
            cls = classes.setdefault(msgtype, message_class(msgtype))
            data = current_message(deserialize(outdated[msgtype], data, msgtype), cls)
        yield topic, msgtype, stamp, data


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_args(remove_ros_args(['bag_player', *argv])[1:])
    rclpy.init(args=['bag_player', *argv])
    node = rclpy.create_node('bag_player')
    namespace = node.get_namespace()
    args.topics = [names.absolute(t, namespace) for t in args.topics or ()]
    args.wait_for = [names.absolute(t, namespace) for t in args.wait_for]
    try:
        topics = bag_topics(args.bag)
        if args.topics:
            missing = sorted(set(args.topics) - set(topics))
            if missing:
                raise BagError(f"topics {missing} are not in {args.bag} (it has "
                               f"{', '.join(sorted(topics))})")
            topics = {t: topics[t] for t in args.topics}
        # All publishers first, so that nothing is published before it is matched.
        profiles = offered_qos(args.bag)
        publishers = {topic: node.create_publisher(
                          message_class(msgtype), topic,
                          replay_qos(topic, profiles.get(topic, [])))
                      for topic, msgtype in topics.items()}
        deadline = time.monotonic() + args.wait_timeout
        for topic in args.wait_for:
            if topic not in publishers:
                raise BagError(f'--wait-for {topic}: not a replayed topic')
            while publishers[topic].get_subscription_count() == 0:
                if time.monotonic() > deadline:
                    print(f'[bag_player] no subscriber on {topic} within {args.wait_timeout} s',
                          file=sys.stderr)
                    return 1
                time.sleep(0.05)
        messages = current_messages(read_bag(args.bag, list(topics)), outdated_types(args.bag))
        count = play(publishers, messages, args.rate, args.fast, args.gap)
        # A reliable writer destroyed before its readers acknowledged would lose the tail.
        unacked = [topic for topic, publisher in publishers.items()
                   if not publisher.wait_for_all_acked(Duration(seconds=args.wait_timeout))]
        print(f'[bag_player] replayed {count} messages from {args.bag}', flush=True)
        if unacked:
            print(f'[bag_player] not acknowledged within {args.wait_timeout} s on '
                  f"{', '.join(unacked)}: the last messages may not have been taken",
                  file=sys.stderr)
            return 1
        if args.hold:
            print('[bag_player] holding the publishers until Ctrl-C', flush=True)
            try:
                rclpy.spin(node)  # nothing to execute: DDS serves late subscribers
            except (KeyboardInterrupt, ExternalShutdownException):
                pass  # the end a holding player waits for
        return 0
    except BagError as error:
        print(f'[bag_player] {error}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
