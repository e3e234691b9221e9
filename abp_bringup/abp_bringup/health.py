"""`health`: a one-screen summary of the graph's /diagnostics.

    health [--duration S] [--watch] [--ros-args ...]

Listens to /diagnostics (diagnostic_msgs/DiagnosticArray; every abp node publishes its
status there once a second, abp_common.health) for `--duration` seconds and prints, per
node, its level and one-line message, its inputs (rate and age of the last), its
processing latency and its rejected inputs by topic and kind. `--watch` prints again
every `--duration` seconds until Ctrl-C. Exit code: 0 when every node is OK, 1 when one
warns, 2 on an error or when no node reported.
"""

import argparse
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.utilities import remove_ros_args

from abp_common import diagnostic_keys as keys
from abp_common.health import DIAGNOSTICS, node_of_status

LEVELS = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}


def level_of(status):
    level = status.level
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def summarize(statuses, width=100):
    """The summary text of the latest DiagnosticStatus of each node."""
    lines = [f'{"NODE":<24} {"LEVEL":<6} MESSAGE']
    for name in sorted(statuses):
        status = statuses[name]
        values = {kv.key: kv.value for kv in status.values}
        node = node_of_status(name) or name
        lines.append(f'{node:<24} {LEVELS.get(level_of(status), "?"):<6} '
                     f'{status.message}'[:width])
        state = values.get(keys.LIFECYCLE_STATE, 'active')
        if state != 'active':
            lines.append(f'  {keys.LIFECYCLE_STATE}: {state}')
        inputs = []
        for key, value in values.items():
            topic = keys.rate_topic(key)
            if topic is None:
                continue
            age = values.get(keys.age_key(topic))
            inputs.append(f'{topic} {value} Hz (last {"?" if age is None else age}'
                          f'{"" if age == keys.AGE_NEVER else " s ago"})')
        if inputs:
            lines.extend(_wrapped('  inputs:   ', inputs, width))
        if keys.LATENCY_MEAN in values:
            lines.append(f'  latency:  mean {values[keys.LATENCY_MEAN]} ms, '
                         f'p95 {values.get(keys.LATENCY_P95, "?")} ms, '
                         f'max {values.get(keys.LATENCY_MAX, "?")} ms')
        rejected = {}
        for key, value in values.items():
            parsed = keys.parse_rejected(key)
            if parsed is not None:
                topic, kind = parsed
                rejected.setdefault(topic, []).append(f'{kind} {value}')
        for topic, kinds in sorted(rejected.items()):
            lines.extend(_wrapped(f'  rejected: {topic}: ', kinds, width))
    return '\n'.join(lines)


def _wrapped(prefix, items, width):
    lines, line = [], prefix
    for item in items:
        text = item if line == prefix else ', ' + item
        if len(line) + len(text) > width and line != prefix:
            lines.append(line + ',')
            line = ' ' * len(prefix) + item
        else:
            line += text
    lines.append(line)
    return lines


def worst_level(statuses):
    return max((level_of(s) for s in statuses.values()), default=2)


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='health', description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, default=2.5,
                        help='seconds to listen before printing (default 2.5)')
    parser.add_argument('--watch', action='store_true', help='print again until Ctrl-C')
    args = parser.parse_args(argv)
    if args.duration <= 0:
        parser.error('--duration must be > 0')
    return args


def main(argv=None):
    argv = sys.argv if argv is None else argv
    args = parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv)
    node = rclpy.create_node('health_summary')
    statuses = {}

    def on_diagnostics(msg):
        for status in msg.status:
            statuses[status.name] = status

    node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diagnostics, 50)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    code = 2
    try:
        while True:
            deadline = time.monotonic() + args.duration
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.1)
            if statuses:
                print(summarize(statuses), flush=True)
            else:
                print(f'no node reported on {DIAGNOSTICS} in {args.duration:g} s', flush=True)
            code = worst_level(statuses) if statuses else 2
            if not args.watch:
                break
            print(flush=True)
            statuses.clear()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return min(code, 2)


if __name__ == '__main__':
    sys.exit(main())
