"""The QoS profiles of the abp graph, defined once.

- `LATCHED`: state topics (belief, ground truth, skills/active) whose last value a late
  subscriber must still get: reliable, transient local, depth 1.
- `LATCHED_READER`: the subscriber side of a latched topic that must not lose a burst.
- `reliable(depth)`: event topics (observations, executed actions, plans), where a lost
  message is lost evidence; depth sized by the subscriber's worst backlog.
- `SENSOR_DATA`: camera images (best effort, keep last): a stale frame is worth nothing.
- `CAMERA_PUBLISHER`: what a camera publishes images and camera info with: reliable, keep
  last `SENSOR_DATA`'s depth. Each subscriber then chooses: `SENSOR_DATA` (the detector)
  takes what arrives and is never waited for; a reliable subscriber (a test that must see
  frames) gets lost fragments sent again. A 640x480 bgr8 frame (921 KB) is larger than
  Fast DDS's default shared-memory segment (512 KB): a best-effort reader got 1 to 4 of 56
  such frames where a reliable reader in the same process got all 56 (mono8, 307 KB: all
  of them either way). Many camera drivers publish reliable for the same reason.
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
CAMERA_PUBLISHER = reliable(SENSOR_DATA.depth)

__all__ = ['CAMERA_PUBLISHER', 'DEFAULT_DEPTH', 'LATCHED', 'LATCHED_READER', 'RELIABLE',
           'SENSOR_DATA', 'latched', 'reliable']
