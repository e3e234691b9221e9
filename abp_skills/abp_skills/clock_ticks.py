"""Wake the skills' control loops when the node's clock moves, not on a wall-time poll.

Under use_sim_time the clock moves with each /clock message. A control loop that polls
every 10 ms of wall time lags the simulation by up to one poll per control period: at a
speed-up of 10, a 50 ms control period is 5 ms of wall time, so polling alone halves the
rate of base commands, and the simulator, which waits for a late base command
(abp_sim_bridge's command_wait), runs slower than asked. On the robot (system time) the
clock never jumps and the loops sleep as before."""

import threading

from rclpy.clock import JumpThreshold
from rclpy.duration import Duration


class ClockTicks:
    """`sleep(timeout)`: sleep up to `timeout` wall seconds, or until the clock moves
    forward (any step) or changes source, whichever comes first. Thread-safe."""

    def __init__(self, clock):
        self._moved = threading.Condition()
        self._ticks = 0
        threshold = JumpThreshold(min_forward=Duration(nanoseconds=1), min_backward=None,
                                  on_clock_change=True)
        # Kept: the callback lives as long as its handle.
        self._handle = clock.create_jump_callback(threshold, post_callback=self._on_jump)

    def _on_jump(self, _jump):
        with self._moved:
            self._ticks += 1
            self._moved.notify_all()

    def sleep(self, timeout):
        if timeout <= 0:
            return
        with self._moved:
            seen = self._ticks
            self._moved.wait_for(lambda: self._ticks != seen, timeout)

    def close(self):
        if self._handle is not None:
            self._handle.unregister()
            self._handle = None


__all__ = ['ClockTicks']
