"""`/diagnostics` of an abp node, and its guarded input subscriptions (ROS wiring).

Every long-running node makes one `NodeHealth(node)`. It declares the parameters of
`health_stats.HEALTH_SPECS`, and publishes on /diagnostics (diagnostic_msgs/
DiagnosticArray, absolute like every ROS driver's, one DiagnosticStatus named
`<node>: health`) every `diagnostics_period` wall seconds: per input topic its rate,
input count and the age of its last input; per (topic, kind) the inputs rejected; the
processing latency; and a level (OK / WARN / ERROR) with a one-line message
(`health_stats.HealthStats.snapshot`); a managed node adds its `lifecycle state`.
diagnostic_updater is the ROS package for this, but it is not installable from PyPI;
this is the small part of it the graph needs.

`subscribe(msg_type, topic, callback, qos)` is create_subscription with the health
accounting around the callback: each message is counted, a callback that raises
`input_checks.Rejected` has the message counted as rejected and logged (each kind on
each topic at most once per `reject_log_period`, with the count so far), and any other
exception is counted as `internal_error` and logged with its traceback under the same
throttle: a bad message never ends the node.
"""

import time
import traceback

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType

from .diagnostic_keys import LIFECYCLE_STATE
from .health_stats import ERROR, HEALTH_SPECS, OK, WARN, HealthStats
from .input_checks import Rejected, StampCheck
from .parameters import declare_all

DIAGNOSTICS = '/diagnostics'
STATUS_SUFFIX = ': health'   # a node's status is named `<node full name><suffix>`
HARDWARE_ID = 'abp'
_LEVELS = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN,
           ERROR: DiagnosticStatus.ERROR}


class NodeHealth:
    def __init__(self, node):
        self.node = node
        self.values = declare_all(node, HEALTH_SPECS)
        self.stats = HealthStats(log_period_s=self.values['reject_log_period'])
        self.name = node.get_fully_qualified_name().lstrip('/') + STATUS_SUFFIX
        self._value_sources = []
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        # Wall time: under use_sim_time a paused simulation must not silence diagnostics.
        self._timer = node.create_timer(self.values['diagnostics_period'], self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    # -- inputs --------------------------------------------------------------------------
    def subscribe(self, msg_type, topic, callback, qos, node=None, **kwargs):
        """create_subscription whose callback is counted and guarded (module doc). `node`:
        another node of this process to subscribe on (its own executor), to `topic` as
        this node resolves it (its namespace and remappings); counted here all the same."""
        def guarded(msg):
            self.stats.count_input(topic)
            try:
                callback(msg)
            except Rejected as rejected:
                self.reject(topic, rejected.kind, rejected.detail)
            except Exception as error:  # noqa: BLE001 -- a message must not end the node
                if not self.node.context.ok():
                    raise
                self.reject(topic, 'internal_error',
                            f'{type(error).__name__}: {error}\n{traceback.format_exc()}',
                            error=True)
        if node is None:
            return self.node.create_subscription(msg_type, topic, guarded, qos, **kwargs)
        return node.create_subscription(msg_type, self.node.resolve_topic_name(topic), guarded,
                                        qos, **kwargs)

    def count_input(self, topic):
        self.stats.count_input(topic)

    def expect(self, topic, max_age_s):
        """WARN when `topic` has been silent for more than `max_age_s` wall seconds."""
        self.stats.expect(topic, max_age_s)

    def reject(self, topic, kind, detail, error=False):
        """Count a rejected input; log it unless its kind was logged on this topic less
        than `reject_log_period` s ago."""
        if not self.stats.reject(topic, kind):
            return
        n = self.stats.rejected[(topic, kind)]
        line = (f'rejected input on {self.node.resolve_topic_name(topic)} ({kind}): {detail} '
                f'[{n} {kind} on this topic so far; logged at most every '
                f'{self.stats.log_period_s:g} s]')
        # Two call sites: rclpy refuses one call site logging at two severities.
        if error:
            self.node.get_logger().error(line)
        else:
            self.node.get_logger().warning(line)

    def stamp_check(self, zero_is_now=False, trust_clock=False):
        """A StampCheck with this node's limits (one per stream of stamps)."""
        return StampCheck(self.values['max_stamp_future'], self.values['max_stamp_lag'],
                          zero_is_now=zero_is_now, trust_clock=trust_clock)

    def now_ns(self):
        return self.node.get_clock().now().nanoseconds

    # -- processing ----------------------------------------------------------------------
    def latency(self, seconds):
        self.stats.latency(seconds)

    def timed(self):
        """`with health.timed(): ...` records the block's wall time as a latency."""
        return _Timed(self.stats)

    def fault(self, text):
        """A fault of the node itself (None clears it): ERROR in /diagnostics."""
        self.stats.fault(text)

    # -- output --------------------------------------------------------------------------
    def add_values(self, source):
        """Report the node's own state too: `source()` returns [(key, value text)], read
        at each publication."""
        self._value_sources.append(source)

    def status(self):
        snap = self.stats.snapshot()
        values = [KeyValue(key=k, value=v) for k, v in snap['values']]
        values += [KeyValue(key=k, value=str(v)) for source in self._value_sources
                   for k, v in source()]
        state = getattr(self.node, 'state_label', None)
        if state is not None:   # a managed node (abp_common.lifecycle)
            values.append(KeyValue(key=LIFECYCLE_STATE, value=state()))
        return DiagnosticStatus(
            level=_LEVELS[snap['level']], name=self.name, message=snap['message'],
            hardware_id=HARDWARE_ID, values=values)

    def publish(self):
        msg = DiagnosticArray(status=[self.status()])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pub.publish(msg)


def node_of_status(name):
    """The node (full name without the leading slash) whose health status is named `name`,
    or None for a status that is not an abp node's health."""
    return name[:-len(STATUS_SUFFIX)] if name.endswith(STATUS_SUFFIX) else None


class _Timed:
    def __init__(self, stats):
        self.stats = stats

    def __enter__(self):
        self.start = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.stats.latency(time.perf_counter() - self.start)
        return False


__all__ = ['DIAGNOSTICS', 'STATUS_SUFFIX', 'NodeHealth', 'node_of_status']
