"""How fast the node's clock runs against the wall: 1 on the robot, the speed-up under a
simulator's /clock. No rclpy.

The skills stamp the controllers' trajectories a little ahead so that the controllers
start together; a trajectory that arrives after its stamp starts part-way along its path
(ros2_control's convention), and a hand that skips its approach misses the cube. A lead
fixed in clock time shrinks in wall time as the speed-up grows (0.1 s of simulation time
is 10 ms of wall time at speed-up 10), so the lead is given in wall time and converted
with the measured rate."""

import threading
from collections import deque


class ClockRate:
    """Clock seconds per wall second over the last `window_s` wall seconds of samples
    (wall, clock); 1.0 until they span `min_span_s`, and never below 1 (a clock slower
    than the wall keeps the lead it would have on the robot). Thread-safe: fed by a sensor
    callback, read by the skills' threads."""

    def __init__(self, window_s=3.0, min_span_s=0.5):
        self.window_s = float(window_s)
        self.min_span_s = float(min_span_s)
        self._samples = deque()
        self._lock = threading.Lock()

    def feed(self, wall_s, clock_s):
        with self._lock:
            self._feed(float(wall_s), float(clock_s))

    def _feed(self, wall_s, clock_s):
        samples = self._samples
        if samples:
            last_wall_s, last_clock_s = samples[-1]
            if clock_s < last_clock_s:
                samples.clear()   # the clock went back (a restarted simulator): start anew
            elif wall_s <= last_wall_s:
                return
        samples.append((wall_s, clock_s))
        while len(samples) > 2 and wall_s - samples[1][0] >= self.window_s:
            samples.popleft()

    def rate(self):
        with self._lock:
            if len(self._samples) < 2:
                return 1.0
            (w0, c0), (w1, c1) = self._samples[0], self._samples[-1]
        if w1 - w0 < self.min_span_s:
            return 1.0
        return max(1.0, (c1 - c0) / (w1 - w0))
