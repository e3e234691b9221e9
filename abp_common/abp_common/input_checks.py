"""Checks of incoming messages, shared by every node (plain Python, no rclpy).

A check raises `Rejected(kind, detail)`: `kind` is a short, stable name (what
/diagnostics counts and the throttled log line names), `detail` says what was wrong
with this message. The kinds used across the graph:

| kind            | the message                                                      |
|-----------------|------------------------------------------------------------------|
| `non_finite`    | has a NaN or an infinite number where a number is used           |
| `empty`         | lacks the content it must have (no joint names, a zero pose)     |
| `oversized`     | has more elements than any real sender produces                  |
| `size_mismatch` | has arrays whose lengths disagree (names and positions)          |
| `out_of_range`  | has a number outside its meaningful range (an index, a type)     |
| `unknown_id`    | names something this node does not know (a tag, an action, a joint) |
| `frame`         | is in a frame this node cannot use                               |
| `stamp_future`  | is stamped later than the node's clock by more than a tolerance  |
| `stamp_past`    | is stamped before what this node already took from the topic     |
| `malformed`     | cannot be parsed at all (a JSON payload that is not one)         |

Messages are read by attribute only, so the checks run on real messages or on any
object with the same fields.
"""

import math

import numpy as np

KINDS = ('non_finite', 'empty', 'oversized', 'size_mismatch', 'out_of_range', 'unknown_id',
         'frame', 'stamp_future', 'stamp_past', 'malformed')


class Rejected(ValueError):
    """An input message a node refuses: `kind` (one of KINDS or a node's own) and why."""

    def __init__(self, kind, detail):
        super().__init__(f'{kind}: {detail}')
        self.kind = kind
        self.detail = detail


def stamp_ns(stamp):
    """A builtin_interfaces/Time as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def finite(what, values):
    """Raise `non_finite` unless every number of `values` is finite."""
    array = np.asarray(values, dtype=np.float64)
    if array.size and not np.all(np.isfinite(array)):
        raise Rejected('non_finite', f'{what} has a NaN or infinite value')


def at_most(what, count, limit):
    """Raise `oversized` when `count` elements exceed `limit`."""
    if count > limit:
        raise Rejected('oversized', f'{what} has {count} elements (at most {limit})')


def point(what, p):
    """A geometry_msgs Point/Vector3 must be finite."""
    finite(what, (p.x, p.y, p.z))


def pose(what, p):
    """A geometry_msgs Pose: a finite position and a finite, non-zero quaternion."""
    point(f'{what} position', p.position)
    o = p.orientation
    finite(f'{what} orientation', (o.x, o.y, o.z, o.w))
    if math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w) < 1e-6:
        raise Rejected('empty', f'{what} orientation is a zero quaternion')


class StampCheck:
    """Stamps of one topic against the node's clock.

    `stamp_future`: stamped more than `max_future_s` after the node's clock (a clock that
    has not started, 0, checks nothing). `stamp_past`: stamped more than `max_lag_s` before
    both the newest stamp taken from the topic and the node's clock, so a sender whose
    clock restarts (a restarted simulation) and a replay of recorded stamps into a node on
    wall time both pass, while a stale message in a live stream does not. 0 turns a check
    off. Call `taken(stamp)` for each message the node used. `trust_clock`: the node's
    clock is the senders' (the simulation itself), so `stamp_past` compares with it alone.
    One StampCheck may serve several topics of one stream of time (observations and
    actions): the newest stamp of either then guards both."""

    def __init__(self, max_future_s=1.0, max_lag_s=10.0, zero_is_now=False,
                 trust_clock=False):
        self.max_future_ns = int(max_future_s * 1e9)
        self.max_lag_ns = int(max_lag_s * 1e9)
        self.zero_is_now = zero_is_now   # a zero stamp means "now" (trajectories)
        self.trust_clock = trust_clock
        self.newest_ns = None

    def check(self, stamp, now_ns):
        t = stamp_ns(stamp)
        if t == 0 and self.zero_is_now:
            return t
        if self.max_future_ns and now_ns > 0 and t > now_ns + self.max_future_ns:
            raise Rejected('stamp_future', f'stamped {(t - now_ns) * 1e-9:.3g} s after the '
                                           "node's clock")
        if self.max_lag_ns and t < now_ns - self.max_lag_ns:
            if self.trust_clock:
                raise Rejected('stamp_past', f'stamped {(now_ns - t) * 1e-9:.3g} s before '
                                             "the node's clock")
            if self.newest_ns is not None and t < self.newest_ns - self.max_lag_ns:
                raise Rejected('stamp_past', f'stamped {(self.newest_ns - t) * 1e-9:.3g} s '
                                             'before the newest message taken from the topic')
        return t

    def taken(self, stamp):
        t = stamp_ns(stamp)
        if self.newest_ns is None or t > self.newest_ns:
            self.newest_ns = t

    def newest_not_after(self, now_ns):
        """The newest stamp taken, but never later than `now_ns` (a clock that has not
        started, 0, limits nothing): after a restarted simulation the newest stamp is
        from the old clock, and a reader's `stamp_future` check would refuse it."""
        if self.newest_ns is None or now_ns <= 0:
            return self.newest_ns
        return min(self.newest_ns, now_ns)


# -- the graph's messages -----------------------------------------------------------------

MAX_HYPOTHESES = 200        # an observation's hypotheses (the matcher keeps a few)
MAX_FEATURES = 100          # tags in one observation or detection array
MAX_JOINTS = 200
MAX_ASPECT_TYPE = 3         # ATG aspect types 0..3 (abp_belief.cube)


def joint_state(msg, max_joints=MAX_JOINTS):
    """A sensor_msgs/JointState: names and finite positions of equal lengths."""
    at_most('joint names', len(msg.name), max_joints)
    if not len(msg.name):
        raise Rejected('empty', 'joint_states without joint names')
    if len(msg.name) != len(msg.position):
        raise Rejected('size_mismatch', f'{len(msg.name)} joint names but '
                                        f'{len(msg.position)} positions')
    finite('joint positions', msg.position)


def odometry(msg):
    """A nav_msgs/Odometry with a finite pose."""
    pose('odometry pose', msg.pose.pose)
    finite('odometry twist', (msg.twist.twist.linear.x, msg.twist.twist.angular.z))


def aspect_observation(msg, frames=None):
    """An abp_msgs/AspectObservation: sizes, finite numbers, aspect types, feature indices,
    and (when `frames` is given) a frame among them."""
    at_most('hypotheses', len(msg.hypotheses), MAX_HYPOTHESES)
    at_most('features', len(msg.features), MAX_FEATURES)
    if frames is not None and msg.header.frame_id.lstrip('/') not in frames:
        raise Rejected('frame', f'frame {msg.header.frame_id!r} (expected '
                                f'{" or ".join(repr(f) for f in frames)})')
    for i, f in enumerate(msg.features):
        point(f'feature {i} position', f.position)
        point(f'feature {i} normal', f.normal)
        finite(f'feature {i} covariance', f.position_covariance)
    for i, h in enumerate(msg.hypotheses):
        if h.aspect_type > MAX_ASPECT_TYPE:
            raise Rejected('out_of_range', f'hypothesis {i} has aspect type {h.aspect_type} '
                                           f'(0..{MAX_ASPECT_TYPE})')
        finite(f'hypothesis {i} support and score', (h.support, h.score))
        pose(f'hypothesis {i} object pose', h.object_pose.pose)
        finite(f'hypothesis {i} covariance', h.object_pose.covariance)
        at_most(f'hypothesis {i} feature indices', len(h.feature_indices), MAX_FEATURES)
        bad = [j for j in h.feature_indices if j >= len(msg.features)]
        if bad:
            raise Rejected('out_of_range', f'hypothesis {i} refers to features {bad[:5]} of '
                                           f'{len(msg.features)}')


def belief(msg, num_nodes):
    """A belief (abp_msgs/Belief) over `num_nodes` aspect nodes that a planner can plan
    on: as many probabilities as indices (and object ids), indices in range, finite
    probabilities, at least one node."""
    n = len(msg.node_indices)
    at_most('node indices', n, num_nodes)
    at_most('object ids', len(msg.object_ids), num_nodes)
    if n != len(msg.node_probabilities):
        raise Rejected('size_mismatch', f'{n} node indices but {len(msg.node_probabilities)} '
                                        'node probabilities')
    if len(msg.object_ids) != len(msg.probabilities):
        raise Rejected('size_mismatch', f'{len(msg.object_ids)} object ids but '
                                        f'{len(msg.probabilities)} probabilities')
    if n == 0:
        raise Rejected('empty', 'belief without any aspect node')
    finite('node probabilities', msg.node_probabilities)
    finite('object probabilities', msg.probabilities)
    finite('entropy and node floor', (msg.entropy, msg.node_floor))
    if max(msg.node_indices) >= num_nodes:
        raise Rejected('out_of_range', f'node index {max(msg.node_indices)} of {num_nodes} '
                                       'nodes')


def skills_state(text, max_chars=4096):
    """The JSON of abp/skills/active: an object with a "node" string."""
    import json
    if len(text) > max_chars:
        raise Rejected('oversized', f'skills state of {len(text)} characters')
    try:
        state = json.loads(text)
    except ValueError as error:
        raise Rejected('malformed', f'skills state is not JSON ({error})') from None
    if not isinstance(state, dict) or not isinstance(state.get('node'), str):
        raise Rejected('malformed', 'skills state is not an object with a "node" string')
    return state


__all__ = ['KINDS', 'MAX_ASPECT_TYPE', 'MAX_FEATURES', 'MAX_HYPOTHESES', 'MAX_JOINTS',
           'Rejected', 'StampCheck', 'aspect_observation', 'at_most', 'finite',
           'joint_state', 'odometry', 'point', 'pose', 'skills_state', 'stamp_ns']
