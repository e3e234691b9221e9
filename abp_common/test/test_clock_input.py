"""ClockInput on a real rclpy context: under use_sim_time (and run_node's
`take_clock_on_own_thread()`) a managed node's clock follows
/clock through a hidden node on a thread of its own, while the node itself has no /clock
subscription and is not spun at all; the subscription is in the node's endpoint report;
use_sim_time still switches sim time off and on; destroying the node ends the thread."""

import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.clock import JumpThreshold  # noqa: E402
from rclpy.duration import Duration  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from abp_common.lifecycle import ManagedNode  # noqa: E402

WAIT_S = 30.0
CLOCK = '/clock'


def managed(context, use_sim_time):
    node = ManagedNode('timed', namespace='/clock_input_test', context=context,
                       parameter_overrides=[Parameter('autostart', value=False),
                                            Parameter('use_sim_time', value=use_sim_time)])
    node.take_clock_on_own_thread()   # what node_runner.run_node does
    return node


def clock_msg(seconds):
    msg = Clock()
    msg.clock.sec = int(seconds)
    msg.clock.nanosec = int(round((seconds % 1) * 1e9))
    return msg


class Reached:
    """Set when the clock's time reaches `seconds` (a jump callback: no polling);
    `threads` names the threads that moved the clock."""

    def __init__(self, clock):
        self.clock = clock
        self.threads = set()
        self._target = None
        self._event = threading.Event()
        threshold = JumpThreshold(min_forward=Duration(nanoseconds=1), min_backward=None,
                                  on_clock_change=False)
        self._handle = clock.create_jump_callback(threshold, post_callback=self._on_jump)

    def _on_jump(self, _jump):
        self.threads.add(threading.current_thread().name)
        if self._target is not None and self.clock.now().nanoseconds >= self._target:
            self._event.set()

    def wait(self, seconds, publish, executor):
        """Publish `seconds` on /clock (again, in case one is lost) until the clock has it."""
        self._target = int(seconds * 1e9)
        self._event.clear()
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            publish(clock_msg(seconds))
            if self._event.wait(0.2):
                return True
            executor.spin_once(timeout_sec=0.0)
        return self._event.is_set()

    def close(self):
        self._handle.unregister()


def clock_subscriptions(node):
    return [s for s in node.subscriptions if s.topic_name == CLOCK]


def test_sim_time_comes_from_the_clock_thread_not_the_nodes_executor(rclpy_context, tester,
                                                                     spin):
    owner = managed(rclpy_context, True)
    node, executor = tester
    pub = node.create_publisher(Clock, CLOCK, 10)
    reached = Reached(owner.get_clock())
    try:
        assert clock_subscriptions(owner) == [], 'the node itself still takes /clock'
        assert [s.topic_name for s in owner.clock_input.subscriptions] == [CLOCK]
        assert spin(executor, lambda: pub.get_subscription_count() > 0, WAIT_S)
        # The owner is in no executor: only the clock thread can move its clock.
        assert reached.wait(12.5, pub.publish, executor), 'the clock never reached 12.5 s'
        assert owner.get_clock().now().nanoseconds == 12_500_000_000
        assert reached.threads == {'timed-clock_input'}
        assert owner.endpoint_report()['inputs'] == {CLOCK: 1}

        # use_sim_time is still the node's switch: off gives system time, on sim time again.
        assert owner.set_parameters([Parameter('use_sim_time', value=False)])[0].successful
        assert not owner.clock_input.active
        assert owner.get_clock().now().nanoseconds > 1e18   # system time (after 2001)
        assert owner.set_parameters([Parameter('use_sim_time', value=True)])[0].successful
        assert clock_subscriptions(owner) == []
        assert owner.clock_input.active
        assert reached.wait(20.0, pub.publish, executor), 'sim time did not come back'
    finally:
        reached.close()
        thread_names = {t.name for t in threading.enumerate()}
        owner.destroy_node()
    assert 'timed-clock_input' in thread_names
    assert 'timed-clock_input' not in {t.name for t in threading.enumerate()}


def test_without_sim_time_there_is_no_clock_thread(rclpy_context):
    owner = managed(rclpy_context, False)
    try:
        assert owner.clock_input.subscriptions == [] and not owner.clock_input.active
        assert 'timed-clock_input' not in {t.name for t in threading.enumerate()}
    finally:
        owner.destroy_node()
