"""QoS in rosbag2 bags: what was offered on a topic, what to record it with, what to replay
it with. Plain module (no rclpy); profiles are `rosbags` `Qos` tuples, the form the
`rosbags` writer stores as `offered_qos_profiles`.

The rules are rosbag2 Jazzy's (rosbag2_storage/src/rosbag2_storage/qos.cpp):
- recording (`Rosbag2QoS::adapt_request_to_offers`): subscribe reliable if every publisher
  offers reliable, transient local if every publisher offers transient local, otherwise the
  weaker policy so that every publisher matches; deadline and liveliness left unset;
- replay (`Rosbag2QoS::adapt_offer_to_recorded_offers`): if all recorded offers agree on the
  policies that decide compatibility (reliability, durability, deadline, liveliness and its
  lease), offer that profile with keep-last history; otherwise there is no single profile.

A latched topic (transient local) is thus recorded with its last message even when it was
published before the recorder started, and replayed latched.
"""

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

# RMW_DURATION_INFINITE (rmw/time.h) in nanoseconds: what DDS reports for an unset
# deadline, lifespan or liveliness lease.
INFINITE_NS = 2**63 - 1
# "Infinite" as RMW implementations reported it before Galactic; bags recorded then carry
# these (rosbag2 maps them to RMW_DURATION_INFINITE when it reads them).
_FOXY_INFINITE = {(0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)}


def qos_time(nanoseconds):
    """A `QosTime` (sec, nsec) from nanoseconds, as rmw_time_from_nsec splits them."""
    nanoseconds = min(int(nanoseconds), INFINITE_NS)
    return QosTime(nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000)


def nanoseconds(time):
    """Nanoseconds of a `QosTime`; the pre-Galactic infinities become INFINITE_NS."""
    if (time.sec, time.nsec) in _FOXY_INFINITE:
        return INFINITE_NS
    return min(time.sec * 1_000_000_000 + time.nsec, INFINITE_NS)


def profile(history, depth, reliability, durability, deadline_ns, lifespan_ns, liveliness,
            lease_ns, avoid_ros_namespace_conventions=False):
    """A `Qos` from policy names as rmw and rclpy spell them ('RELIABLE',
    'TRANSIENT_LOCAL', ...; any case) and durations in nanoseconds."""
    return Qos(QosHistory[history.upper()], int(depth), QosReliability[reliability.upper()],
               QosDurability[durability.upper()], qos_time(deadline_ns),
               qos_time(lifespan_ns), QosLiveliness[liveliness.upper()], qos_time(lease_ns),
               bool(avoid_ros_namespace_conventions))


def recording_request(topic, offers):
    """(reliable, transient_local, warnings): the subscription that matches every offer
    in `offers` (the topic's publishers' profiles), and why it is weaker than some."""
    reliable = sum(o.reliability == QosReliability.RELIABLE for o in offers)
    latched = sum(o.durability == QosDurability.TRANSIENT_LOCAL for o in offers)
    warnings = []
    if 0 < reliable < len(offers):
        warnings.append(f'some, not all, publishers on {topic} are reliable: recording best '
                        'effort to match them all (messages of the reliable ones may be lost)')
    if 0 < latched < len(offers):
        warnings.append(f'some, not all, publishers on {topic} are transient local: '
                        'recording volatile to match them all (their latched messages '
                        'published before the recorder started are not recorded)')
    return (bool(offers) and reliable == len(offers), bool(offers) and latched == len(offers),
            warnings)


def _compatibility(profile):
    return (profile.reliability, profile.durability, nanoseconds(profile.deadline),
            profile.liveliness, nanoseconds(profile.liveliness_lease_duration))


def playback_offer(profiles):
    """The profile to replay a topic with from its recorded `profiles`: the first one if
    they all agree where compatibility is decided, else None (no single profile; rosbag2
    then falls back to its default, reliable and volatile)."""
    if not profiles or len({_compatibility(p) for p in profiles}) > 1:
        return None
    return profiles[0]


def describe(profile):
    """'reliable, transient_local' (the spellings of metadata.yaml)."""
    return f'{profile.reliability.name.lower()}, {profile.durability.name.lower()}'
