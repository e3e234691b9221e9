"""Time-optimal jerk-limited motion with Ruckig (plain NumPy + Ruckig, no rclpy).

- Joint space: `joint_trajectory` goes through joint waypoints with one phase-synchronised
  multi-DOF Ruckig profile per segment (a straight line in joint space), rest to rest at
  each waypoint (the open-source Ruckig computes intermediate waypoints only through its
  cloud API, so segments are planned one by one), sampled every `dt` into a
  `SampledTrajectory`.
- Paths: `path_profile` is a 1-D Ruckig profile of the arc length along a Cartesian path
  (the skills map it to joints with IK, see `plans`).
- Base: `plan_orbit` builds ORBIT(θ) for a differential drive: turn in place to the
  tangent, drive a constant-radius arc around the cube (v = r·ω), turn back to face the
  cube, each piece a Ruckig profile of its angle or length. `OrbitTracker` closes the
  loop on odometry with a unicycle tracking law and a final settling phase.

Angles in rad, lengths in m, times in s.
"""

from dataclasses import dataclass, field

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory


def wrap(angle):
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


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


# -- ORBIT: the base ------------------------------------------------------------------------

@dataclass(frozen=True)
class BaseLimits:
    linear_velocity: float = 0.15       # m/s
    linear_acceleration: float = 0.3    # m/s^2
    linear_jerk: float = 1.0            # m/s^3
    angular_velocity: float = 0.6       # rad/s
    angular_acceleration: float = 1.0   # rad/s^2
    angular_jerk: float = 4.0           # rad/s^3

    def linear(self):
        return Limits(self.linear_velocity, self.linear_acceleration, self.linear_jerk)

    def angular(self):
        return Limits(self.angular_velocity, self.angular_acceleration, self.angular_jerk)


@dataclass
class BaseSegment:
    """A rest-to-rest piece of base motion: 'turn' (in place, amount in rad), 'line'
    (straight, m, signed) or 'arc' (m along the arc, with signed `curvature` = ω / v)."""

    kind: str
    amount: float
    phase: str
    start_pose: np.ndarray
    curvature: float = 0.0
    profile: object = None   # 1-D ruckig.Trajectory of |amount|
    duration: float = 0.0

    def state(self, t):
        """(pose, v, ω) at time t in the segment (clamped)."""
        t = float(np.clip(t, 0.0, self.duration))
        if self.profile is None:
            s, ds = abs(self.amount), 0.0
        else:
            p, v, _ = self.profile.at_time(t)
            s, ds = float(p[0]), float(v[0])
        sign = 1.0 if self.amount >= 0 else -1.0
        x0, y0, yaw0 = self.start_pose
        if self.kind == 'turn':
            return np.array([x0, y0, wrap(yaw0 + sign * s)]), 0.0, sign * ds
        if self.kind == 'line':
            d = sign * s
            return np.array([x0 + d * np.cos(yaw0), y0 + d * np.sin(yaw0), yaw0]), sign * ds, 0.0
        k = self.curvature
        yaw = yaw0 + k * s
        if abs(k) < 1e-12:
            x, y = x0 + s * np.cos(yaw0), y0 + s * np.sin(yaw0)
        else:
            x = x0 + (np.sin(yaw) - np.sin(yaw0)) / k
            y = y0 - (np.cos(yaw) - np.cos(yaw0)) / k
        return np.array([x, y, wrap(yaw)]), ds, k * ds

    def end_pose(self):
        return self.state(self.duration)[0]


@dataclass
class OrbitPlan:
    """Base motion of ORBIT(angle) around the cube at `cube_xy` (odom frame)."""

    angle: float
    radius: float
    cube_xy: np.ndarray
    start_pose: np.ndarray
    segments: list = field(default_factory=list)

    @property
    def duration(self):
        return float(sum(s.duration for s in self.segments))

    def _segment_at(self, t):
        for seg in self.segments:
            if t <= seg.duration:
                return seg, t
            t -= seg.duration
        return (self.segments[-1], self.segments[-1].duration) if self.segments else (None, 0)

    def reference(self, t):
        """(pose, v, ω, phase) of the plan at time t from its start."""
        seg, local = self._segment_at(max(0.0, t))
        if seg is None:
            return self.start_pose.copy(), 0.0, 0.0, 'stroke'
        pose, v, w = seg.state(local)
        if t >= self.duration:
            v, w = 0.0, 0.0
        return pose, v, w, seg.phase

    def end_pose(self):
        return self.segments[-1].end_pose() if self.segments else self.start_pose.copy()

    def sample(self, dt):
        """(times, poses (N, 3), v, ω) every dt."""
        n = max(1, int(np.ceil(self.duration / dt)))
        times = np.linspace(0.0, self.duration, n + 1)
        refs = [self.reference(t) for t in times]
        return (times, np.array([r[0] for r in refs]), np.array([r[1] for r in refs]),
                np.array([r[2] for r in refs]))


def _make_segment(kind, amount, phase, start_pose, limits, curvature=0.0):
    if kind == 'turn':
        vel, acc, jerk = (limits.angular_velocity, limits.angular_acceleration,
                          limits.angular_jerk)
    else:
        vel, acc, jerk = limits.linear_velocity, limits.linear_acceleration, limits.linear_jerk
    if kind == 'arc' and abs(curvature) > 1e-12:
        # Keep ω = κ v (and its derivatives) within the angular limits too.
        k = abs(curvature)
        vel = min(vel, limits.angular_velocity / k)
        acc = min(acc, limits.angular_acceleration / k)
        jerk = min(jerk, limits.angular_jerk / k)
    seg = BaseSegment(kind, float(amount), phase, np.asarray(start_pose, dtype=float),
                      float(curvature))
    if abs(amount) > 1e-9:
        seg.profile = path_profile(abs(amount), vel, acc, jerk)
        seg.duration = float(seg.profile.duration)
    return seg


def plan_orbit(start_pose, cube_xy, angle, radius, limits=None, face_tol=np.radians(1.0),
               approach_tol=0.005):
    """ORBIT(angle): the cube's yaw relative to the robot changes by `angle` (docs/MODEL.md),
    i.e. the robot moves by -angle about the cube's vertical axis and ends `radius` from
    it, facing it. Positive angle: turn left, drive forward clockwise around the cube
    (seen from above, the cube on the right); negative: the mirror image.

    `start_pose` (x, y, yaw) and `cube_xy` are in the odom frame."""
    limits = limits or BaseLimits()
    if radius <= 0:
        raise ValueError('orbit radius must be > 0')
    pose = np.asarray(start_pose, dtype=float).copy()
    cube = np.asarray(cube_xy, dtype=float)[:2]
    plan = OrbitPlan(float(angle), float(radius), cube, pose.copy())
    sgn = 1.0 if angle >= 0 else -1.0
    rel = cube - pose[:2]
    dist = float(np.linalg.norm(rel))
    if dist < 1e-6:
        raise ValueError('the robot stands on the cube')
    bearing = wrap(np.arctan2(rel[1], rel[0]) - pose[2])

    def add(kind, amount, phase, curvature=0.0):
        nonlocal pose
        seg = _make_segment(kind, amount, phase, pose, limits, curvature)
        if seg.duration > 0:
            plan.segments.append(seg)
            pose = seg.end_pose()

    if abs(dist - radius) > approach_tol:
        if abs(bearing) > face_tol:
            add('turn', bearing, 'approach')
        add('line', dist - radius, 'approach')
        add('turn', sgn * np.pi / 2, 'approach')
    else:
        add('turn', wrap(bearing + sgn * np.pi / 2), 'approach')
    add('arc', radius * abs(angle), 'stroke', curvature=-sgn / radius)
    to_cube = cube - pose[:2]
    add('turn', wrap(np.arctan2(to_cube[1], to_cube[0]) - pose[2]), 'stroke')
    return plan


def plan_base_approach(start_pose, cube_xy, distance, limits=None, face_tol=np.radians(1.0),
                       approach_tol=0.005):
    """Turn to face the cube and drive straight to `distance` from it (the bearing about
    the cube, hence the cube's relative yaw, does not change). An OrbitPlan of angle 0."""
    limits = limits or BaseLimits()
    pose = np.asarray(start_pose, dtype=float).copy()
    cube = np.asarray(cube_xy, dtype=float)[:2]
    plan = OrbitPlan(0.0, float(distance), cube, pose.copy())
    rel = cube - pose[:2]
    bearing = wrap(np.arctan2(rel[1], rel[0]) - pose[2])
    if abs(bearing) > face_tol:
        seg = _make_segment('turn', bearing, 'approach', pose, limits)
        plan.segments.append(seg)
        pose = seg.end_pose()
    dist = float(np.linalg.norm(rel))
    if abs(dist - distance) > approach_tol:
        plan.segments.append(_make_segment('line', dist - distance, 'approach', pose, limits))
    return plan


def integrate_unicycle(pose, v, w, dt):
    """Exact pose after driving at (v, ω) for dt from pose (x, y, yaw)."""
    x, y, yaw = pose
    if abs(w) < 1e-9:
        return np.array([x + v * dt * np.cos(yaw), y + v * dt * np.sin(yaw), yaw])
    yaw1 = yaw + w * dt
    return np.array([x + v / w * (np.sin(yaw1) - np.sin(yaw)),
                     y - v / w * (np.cos(yaw1) - np.cos(yaw)), wrap(yaw1)])


def bearing_about(cube_xy, pose):
    """Direction (rad, odom) from the cube to the robot: what ORBIT changes by -angle."""
    return float(np.arctan2(pose[1] - cube_xy[1], pose[0] - cube_xy[0]))


def head_pan_towards(pose, cube_xy, limit=1.6):
    """Head pan (rad) that points the camera at the cube from the base pose (clipped)."""
    rel = np.asarray(cube_xy[:2], dtype=float) - np.asarray(pose[:2], dtype=float)
    return float(np.clip(wrap(np.arctan2(rel[1], rel[0]) - pose[2]), -limit, limit))


@dataclass
class OrbitTracker:
    """Closed-loop tracking of an OrbitPlan on odometry (Kanayama's unicycle law plus a
    heading term that also acts when turning in place), then settling on the end pose.

    Settling turns in place when only the heading is off. A unicycle cannot remove a
    sideways error in place, so when the position is off (odometry lag, wheel slip)
    it turns towards the end point, drives there (backwards if that is shorter), and
    turns to the end heading."""

    plan: OrbitPlan
    limits: BaseLimits = field(default_factory=BaseLimits)
    k_x: float = 1.5
    k_y: float = 8.0
    k_theta: float = 2.5
    yaw_tolerance: float = np.radians(2.0)
    position_tolerance: float = 0.02
    settle_time: float = 4.0
    # Settling state: driving to the end point, and the settling time added for that.
    _repositioning: bool = field(default=False, init=False, repr=False)
    _extra_settle_time: float = field(default=0.0, init=False, repr=False)

    @property
    def settle_deadline(self):
        """Plan time (s) at which an unsettled base is given up on."""
        return self.plan.duration + self.settle_time + self._extra_settle_time

    def errors(self, t, pose):
        """(ex, ey, e_yaw) of the measured pose against the reference, robot frame."""
        ref, _, _, _ = self.plan.reference(t)
        dx, dy = ref[0] - pose[0], ref[1] - pose[1]
        c, s = np.cos(pose[2]), np.sin(pose[2])
        return c * dx + s * dy, -s * dx + c * dy, wrap(ref[2] - pose[2])

    def final_errors(self, pose):
        """(bearing error about the cube, heading error, radius error) against the end."""
        end = self.plan.end_pose()
        cube = self.plan.cube_xy
        b_err = wrap(bearing_about(cube, end) - bearing_about(cube, pose))
        r_err = float(np.linalg.norm(np.asarray(pose[:2]) - cube) - self.plan.radius)
        return b_err, wrap(end[2] - pose[2]), r_err

    def settled(self, pose):
        b_err, h_err, r_err = self.final_errors(pose)
        return (abs(b_err) <= self.yaw_tolerance and abs(h_err) <= self.yaw_tolerance
                and abs(r_err) <= self.position_tolerance)

    def command(self, t, pose):
        """(v, ω, phase, done, ok): velocity command at time t for the measured pose;
        done once past the plan and settled (ok) or out of settling time (not ok)."""
        _, v_ref, w_ref, phase = self.plan.reference(t)
        if t >= self.plan.duration:
            if self.settled(pose):
                return 0.0, 0.0, phase, True, True
            if t >= self.settle_deadline:
                return 0.0, 0.0, phase, True, False
        if t >= self.plan.duration:
            v, w = self._settle(pose)
        else:
            ex, ey, eth = self.errors(t, pose)
            v = v_ref * np.cos(eth) + self.k_x * ex
            w = w_ref + self.k_y * v_ref * ey + self.k_theta * np.sin(eth)
        vmax = 1.2 * self.limits.linear_velocity
        wmax = 1.2 * self.limits.angular_velocity
        return (float(np.clip(v, -vmax, vmax)), float(np.clip(w, -wmax, wmax)), phase,
                False, False)

    def _settle(self, pose):
        """(v, ω) towards the end pose: turn-drive-turn, with hysteresis on the distance."""
        end = self.plan.end_pose()
        offset = end[:2] - np.asarray(pose[:2], dtype=float)
        distance = float(np.hypot(*offset))
        # Within `enough`, the bearing and radius errors are within their tolerances.
        enough = 0.8 * min(self.position_tolerance, self.plan.radius * self.yaw_tolerance)
        if distance > enough and not self._repositioning:
            self._repositioning = True
            if not self._extra_settle_time:   # once: a base that cannot get there fails
                self._extra_settle_time = (np.pi / self.limits.angular_velocity + 1.0
                                           + distance / (0.5 * self.limits.linear_velocity))
        elif distance < 0.5 * enough:
            self._repositioning = False
        if not self._repositioning:
            return 0.0, self.k_theta * np.sin(wrap(end[2] - pose[2]))
        heading_error = wrap(np.arctan2(offset[1], offset[0]) - pose[2])
        direction = 1.0
        if abs(heading_error) > np.pi / 2:   # the end point is behind: back up to it
            heading_error, direction = wrap(heading_error - np.pi), -1.0
        w = self.k_theta * heading_error
        if abs(heading_error) > np.radians(10):
            return 0.0, w   # face the line first, so the drive does not swing sideways
        return direction * self.k_x * distance * np.cos(heading_error), w
