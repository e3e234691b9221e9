"""The keys of an abp node's health status on /diagnostics (diagnostic_msgs/KeyValue),
in one place: `health_stats` and `health` write them, `abp_bringup.health` and the
planner's belief-node report (`abp_planner.episode`) read them back. Plain Python.

Per input topic: `<topic> rate (Hz)`, `<topic> inputs`, `<topic> age of last input (s)`;
per rejected (topic, kind): `rejected <topic> <kind>`; then `rejected total`, the
latency keys and, on a managed node, `lifecycle state`.
"""

RATE_SUFFIX = ' rate (Hz)'
INPUTS_SUFFIX = ' inputs'
AGE_SUFFIX = ' age of last input (s)'
AGE_NEVER = 'never'   # the age value of a topic that never had an input
REJECTED_PREFIX = 'rejected '
REJECTED_TOTAL = 'rejected total'
LATENCY_MEAN = 'latency mean (ms)'
LATENCY_MAX = 'latency max (ms)'
LATENCY_P95 = 'latency p95 (ms)'
LIFECYCLE_STATE = 'lifecycle state'


def rate_key(topic):
    return topic + RATE_SUFFIX


def inputs_key(topic):
    return topic + INPUTS_SUFFIX


def age_key(topic):
    return topic + AGE_SUFFIX


def rejected_key(topic, kind):
    return f'{REJECTED_PREFIX}{topic} {kind}'


def rate_topic(key):
    """The topic of a rate key, or None for another key."""
    return key[:-len(RATE_SUFFIX)] if key.endswith(RATE_SUFFIX) else None


def parse_rejected(key):
    """(topic, kind) of a per-kind rejection key, or None for another key (also for
    `rejected total`)."""
    if not key.startswith(REJECTED_PREFIX) or key == REJECTED_TOTAL:
        return None
    topic, _, kind = key[len(REJECTED_PREFIX):].rpartition(' ')
    return topic, kind


__all__ = ['AGE_NEVER', 'AGE_SUFFIX', 'INPUTS_SUFFIX', 'LATENCY_MAX', 'LATENCY_MEAN',
           'LATENCY_P95', 'LIFECYCLE_STATE', 'RATE_SUFFIX', 'REJECTED_PREFIX',
           'REJECTED_TOTAL', 'age_key', 'inputs_key', 'parse_rejected', 'rate_key',
           'rate_topic', 'rejected_key']
