"""What a running skill decides besides its plan, in plain code (no rclpy): whether a goal's
values are acceptable, when it has run out of time, when a phase's joints have arrived (or
never will), what a base drive does when its odometry goes stale, when feedback is due, and
how to wait on a clock that may stop.

Clocks are injected (`now` is the node's clock, sim time under use_sim_time; `monotonic`
is wall time), so the rules are unit-tested without a ROS graph.
"""

import math
import time

import numpy as np

FEEDBACK_PERIOD_S = 0.25


class Refused(Exception):
    """The skill cannot start (or go on); the message is the result's reason."""


def manual_goal_overrides(skill, goal):
    """SkillConfig overrides from a PUSH, LIFT or FLIP goal (fields as in abp_msgs/action);
    raises Refused when the goal asks for what the skill cannot do."""
    if skill == 'push':
        face = (goal.face or 'front').strip().lower()
        if face != 'front':
            raise Refused(f'refused: PUSH supports only the front face, not {goal.face!r}')
        overrides = {'push_stroke': goal.stroke_length}
    elif skill == 'lift':
        overrides = {'lift_height': goal.lift_height}
    elif skill == 'flip':
        overrides = {'flip_roll_deg': goal.roll_deg}
    else:
        raise ValueError(f'{skill!r} is not a manual skill')
    for name, value in overrides.items():
        if not math.isfinite(value) or value < 0:
            raise Refused(f'refused: {name} must be >= 0, got {value}')
    return overrides


def timeout_reason(elapsed_s, limit_s):
    """The abort reason when a skill has run longer than `limit_s`, or when its clock went
    back (a restarted simulator starts its /clock again from 0, with the robot and the cube
    back at their initial poses: the motion no longer fits the world, and a timeout measured
    on that clock would never come), else None."""
    if elapsed_s < 0.0:
        return (f'the clock went back {-elapsed_s:.1f} s during the skill (a restarted '
                'simulator?)')
    if elapsed_s > limit_s:
        return f'timeout: the skill took more than {limit_s:.0f} s'
    return None


class FeedbackThrottle:
    """Feedback at most every `period_s` of the skill's time (the first call is due)."""

    def __init__(self, period_s=FEEDBACK_PERIOD_S):
        self.period_s = float(period_s)
        self._last = None

    def due(self, t):
        if self._last is None or t - self._last >= self.period_s:
            self._last = t
            return True
        return False


class ArrivalCheck:
    """Whether the joints reached the end of a phase trajectory once it has ended.

    Arrived: every joint within `tolerance` (rad) of the trajectory's end. Failed: not so
    `settle_s` after the end in the skill's time (node clock) *and* in wall time: at a high
    sim speed-up on a busy machine the joint states can lag the sim clock by more than
    `settle_s`."""

    def __init__(self, phase, joint_names, end, duration_s, tolerance, settle_s,
                 monotonic=time.monotonic):
        self.phase = phase
        self.joint_names = tuple(joint_names)
        self.end = np.asarray(end, dtype=float)
        self.duration_s = float(duration_s)
        self.tolerance = float(tolerance)
        self.settle_s = float(settle_s)
        self._monotonic = monotonic
        self._ended_wall = None

    def ended(self, t):
        """The trajectory's time is over at `t` (s since its start)."""
        return t >= self.duration_s

    def check(self, t, q_phase):
        """(done, reason) at time `t` with the joints `q_phase` (over joint_names):
        (False, '') keep waiting, (True, '') arrived, (True, reason) give up."""
        if not self.ended(t):
            return False, ''
        err = np.abs(np.asarray(q_phase, dtype=float) - self.end)
        if np.max(err) <= self.tolerance:
            return True, ''
        if self._ended_wall is None:
            self._ended_wall = self._monotonic()
        if (t >= self.duration_s + self.settle_s
                and self._monotonic() - self._ended_wall >= self.settle_s):
            worst = self.joint_names[int(np.argmax(err))]
            return True, (f'the joints did not reach the end of the {self.phase} phase '
                          f'({worst} {np.max(err):.3f} rad off)')
        return False, ''


class OdometryGap:
    """What a base drive does when its odometry goes stale, in *wall* time.

    `max_state_age` is node time (sim time under use_sim_time): at a sim speed-up of 10,
    1 s of it is 100 ms of wall time, and a skills process starved of CPU that briefly
    reads /clock ahead of /odom sees odometry that is late, not lost. So a stale pose does
    not abort the drive at once: the base stops and the drive holds (its plan time paused)
    until a fresh pose arrives; it aborts only when none arrives within `max_wait_s` of
    wall time. `update(fresh)` returns the step to take:

    - 'drive': the pose is fresh, track the plan;
    - 'stop': the pose just went stale: stop the base and hold;
    - 'hold': still stale, within the wall-time wait: keep holding (already stopped);
    - 'resume': fresh again after a hold: shift the plan time by the time held, drive on;
    - 'abort': stale for longer than `max_wait_s` wall seconds (`reason()` says so).
    """

    def __init__(self, max_wait_s, monotonic=time.monotonic):
        self.max_wait_s = float(max_wait_s)
        self._monotonic = monotonic
        self._since = None      # wall time the pose went stale; None while fresh
        self._waited = 0.0

    @property
    def holding(self):
        return self._since is not None

    def update(self, fresh):
        if fresh:
            held, self._since = self._since is not None, None
            return 'resume' if held else 'drive'
        now = self._monotonic()
        if self._since is None:
            self._since = now
            self._waited = 0.0
            return 'abort' if self.max_wait_s <= 0 else 'stop'
        self._waited = now - self._since
        return 'abort' if self._waited >= self.max_wait_s else 'hold'

    def reason(self):
        return (f'odometry lost: no recent /odom for {self._waited:.1f} s of wall time '
                f'(state_wait_timeout {self.max_wait_s:.1f} s)')


def sleep_on_clock(seconds, now, sleep=time.sleep, monotonic=time.monotonic):
    """Sleep `seconds` on the clock `now()` (sim time when use_sim_time is set), at most a
    few wall seconds (max(0.5, 5 x seconds)) so that a stopped /clock cannot block cancel
    and timeout checks. `sleep(t)` may return early (clock_ticks.ClockTicks.sleep wakes
    when the clock moves): the clock is read again after each return."""
    end = now() + seconds
    wall_end = monotonic() + max(0.5, 5.0 * seconds)
    while now() < end and monotonic() < wall_end:
        sleep(min(0.01, max(0.0, end - now())))


__all__ = ['ArrivalCheck', 'FeedbackThrottle', 'OdometryGap', 'Refused',
           'manual_goal_overrides', 'sleep_on_clock', 'timeout_reason']
