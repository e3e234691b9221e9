"""The QoS profiles of the abp graph, defined once.

- `LATCHED`: state topics (belief, ground truth, skills/active) whose last value a late
  subscriber must still get: reliable, transient local, depth 1.
- `LATCHED_READER`: the subscriber side of a latched topic that must not lose a burst.
- `reliable(depth)`: event topics (observations, executed actions, plans), where a lost
  message is lost evidence; depth sized by the subscriber's worst backlog.
- `SENSOR_DATA`: camera images (best effort, keep last): a stale frame is worth nothing.
"""

from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
    qos_profile_sensor_data,
)

DEFAULT_DEPTH = 10


def reliable(depth=DEFAULT_DEPTH):
    """Reliable, volatile, keep-last `depth`."""
    return QoSProfile(depth=depth, history=QoSHistoryPolicy.KEEP_LAST,
                      reliability=QoSReliabilityPolicy.RELIABLE)


def latched(depth=1):
    """Reliable, transient local, keep-last `depth`."""
    return QoSProfile(depth=depth, history=QoSHistoryPolicy.KEEP_LAST,
                      reliability=QoSReliabilityPolicy.RELIABLE,
                      durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)


RELIABLE = reliable()
LATCHED = latched()
LATCHED_READER = latched(DEFAULT_DEPTH)
SENSOR_DATA = qos_profile_sensor_data

__all__ = ['DEFAULT_DEPTH', 'LATCHED', 'LATCHED_READER', 'RELIABLE', 'SENSOR_DATA', 'latched',
           'reliable']
