"""A node's /clock taken on a small hidden node with a thread of its own.

Under use_sim_time rclpy subscribes each node to /clock on the node itself, so every
/clock message (25-50 a wall second from the sim bridge) wakes the node's executor, and
rclpy's executors rebuild their wait set from every entity of the node on each wake-up: in
the idle graph that was most of the skill servers' and the planner's CPU (their executor
thread, not the callbacks; docs/SPEED.md). Here the node's clock is driven instead by a
`rclpy.time_source.TimeSource` of a hidden node `_<owner name>_clock_input` (one subscription,
spun by a single-threaded executor on its own thread), and the node's own /clock
subscription is destroyed. The node's clock is the same object: `get_clock()`, its timers
and jump callbacks behave as before; they are now called from the clock thread.

`use_sim_time` keeps working as a parameter of the node: a change is forwarded to the
hidden time source (and a /clock subscription rclpy's own time source makes again is
destroyed again). Without use_sim_time nothing is made until it is set.
Only rclpy's public API is used: `Node.subscriptions`, `destroy_subscription`,
`TimeSource(node=...)`, `ros_time_is_active`, `attach_clock`, `detach_node`.
"""

import threading

from rclpy.parameter import Parameter
from rclpy.time_source import CLOCK_TOPIC, USE_SIM_TIME_NAME, TimeSource

from .input_node import InputNode


class ClockInput:
    """Drive `owner`'s clock from /clock on a thread of its own (module docstring)."""

    def __init__(self, owner):
        self._owner = owner
        self._lock = threading.Lock()
        self._input = None         # InputNode: the hidden node and its thread
        self._time_source = None
        if owner.get_parameter(USE_SIM_TIME_NAME).value:
            self._start()
        owner.add_post_set_parameters_callback(self._on_parameters)

    def _start(self):
        owner = self._owner
        with self._lock:
            if self._input is None:
                self._input = InputNode(owner, 'clock_input')
                self._time_source = TimeSource(node=self._input.node)
                self._time_source.attach_clock(owner.get_clock())
            self._time_source.ros_time_is_active = True
        self._drop_owner_subscription()

    def _drop_owner_subscription(self):
        for subscription in list(self._owner.subscriptions):
            if subscription.topic_name == CLOCK_TOPIC:
                self._owner.destroy_subscription(subscription)

    def _on_parameters(self, parameters):
        for parameter in parameters:
            if parameter.name == USE_SIM_TIME_NAME and parameter.type_ == Parameter.Type.BOOL:
                if parameter.value:
                    self._start()
                elif self._time_source is not None:
                    self._time_source.ros_time_is_active = False

    @property
    def node(self):
        """The hidden node that takes /clock (None until use_sim_time is first set)."""
        return None if self._input is None else self._input.node

    @property
    def subscriptions(self):
        """The clock node's subscriptions (its /clock), for the owner's endpoint report."""
        return [] if self._input is None else self._input.subscriptions

    @property
    def active(self):
        """True while /clock drives the owner's clock from the clock thread."""
        return (self._time_source is not None and self._time_source.ros_time_is_active
                and self._input.spinning)

    def close(self):
        if self._input is None:
            return
        self._time_source.detach_node()
        self._input.close()
        self._input = None


__all__ = ['ClockInput']
