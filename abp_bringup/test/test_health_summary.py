"""The `health` summary reads back what a node's HealthStats writes: both use the keys
of abp_common.diagnostic_keys, so a key renamed on one side fails here."""

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from abp_bringup.health import summarize
from abp_common import diagnostic_keys as keys
from abp_common.health import STATUS_SUFFIX
from abp_common.health_stats import HealthStats


def test_the_summary_reads_every_key_the_node_writes():
    now = [100.0]
    stats = HealthStats(window_s=10.0, monotonic=lambda: now[0])
    stats.expect('abp/belief', 5.0)   # expected, never received: age 'never'
    for _ in range(10):
        stats.count_input('camera/image_raw')
        now[0] += 0.1
    stats.reject('camera/image_raw', 'size')
    stats.latency(0.004)
    snap = stats.snapshot()
    values = [KeyValue(key=k, value=v) for k, v in snap['values']]
    values.append(KeyValue(key=keys.LIFECYCLE_STATE, value='inactive'))
    status = DiagnosticStatus(level=DiagnosticStatus.WARN, name='matcher' + STATUS_SUFFIX,
                              message=snap['message'], values=values)
    text = summarize({status.name: status}, width=200)
    assert 'lifecycle state: inactive' in text, text
    assert 'camera/image_raw 10.00 Hz (last 0.10 s ago)' in text, text
    assert 'abp/belief 0.00 Hz (last never)' in text, text
    assert 'latency:  mean 4.00 ms, p95 4.00 ms, max 4.00 ms' in text, text
    assert 'rejected: camera/image_raw: size 1' in text, text
    # Every per-kind rejection key parses back to its (topic, kind); the total does not.
    parsed = [keys.parse_rejected(k) for k, _ in snap['values']]
    assert [p for p in parsed if p] == [('camera/image_raw', 'size')]
    assert keys.parse_rejected(keys.REJECTED_TOTAL) is None
