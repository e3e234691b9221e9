"""run_node over real DDS: a message rclpy cannot convert to the topic's type is dropped
with a logged error and the node spins on; an exception from the node's own callback
still ends it.

The failure is real, not injected: the tester publishes bytes that are not a valid
std_msgs/String (a string length far beyond the message), through rclpy's public raw
publish. An abp node's subscriptions take raw bytes and convert them in Python
(`tolerant_subscriptions`), so rclpy's conversion failing, as it does now and then under
load, and a malformed message end the same way: in the drop. (A plain rclpy subscription
never sees such bytes: Fast DDS drops them in its take, silently.)"""

import subprocess

import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from std_msgs.msg import String  # noqa: E402

TOPIC = '/conversion_fails_once'

# The listener stops after two messages (`stop`) or raises in its callback (`bug`).
LISTENER = f"""
import sys

import rclpy
from std_msgs.msg import String

from abp_common.node_runner import run_node
from abp_common.tolerant_subscriptions import TolerantNode


class Listener(TolerantNode):
    def __init__(self):
        super().__init__('listener')
        self.received = 0
        self.create_subscription(String, '{TOPIC}', self.on_message, 10)

    def on_message(self, msg):
        assert isinstance(msg, String), type(msg)
        self.received += 1
        print(f'got message {{self.received}}: {{msg.data}}', flush=True)
        if self.received == 2:
            if sys.argv[1] == 'bug':
                raise ValueError('a bug in the callback')
            rclpy.shutdown()


sys.exit(run_node('listener', Listener))
"""


def malformed_string():
    """A serialised String whose length field claims a billion bytes."""
    good = bytearray(serialize_message(String(data='hello')))
    length_at = 4                              # after the 4-byte CDR encapsulation header
    assert int.from_bytes(good[length_at:length_at + 4], 'little') == len('hello') + 1
    good[length_at:length_at + 4] = (10 ** 9).to_bytes(4, 'little')
    return bytes(good)


@pytest.mark.parametrize('ending', ['stop', 'bug'])
def test_a_message_rclpy_cannot_convert_is_dropped_and_a_callback_error_is_not(
        tmp_path, ros_processes, tester, spin, ending):
    script = tmp_path / 'listener.py'
    script.write_text(LISTENER)
    proc = ros_processes.start_python(script, ending)
    node, executor = tester
    publisher = node.create_publisher(String, TOPIC, 10)
    assert spin(executor, lambda: publisher.get_subscription_count() > 0, 60), \
        'the listener never subscribed'
    # Alternate malformed and valid messages until the listener ends: every malformed one
    # is dropped, the valid ones arrive.
    sent = []

    def send():
        sent.append(True)
        if len(sent) % 2:
            publisher.publish(malformed_string())
        else:
            publisher.publish(String(data=f'valid {len(sent)}'))

    node.create_timer(0.05, send)
    assert spin(executor, lambda: proc.poll() is not None, 60), 'listener did not end'
    out = ros_processes.transcript(proc)
    assert f'dropped a message on {TOPIC} that rclpy could not convert to String' in out, out
    assert 'got message 2: valid' in out, out
    if ending == 'stop':
        assert proc.returncode == 0, out
    else:
        assert proc.returncode != 0 and 'ValueError: a bug in the callback' in out, out


# Ctrl-C arrives while the main thread holds the context's lock: Python runs its SIGINT
# handler between two bytecodes of whatever the main thread is doing, which in a spinning
# node is often `Context.ok()` (the executor's loop condition). A shutdown callback runs
# under that lock too, so raising SIGINT in one puts the handler exactly there. A handler
# that took the lock (rclpy.try_shutdown) never returned: a bag recorder hung on Ctrl-C.
INTERRUPTED_UNDER_THE_LOCK = """
import signal

import rclpy

from abp_common.node_runner import init_rclpy_with_quiet_interrupt

init_rclpy_with_quiet_interrupt(None)
context = rclpy.get_default_context()
context.on_shutdown(lambda: signal.raise_signal(signal.SIGINT))
context.shutdown()
print('shut down; ok:', rclpy.ok(), flush=True)
"""


def test_ctrl_c_while_the_context_lock_is_held_neither_hangs_nor_raises(tmp_path,
                                                                       ros_processes):
    script = tmp_path / 'interrupted.py'
    script.write_text(INTERRUPTED_UNDER_THE_LOCK)
    proc = ros_processes.start_python(script)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail('the SIGINT handler waited on the context lock its own thread held')
    out = ros_processes.transcript(proc)
    assert proc.returncode == 0 and 'shut down; ok: False' in out, out
    assert 'KeyboardInterrupt' not in out, out
