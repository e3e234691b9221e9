"""Time-optimal jerk-limited joint and path profiles with Ruckig (plain NumPy + Ruckig, no
rclpy).

- Joint space: `joint_trajectory` goes through joint waypoints with one phase-synchronised
  multi-DOF Ruckig profile per segment (a straight line in joint space), rest to rest at
  each waypoint (the open-source Ruckig computes intermediate waypoints only through its
  cloud API, so segments are planned one by one), sampled every `dt` into a
  `SampledTrajectory`.
- Paths: `path_profile` is a 1-D Ruckig profile of the arc length along a Cartesian path
  (the skills map it to joints with IK, see `plans`; the base's pieces, see `base_motion`).

Angles in rad, lengths in m, times in s.
"""

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory


@dataclass(frozen=True)
class Limits:
    """Per-DOF kinematic limits (arrays of the trajectory's DOF count, or scalars)."""

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def for_dofs(self, n):
        def vec(v):
            v = np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()
            if np.any(~np.isfinite(v)) or np.any(v <= 0):
                raise ValueError('velocity, acceleration and jerk limits must be finite and > 0')
            return v
        return Limits(vec(self.velocity), vec(self.acceleration), vec(self.jerk))


class TrajectoryError(RuntimeError):
    pass


@dataclass
class SampledTrajectory:
    """Joint positions/velocities/accelerations at increasing times from 0."""

    joint_names: tuple
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray

    @property
    def duration(self):
        return float(self.times[-1]) if len(self.times) else 0.0

    @property
    def start(self):
        return self.positions[0]

    @property
    def end(self):
        return self.positions[-1]

    def at(self, t):
        """Positions at time t (linear between samples, clamped to the ends)."""
        t = float(np.clip(t, 0.0, self.duration))
        i = int(np.searchsorted(self.times, t, side='right')) - 1
        i = min(max(i, 0), len(self.times) - 1)
        if i == len(self.times) - 1:
            return self.positions[-1].copy()
        t0, t1 = self.times[i], self.times[i + 1]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return (1 - w) * self.positions[i] + w * self.positions[i + 1]

    def select(self, names):
        """The same trajectory restricted to some joints (in the order given)."""
        idx = [self.joint_names.index(n) for n in names]
        return SampledTrajectory(tuple(names), self.times, self.positions[:, idx],
                                 self.velocities[:, idx], self.accelerations[:, idx])

    @staticmethod
    def hold(joint_names, q, duration=0.0):
        q = np.asarray(q, dtype=float)[None, :]
        times = np.array([0.0]) if duration <= 0 else np.array([0.0, duration])
        pos = np.repeat(q, len(times), axis=0)
        return SampledTrajectory(tuple(joint_names), times, pos, np.zeros_like(pos),
                                 np.zeros_like(pos))

    @staticmethod
    def concat(parts):
        parts = [p for p in parts if p is not None and len(p.times)]
        if not parts:
            raise ValueError('nothing to concatenate')
        names = parts[0].joint_names
        times, pos, vel, acc = [parts[0].times], [parts[0].positions], [parts[0].velocities], \
            [parts[0].accelerations]
        offset = parts[0].duration
        for p in parts[1:]:
            if p.joint_names != names:
                raise ValueError('joint names differ')
            times.append(p.times[1:] + offset)
            pos.append(p.positions[1:])
            vel.append(p.velocities[1:])
            acc.append(p.accelerations[1:])
            offset += p.duration
        return SampledTrajectory(names, np.concatenate(times), np.vstack(pos), np.vstack(vel),
                                 np.vstack(acc))


def ruckig_profile(start, target, limits, start_velocity=None, target_velocity=None):
    """Time-optimal, time-synchronised jerk-limited profile from `start` to `target`
    (arrays of n DOF); returns a ruckig.Trajectory."""
    start = np.atleast_1d(np.asarray(start, dtype=float))
    target = np.atleast_1d(np.asarray(target, dtype=float))
    n = start.size
    lim = limits.for_dofs(n)
    otg = Ruckig(n)
    inp = InputParameter(n)
    inp.current_position = start.tolist()
    inp.current_velocity = (np.zeros(n) if start_velocity is None
                            else np.asarray(start_velocity, dtype=float)).tolist()
    inp.current_acceleration = [0.0] * n
    inp.target_position = target.tolist()
    inp.target_velocity = (np.zeros(n) if target_velocity is None
                           else np.asarray(target_velocity, dtype=float)).tolist()
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = lim.velocity.tolist()
    inp.max_acceleration = lim.acceleration.tolist()
    inp.max_jerk = lim.jerk.tolist()
    # Phase synchronisation: every DOF follows the same normalised profile, so the motion
    # is a straight line in joint space (Ruckig falls back to time synchronisation when a
    # non-zero boundary velocity makes that impossible).
    inp.synchronization = Synchronization.Phase
    traj = Trajectory(n)
    result = otg.calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise TrajectoryError(f'Ruckig could not plan the segment: {result}')
    return traj


def sample_profile(traj, dt):
    """(times, positions, velocities, accelerations) of a Ruckig trajectory every dt,
    the end included."""
    duration = float(traj.duration)
    n_steps = max(1, int(np.ceil(duration / dt - 1e-9)))
    times = np.linspace(0.0, duration, n_steps + 1)
    pos, vel, acc = [], [], []
    for t in times:
        p, v, a = traj.at_time(float(t))
        pos.append(p)
        vel.append(v)
        acc.append(a)
    return times, np.array(pos, dtype=float), np.array(vel, dtype=float), \
        np.array(acc, dtype=float)


def joint_trajectory(joint_names, q_start, waypoints, limits, dt=0.05):
    """Rest-to-rest jerk-limited motion from `q_start` through every waypoint (each an
    array over `joint_names`), sampled every `dt`."""
    names = tuple(joint_names)
    current = np.asarray(q_start, dtype=float)
    parts = []
    for wp in waypoints:
        wp = np.asarray(wp, dtype=float)
        if wp.shape != current.shape:
            raise ValueError(f'waypoint has shape {wp.shape}, expected {current.shape}')
        if np.max(np.abs(wp - current)) < 1e-9:
            continue
        times, pos, vel, acc = sample_profile(ruckig_profile(current, wp, limits), dt)
        pos[-1] = wp
        parts.append(SampledTrajectory(names, times, pos, vel, acc))
        current = wp
    if not parts:
        return SampledTrajectory.hold(names, current)
    return SampledTrajectory.concat(parts)


def path_profile(length, velocity, acceleration, jerk):
    """1-D rest-to-rest Ruckig profile of the distance travelled along a path."""
    return ruckig_profile([0.0], [float(length)], Limits(velocity, acceleration, jerk))
