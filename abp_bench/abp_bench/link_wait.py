"""`python -m abp_bench.link_wait [--timeout S] [--ros-args ...]`: wait until the
lifecycle manager says the graph is ready (true on its latched `~/graph_ready`), exit 0;
1 after `--timeout` s. For a driver in another network namespace than the manager's
(abp_bench/test/test_two_hosts.py, abp_bench.link_benchmark): after the link comes back,
the next goal waits for the graph, not for a guessed time."""

import argparse
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.utilities import remove_ros_args
from std_msgs.msg import Bool

from abp_common import qos

READY_TOPIC = 'lifecycle_manager/graph_ready'


def main(argv=None):
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(prog='python -m abp_bench.link_wait',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--timeout', type=float, default=120.0,
                        help='seconds to wait (default 120)')
    args = parser.parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv)
    node = rclpy.create_node('link_wait')
    ready = []
    node.create_subscription(Bool, READY_TOPIC, lambda msg: ready.append(msg.data),
                             qos.LATCHED)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + args.timeout
    try:
        while time.monotonic() < deadline and not (ready and ready[-1]):
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if ready and ready[-1]:
        print('graph ready', flush=True)
        return 0
    print(f'graph not ready within {args.timeout:g} s', flush=True)
    return 1


if __name__ == '__main__':
    sys.exit(main())
