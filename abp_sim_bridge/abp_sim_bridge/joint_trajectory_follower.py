"""Joint trajectory following with ros2_control's joint_trajectory_controller semantics
(plain NumPy, no rclpy).

One `TrajectoryFollower` per controller (a fixed tuple of joints):

- `set_trajectory(names, points, start, now, q, v)`: a new trajectory replaces the running
  one. Point times (`time_from_start`) count from `start` (the message's header.stamp; a
  zero stamp means "on receipt", i.e. `now`). The first segment runs from the joints'
  state at receipt to the first point. A message with **no points** stops the controller
  and holds the current position. Positions are clamped to the joint limits.
- Interpolation as the controller's default "splines": linear between points that give
  positions only, cubic Hermite when every point also gives velocities (accelerations
  are ignored). Before `start` the joints hold; after the last point they hold it.
- Joints of the controller missing from a message hold their position (the real
  controller refuses such goals unless allow_partial_joints_goal is set; holding is the
  lenient equivalent). A message naming a joint of another controller, or with
  inconsistent sizes or times, is refused as a whole (`TrajectoryError`).

Times are float seconds of the simulation clock.
"""

import bisect
from dataclasses import dataclass

import numpy as np


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
    def end_time(self):
        return None if self._times is None else float(self._times[-1])

    def hold(self, q):
        """Stop and hold `q` (the controller's joints)."""
        self._times = self._pos = self._vel = None
        self._hold = np.clip(np.asarray(q, dtype=float), self.lower, self.upper)

    def set_trajectory(self, names, points, start, now, q, v=None):
        """Replace the running trajectory. `q`, `v`: current positions/velocities of the
        controller's joints (controller order). Returns the number of points accepted."""
        names = list(names)
        q = np.asarray(q, dtype=float)
        v = np.zeros_like(q) if v is None else np.asarray(v, dtype=float)
        unknown = [n for n in names if n not in self.joint_names]
        if unknown:
            raise TrajectoryError(f'joints {unknown} are not controlled here '
                                  f'(this controller has {list(self.joint_names)})')
        if len(set(names)) != len(names):
            raise TrajectoryError('duplicate joint names')
        if not points:
            self.hold(q)
            return 0
        if not names:
            raise TrajectoryError('points given but no joint names')
        cols = [self.joint_names.index(n) for n in names]
        with_vel = all(p.velocities is not None and len(p.velocities) for p in points)
        times, pos, vel = [], [], []
        last = -np.inf
        for i, p in enumerate(points):
            t = float(p.time_from_start)
            if not np.isfinite(t) or t < 0:
                raise TrajectoryError(f'point {i}: time_from_start must be >= 0')
            if t <= last:
                raise TrajectoryError(f'point {i}: time_from_start must increase strictly')
            last = t
            if len(p.positions) != len(names):
                raise TrajectoryError(f'point {i}: {len(p.positions)} positions for '
                                      f'{len(names)} joints')
            if with_vel and len(p.velocities) != len(names):
                raise TrajectoryError(f'point {i}: {len(p.velocities)} velocities for '
                                      f'{len(names)} joints')
            row = q.copy()
            row[cols] = np.asarray(p.positions, dtype=float)
            if not np.all(np.isfinite(row)):
                raise TrajectoryError(f'point {i}: positions must be finite')
            times.append(t)
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
