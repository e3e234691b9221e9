"""A node's health, counted (plain Python, no rclpy): what `abp_common.health` publishes.

`HealthStats` counts inputs per topic (rate over a sliding window, age of the last),
rejected inputs per (topic, kind), processing latencies, and decides when a rejection is
logged: each (topic, kind) at most once per `log_period_s`, the line saying how many of
that kind were rejected so far. `summary()` turns it into a level (OK, WARN, ERROR) and
one line, the way diagnostic_updater's tasks do:

- ERROR: the node reported a fault (`fault(text)`), or over the last window every input
  of a topic that got any was rejected;
- WARN: inputs were rejected over the last window, or a topic with an expected period
  (`expect(topic, max_age_s)`) is silent for longer than that;
- OK otherwise.

Times come from an injected monotonic clock (seconds), so it is unit-tested without ROS.
Thread-safe: multi-threaded executors count from several threads.
"""

import collections
import threading
import time

from . import diagnostic_keys as keys
from .param_spec import DOUBLE, ParamSpec

OK, WARN, ERROR = 0, 1, 2          # diagnostic_msgs/DiagnosticStatus levels
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', 3: 'STALE'}


# Every long-running node declares these (abp_common.health.NodeHealth).
HEALTH_SPECS = (
    ParamSpec('diagnostics_period', DOUBLE, 1.0,
              'Seconds (wall clock) between two /diagnostics messages of this node.',
              (0.1, 60.0)),
    ParamSpec('reject_log_period', DOUBLE, 5.0,
              'A rejected input of one kind on one topic is logged at most once per this '
              'many seconds (every one is counted in /diagnostics).', (0.0, 3600.0)),
    ParamSpec('max_stamp_future', DOUBLE, 30.0,
              "Inputs stamped more than this many seconds after the node's clock are "
              'rejected (stamp_future); 0 turns the check off.', (0.0, 1e6)),
    ParamSpec('max_stamp_lag', DOUBLE, 30.0,
              'Inputs stamped more than this many seconds before both the newest input of '
              "their topic and the node's clock are rejected (stamp_past); 0 turns the "
              'check off.', (0.0, 1e6)),
)
# Both stamp limits are in the node's clock: simulated seconds under use_sim_time, where
# a node's clock lags the simulation by its /clock backlog times the speed-up.


class _Window:
    """Event times within the last `span_s` seconds."""

    def __init__(self, span_s):
        self.span_s = span_s
        self.times = collections.deque()

    def add(self, t):
        self.times.append(t)

    def count(self, now):
        while self.times and self.times[0] < now - self.span_s:
            self.times.popleft()
        return len(self.times)


class HealthStats:
    def __init__(self, window_s=10.0, log_period_s=5.0, monotonic=time.monotonic):
        self.window_s = float(window_s)
        self.log_period_s = float(log_period_s)
        self._now = monotonic
        self._lock = threading.Lock()
        self._started = monotonic()
        self.inputs = collections.Counter()            # topic -> inputs so far
        self._input_windows = {}                        # topic -> _Window
        self._last_input = {}                           # topic -> time of the last input
        self._expected = {}                             # topic -> max age, s
        self.rejected = collections.Counter()          # (topic, kind) -> rejections so far
        self._reject_windows = {}                       # topic -> _Window
        self._last_log = {}                             # (topic, kind) -> time of last line
        self._latency = collections.deque(maxlen=200)   # recent processing times, s
        self.latency_count = 0
        self._fault = None

    # -- counting ------------------------------------------------------------------------
    def expect(self, topic, max_age_s):
        """`topic` should deliver at least every `max_age_s` s (WARN when it does not)."""
        with self._lock:
            self._expected[topic] = float(max_age_s)

    def count_input(self, topic):
        now = self._now()
        with self._lock:
            self.inputs[topic] += 1
            self._input_windows.setdefault(topic, _Window(self.window_s)).add(now)
            self._last_input[topic] = now

    def reject(self, topic, kind):
        """Count a rejected input; True when it should be logged now (the first of its
        (topic, kind) in `log_period_s`)."""
        now = self._now()
        key = (topic, kind)
        with self._lock:
            self.rejected[key] += 1
            self._reject_windows.setdefault(topic, _Window(self.window_s)).add(now)
            last = self._last_log.get(key)
            if last is not None and now - last < self.log_period_s:
                return False
            self._last_log[key] = now
            return True

    def latency(self, seconds):
        with self._lock:
            self._latency.append(float(seconds))
            self.latency_count += 1

    def fault(self, text):
        """A fault the node found itself (None clears it): level ERROR while it lasts."""
        with self._lock:
            self._fault = text

    # -- reading -------------------------------------------------------------------------
    def snapshot(self):
        """{'level', 'message', 'values': [(key, value text)]} of the current state."""
        now = self._now()
        with self._lock:
            topics = sorted(set(self.inputs) | set(self._expected)
                            | {t for t, _ in self.rejected})
            values, problems = [], []
            rejected_recent = 0
            all_rejected = []
            for topic in topics:
                recent = self._input_windows[topic].count(now) \
                    if topic in self._input_windows else 0
                span = min(self.window_s, max(now - self._started, 1e-3))
                values.append((keys.rate_key(topic), f'{recent / span:.2f}'))
                values.append((keys.inputs_key(topic), str(self.inputs[topic])))
                last = self._last_input.get(topic)
                age = None if last is None else now - last
                values.append((keys.age_key(topic),
                               keys.AGE_NEVER if age is None else f'{age:.2f}'))
                limit = self._expected.get(topic)
                if limit is not None and (age is None or age > limit) \
                        and now - self._started > limit:
                    problems.append(f'no {topic} for '
                                    f'{"ever" if age is None else f"{age:.1f} s"}')
                bad = self._reject_windows[topic].count(now) \
                    if topic in self._reject_windows else 0
                rejected_recent += bad
                if bad and bad >= recent:
                    all_rejected.append(topic)
            for (topic, kind), n in sorted(self.rejected.items()):
                values.append((keys.rejected_key(topic, kind), str(n)))
            values.append((keys.REJECTED_TOTAL, str(sum(self.rejected.values()))))
            if self._latency:
                ordered = sorted(self._latency)
                values.append((keys.LATENCY_MEAN,
                               f'{1e3 * sum(ordered) / len(ordered):.2f}'))
                values.append((keys.LATENCY_MAX, f'{1e3 * ordered[-1]:.2f}'))
                values.append((keys.LATENCY_P95,
                               f'{1e3 * ordered[int(0.95 * (len(ordered) - 1))]:.2f}'))
            fault = self._fault
        if fault:
            level, message = ERROR, fault
        elif all_rejected:
            level = ERROR
            message = f'every input rejected in the last {self.window_s:g} s on ' \
                      + ', '.join(all_rejected)
        elif rejected_recent or problems:
            level = WARN
            parts = list(problems)
            if rejected_recent:
                parts.insert(0, f'{rejected_recent} inputs rejected in the last '
                                f'{self.window_s:g} s')
            message = '; '.join(parts)
        else:
            level = OK
            total = sum(self.inputs.values())
            message = f'{total} inputs, none rejected recently'
        return {'level': level, 'message': message, 'values': values}


__all__ = ['ERROR', 'HEALTH_SPECS', 'LEVEL_NAMES', 'OK', 'WARN', 'HealthStats']
