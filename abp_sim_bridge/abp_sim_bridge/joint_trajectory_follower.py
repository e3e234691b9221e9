"""Joint trajectory following with ros2_control's joint_trajectory_controller semantics
(plain NumPy, no rclpy).

One `TrajectoryFollower` per controller (a fixed tuple of joints):

- `set_trajectory(names, points, start, now, q, v)`: a new trajectory replaces the running
  one. Point times (`time_from_start`) count from `start` (the message's header.stamp; a
  zero stamp means "on receipt", i.e. `now`). The first segment runs from the joints'
  state at receipt to the first point. Positions are clamped to the joint limits.
- Refused as Jazzy's joint_trajectory_controller refuses them (its messages, word for
  word where it has one; `TrajectoryError`): a message with **no points** ("Empty
  trajectory received." -- a stop is a one-point hold, `hold_message`), one that does not
  name every joint of the controller (allow_partial_joints_goal is false by default), a
  joint of another controller, a last point with a non-zero velocity
  (allow_nonzero_velocity_at_trajectory_end is false by default), times that do not
  increase strictly, sizes that disagree.
- Interpolation as the controller's default "splines": linear between points that give
  positions only, cubic Hermite when every point also gives velocities (accelerations
  are ignored). Before `start` the joints hold; after the last point they hold it.
- `hold(q)`: the controller's own hold (after a cancel, an abort or a tolerance
  violation): stop where the joints are.

Times are float seconds of the simulation clock.
"""

import bisect
from dataclasses import dataclass

import numpy as np

# Single-precision epsilon: how close to zero the controller wants the last velocity.
FLOAT_EPS = float(np.finfo(np.float32).eps)


class TrajectoryError(ValueError):
    """A trajectory message the controller refuses."""


@dataclass
class TrajectoryPoint:
    time_from_start: float
    positions: np.ndarray
    velocities: np.ndarray | None = None


class TrajectoryFollower:
    def __init__(self, joint_names, lower, upper):
        self.joint_names = tuple(joint_names)
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        if self.lower.shape != (len(self.joint_names),) or self.upper.shape != self.lower.shape:
            raise ValueError('one lower and one upper limit per joint')
        self._times = None      # (K,) absolute knot times, the first is the start anchor
        self._pos = None        # (K, n) knot positions (all controller joints)
        self._vel = None        # (K, n) knot velocities, None for linear interpolation
        self._hold = None       # (n,) position to hold when no trajectory runs

    @property
    def active(self):
        return self._times is not None

    @property
    def holding(self):
        return self._times is None

    @property
    def end_time(self):
        return None if self._times is None else float(self._times[-1])

    def hold(self, q):
        """Stop and hold `q` (the controller's joints)."""
        self._times = self._pos = self._vel = None
        self._hold = np.clip(np.asarray(q, dtype=float), self.lower, self.upper)

    def check(self, names, points):
        """Raise TrajectoryError when the controller refuses a trajectory of `names` and
        `points` (what Jazzy's joint_trajectory_controller validates before it accepts a
        message or an action goal); nothing changes."""
        names = list(names)
        if not names:
            raise TrajectoryError('Empty joint names on incoming trajectory.')
        unknown = [n for n in names if n not in self.joint_names]
        if unknown:
            raise TrajectoryError(f"Incoming joint {unknown[0]} doesn't match the "
                                  f'controller\'s joints ({", ".join(self.joint_names)}).')
        if len(set(names)) != len(names):
            raise TrajectoryError('duplicate joint names')
        if len(names) != len(self.joint_names):
            raise TrajectoryError("Joints on incoming trajectory don't match the controller "
                                  f'joints: {len(names)} of {len(self.joint_names)} named '
                                  '(partial goals are not allowed)')
        if not points:
            raise TrajectoryError('Empty trajectory received. (A stop is a one-point hold '
                                  'at the current position.)')
        last_v = points[-1].velocities
        if last_v is not None and len(last_v) and np.any(np.abs(last_v) > FLOAT_EPS):
            raise TrajectoryError('Velocity of the last trajectory point is not zero')
        with_vel = all(p.velocities is not None and len(p.velocities) for p in points)
        last = -np.inf
        for i, p in enumerate(points):
            t = float(p.time_from_start)
            if not np.isfinite(t) or t < 0:
                raise TrajectoryError(f'point {i}: time_from_start must be >= 0')
            if t <= last:
                raise TrajectoryError(f'Time between points {i - 1} and {i} is not strictly '
                                      'increasing')
            last = t
            if len(p.positions) != len(names):
                raise TrajectoryError(f'point {i}: {len(p.positions)} positions for '
                                      f'{len(names)} joints')
            if with_vel and len(p.velocities) != len(names):
                raise TrajectoryError(f'point {i}: {len(p.velocities)} velocities for '
                                      f'{len(names)} joints')
            if not np.all(np.isfinite(np.asarray(p.positions, dtype=float))):
                raise TrajectoryError(f'point {i}: positions must be finite')
        return with_vel

    def set_trajectory(self, names, points, start, now, q, v=None):
        """Replace the running trajectory (refused as `check` says). `q`, `v`: current
        positions/velocities of the controller's joints (controller order). Returns the
        number of points accepted."""
        with_vel = self.check(names, points)
        names = list(names)
        q = np.asarray(q, dtype=float)
        v = np.zeros_like(q) if v is None else np.asarray(v, dtype=float)
        cols = [self.joint_names.index(n) for n in names]
        times, pos, vel = [], [], []
        for p in points:
            times.append(float(p.time_from_start))
            row = q.copy()
            row[cols] = np.asarray(p.positions, dtype=float)
            pos.append(np.clip(row, self.lower, self.upper))
            if with_vel:
                vrow = np.zeros_like(q)
                vrow[cols] = np.asarray(p.velocities, dtype=float)
                vel.append(vrow)
        start = float(now) if start is None or start <= 0 else float(start)
        t_abs = start + np.asarray(times)
        # Anchor: the state at receipt, at the start time (or at receipt, whichever is later
        # and still before the first point, so that a stamp in the past does not jump).
        anchor_t = min(max(start, float(now)), t_abs[0])
        if t_abs[0] - anchor_t > 1e-9:
            t_abs = np.concatenate([[anchor_t], t_abs])
            pos.insert(0, np.clip(q, self.lower, self.upper))
            if with_vel:
                vel.insert(0, v.copy())
        self._times = t_abs
        self._times_list = t_abs.tolist()
        self._pos = np.array(pos)
        self._vel = np.array(vel) if with_vel else None
        self._hold = None
        return len(points)

    def sample(self, t, q_current):
        """Desired positions of the controller's joints at time `t`."""
        if self._times is None:
            if self._hold is None:
                self._hold = np.clip(np.asarray(q_current, dtype=float), self.lower, self.upper)
            return self._hold
        times = self._times_list
        if t <= times[0]:
            return self._pos[0]
        if t >= times[-1]:
            # Done: keep holding the last point.
            self.hold(self._pos[-1])
            return self._hold
        k = bisect.bisect_right(times, t) - 1
        t0, t1 = times[k], times[k + 1]
        h = t1 - t0
        s = (t - t0) / h
        p0, p1 = self._pos[k], self._pos[k + 1]
        if self._vel is None:
            out = p0 + s * (p1 - p0)
        else:
            m0, m1 = self._vel[k] * h, self._vel[k + 1] * h
            s2, s3 = s * s, s * s * s
            out = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0
                   + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1)
        return np.minimum(np.maximum(out, self.lower), self.upper)

