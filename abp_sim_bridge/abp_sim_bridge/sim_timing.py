"""When the sim_bridge's simulation thread ticks and publishes (plain Python, no rclpy).

- `Pacer`: simulation time against wall time at a speed-up; catching up when a tick is
  late, giving up (simulation time runs slower) when too far behind, and the real-time
  factor report. The wall clock is injected, so the rules are unit-tested without sleeps.
- `CameraSchedule`, `GroundTruthSchedule`, `StateSchedule`: which ticks (simulation time)
  may take a camera frame, and publish the ground truth, joint states and odometry.
- `BaseCommandWait`: the simulation waits for a late base command rather than drive on.
- `WallRateLimit`: at most so many events per wall second (camera frames, /clock), so that
  at a speed-up the graph is not flooded with what it cannot use.

Simulation times are integer nanoseconds; wall times float seconds.
"""

import time

MAX_LAG_WALL_S = 0.1        # further behind than this: stop trying to catch up (re-anchor)
MAX_WAIT_WALL_S = 0.05      # longest single wait, so a stop or a new speed-up is seen soon
REPORT_PERIOD_WALL_S = 10.0  # how often the real-time factor is checked
SLOW_FRACTION = 0.9         # a factor below this share of the speed-up is reported


class Pacer:
    """Paces simulation ticks to `speedup` x wall time.

    Simulation time is anchored to a wall-clock instant: the tick to simulation time t is
    due when the wall clock reaches wall0 + (t - sim0) / speedup. Late ticks run at once
    (catching up), unless the simulation is more than `max_lag_wall_s` behind: then the
    anchor moves to now, and simulation time simply runs slower than asked for (never
    inconsistently). A new speed-up also moves the anchor. `clock()` returns wall seconds
    (monotonic)."""

    def __init__(self, speedup, sim_ns, clock=time.monotonic, max_lag_wall_s=MAX_LAG_WALL_S,
                 max_wait_wall_s=MAX_WAIT_WALL_S, report_period_s=REPORT_PERIOD_WALL_S,
                 slow_fraction=SLOW_FRACTION):
        self._clock = clock
        self.max_lag_wall_s = max_lag_wall_s
        self.max_wait_wall_s = max_wait_wall_s
        self.report_period_s = report_period_s
        self.slow_fraction = slow_fraction
        self.speedup = self._requested = float(speedup)
        self._now = self._wall0 = clock()
        self._sim0 = int(sim_ns)
        self._report_wall, self._report_sim = self._wall0, self._sim0

    def set_speedup(self, speedup):
        """Ask for a new speed-up (from any thread); it applies at the next `wait_s`."""
        self._requested = float(speedup)

    def wait_s(self, sim_ns, next_ns):
        """Wall seconds to wait before the tick from `sim_ns` to `next_ns`; 0.0: tick now."""
        now = self._clock()
        if self._requested != self.speedup:
            self.speedup = self._requested
            self._wall0, self._sim0 = now, sim_ns
        ns_per_wall_s = self.speedup * 1e9
        target = self._sim0 + (now - self._wall0) * ns_per_wall_s
        if next_ns > target:
            return min((next_ns - target) / ns_per_wall_s, self.max_wait_wall_s)
        if (target - next_ns) / ns_per_wall_s > self.max_lag_wall_s:
            # Too far behind to catch up smoothly: let simulation time run slower.
            self._wall0, self._sim0 = now, sim_ns
        self._now = now
        return 0.0

    def ticked(self, sim_ns):
        """Call after each tick (now at `sim_ns`). Every `report_period_s`: the real-time
        factor reached over the period when it fell short of the speed-up, else None."""
        elapsed = self._now - self._report_wall
        if elapsed <= self.report_period_s:
            return None
        factor = (sim_ns - self._report_sim) * 1e-9 / elapsed
        self._report_wall, self._report_sim = self._now, sim_ns
        return factor if factor < self.slow_fraction * self.speedup else None


def _period_ns(rate_hz):
    return int(round(1e9 / rate_hz)) if rate_hz > 0 else 0


class CameraSchedule:
    """Camera frames at whole multiples of the camera period (t = 0.1, 0.2, ... s at 10 Hz),
    from the first tick after `start_ns`; rate 0: none. A tick that falls behind by more
    than a period skips the missed frames (one frame per tick at most)."""

    def __init__(self, rate_hz, start_ns, tick_ns):
        self.period_ns = _period_ns(rate_hz)
        self.next_ns = None
        if self.period_ns:
            p = self.period_ns
            self.next_ns = ((start_ns + tick_ns + p - 1) // p) * p

    def due(self, t_ns):
        """True when the tick at `t_ns` draws a frame."""
        if self.next_ns is None or t_ns < self.next_ns:
            return False
        self.next_ns += self.period_ns
        if self.next_ns <= t_ns:
            self.next_ns = t_ns + self.period_ns
        return True


class GroundTruthSchedule:
    """Ground truth every 1/rate of simulation time from the first tick after `start_ns`,
    and at once on the first tick and after every contact event (rate 0: only then)."""

    def __init__(self, rate_hz, start_ns, tick_ns):
        self.period_ns = _period_ns(rate_hz)
        self.next_ns = start_ns + tick_ns
        self._first = True

    def due(self, t_ns, events=False):
        """True when the tick at `t_ns` (with new contact events or not) publishes."""
        if not (events or self._first or (self.period_ns and t_ns >= self.next_ns)):
            return False
        if self.period_ns:
            while self.next_ns <= t_ns:
                self.next_ns += self.period_ns
        self._first = False
        return True


class StateSchedule:
    """Joint states and odometry at whole multiples of 1/rate of simulation time (t = 0.04,
    0.08, ... s at 25 Hz), from the first tick after `start_ns`; a rate at or above the
    tick rate: every tick. `due(t_ns, forced)`: `forced` (a camera frame at this tick)
    publishes too and does not move the schedule."""

    def __init__(self, rate_hz, start_ns, tick_ns):
        self.period_ns = p = _period_ns(rate_hz)
        self.tick_ns = tick_ns
        self.next_ns = ((start_ns + tick_ns + p - 1) // p) * p if p else 0

    def due(self, t_ns, forced=False):
        if self.period_ns <= self.tick_ns:
            return True
        if t_ns < self.next_ns:
            return forced
        while self.next_ns <= t_ns:
            self.next_ns += self.period_ns
        return True


class WallRateLimit:
    """At most `max_hz` events per second of wall time (0: no limit). `ready(now)` says
    whether one may happen now; `taken(now)` records that it did. Wall seconds."""

    def __init__(self, max_hz):
        self.min_gap_s = 1.0 / max_hz if max_hz > 0 else 0.0
        self._last = None

    def ready(self, now):
        return self._last is None or now - self._last >= self.min_gap_s

    def taken(self, now):
        self._last = now


class BaseCommandWait:
    """While the base drives on a /cmd_vel, its controller (the skills) sends one every
    control period. When the next is later than `after_s` of simulation time, the machine
    cannot run that loop at the speed-up asked for: the simulation waits for the command
    (`hold` True), up to `max_wall_s` of wall time per command; after that the base's
    cmd_vel_timeout applies as on a robot. So a loaded machine slows simulation time
    instead of letting the base drive on unsteered (at speed-up 10, 0.5 s of
    cmd_vel_timeout is 50 ms of wall time). `after_s` 0: never waits."""

    def __init__(self, after_s, max_wall_s=0.5):
        self.after_ns = int(round(after_s * 1e9))
        self.max_wall_s = max_wall_s
        self._late_cmd_ns = None
        self._since = 0.0
        self.waits = 0          # commands waited for, since the start

    def hold(self, sim_ns, cmd, cmd_time_ns, wall_now):
        if not self.after_ns or cmd is None or not any(cmd) or \
                sim_ns - cmd_time_ns < self.after_ns:
            return False
        if self._late_cmd_ns != cmd_time_ns:     # a new late command: start waiting
            self._late_cmd_ns, self._since = cmd_time_ns, wall_now
            self.waits += 1
        return wall_now - self._since < self.max_wall_s


def sim_seconds(stamp_ns, epoch_ns):
    """Simulation seconds of a command's header stamp (`epoch_ns`: the wall-clock time of
    simulation time 0 when stamps are wall time, else 0); a zero stamp means on receipt
    and reads as 0.0."""
    return 0.0 if stamp_ns == 0 else (stamp_ns - epoch_ns) * 1e-9


__all__ = ['BaseCommandWait', 'CameraSchedule', 'GroundTruthSchedule', 'Pacer',
           'StateSchedule', 'WallRateLimit', 'sim_seconds']
