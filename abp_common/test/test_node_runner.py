"""run_node over real DDS: a message rclpy fails to take (injected in rclpy's own take
step) is dropped and the node spins on; an exception from the node's own callback still
ends it."""

import pytest

pytest.importorskip('rclpy')

from std_msgs.msg import String  # noqa: E402

# The listener fails rclpy's first take on /take_fails_once (as rclpy's take_message does now and
# then under load), then stops after two messages (`stop`) or raises in its callback (`bug`).
LISTENER = """
import sys

import rclpy
from rclpy.executors import Executor
from rclpy.node import Node
from std_msgs.msg import String

from abp_common.node_runner import run_node

original_take = Executor._take_subscription
failed = []


def take_failing_once(self, sub):
    if sub.topic_name == '/take_fails_once' and not failed:
        failed.append(True)
        raise RuntimeError('Unable to convert call argument (injected)')
    return original_take(self, sub)


Executor._take_subscription = take_failing_once


class Listener(Node):
    def __init__(self):
        super().__init__('listener')
        self.received = 0
        self.create_subscription(String, '/take_fails_once', self.on_message, 10)

    def on_message(self, msg):
        self.received += 1
        print(f'got message {self.received}', flush=True)
        if self.received == 2:
            if sys.argv[1] == 'bug':
                raise ValueError('a bug in the callback')
            rclpy.shutdown()


sys.exit(run_node('listener', Listener))
"""


@pytest.mark.parametrize('ending', ['stop', 'bug'])
def test_a_failed_take_is_dropped_and_a_callback_error_is_not(
        tmp_path, ros_processes, tester, spin, ending):
    script = tmp_path / 'listener.py'
    script.write_text(LISTENER)
    proc = ros_processes.start_python(script, ending)
    node, executor = tester
    publisher = node.create_publisher(String, '/take_fails_once', 10)
    # A steady stream until the listener ends: the first take fails, later ones arrive.
    node.create_timer(0.05, lambda: publisher.publish(String(data='hello')))
    assert spin(executor, lambda: proc.poll() is not None, 60), 'listener did not end'
    out = ros_processes.transcript(proc)
    assert 'dropped a message on /take_fails_once that rclpy could not take' in out, out
    assert 'got message 2' in out, out
    if ending == 'stop':
        assert proc.returncode == 0, out
    else:
        assert proc.returncode != 0 and 'ValueError: a bug in the callback' in out, out
