"""The base's motions: ORBIT around the cube and the manual skills' approach, as planned
profiles and a closed-loop tracker on odometry (plain NumPy + Ruckig, no rclpy).

`plan_orbit` builds ORBIT(θ) for a differential drive: turn in place to the tangent,
drive a constant-radius arc around the cube (v = r·ω), turn back to face the cube, each
piece a Ruckig profile of its angle or length (`motion_profiles.path_profile`).
`plan_base_approach` turns to the cube and drives straight to a distance from it.
`OrbitTracker` closes the loop on odometry with a unicycle tracking law and a final
settling phase.

Angles in rad, lengths in m, times in s; poses are (x, y, yaw) in the odom frame.
"""

from dataclasses import dataclass, field

import numpy as np

from abp_description.frames import se2_between, wrap_rad

from .motion_profiles import Limits, path_profile


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
            return np.array([x0, y0, wrap_rad(yaw0 + sign * s)]), 0.0, sign * ds
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
        return np.array([x, y, wrap_rad(yaw)]), ds, k * ds

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
    bearing = wrap_rad(np.arctan2(rel[1], rel[0]) - pose[2])

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
        add('turn', wrap_rad(bearing + sgn * np.pi / 2), 'approach')
    add('arc', radius * abs(angle), 'stroke', curvature=-sgn / radius)
    to_cube = cube - pose[:2]
    add('turn', wrap_rad(np.arctan2(to_cube[1], to_cube[0]) - pose[2]), 'stroke')
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
    bearing = wrap_rad(np.arctan2(rel[1], rel[0]) - pose[2])
    if abs(bearing) > face_tol:
        seg = _make_segment('turn', bearing, 'approach', pose, limits)
        plan.segments.append(seg)
        pose = seg.end_pose()
    dist = float(np.linalg.norm(rel))
    if abs(dist - distance) > approach_tol:
        plan.segments.append(_make_segment('line', dist - distance, 'approach', pose, limits))
    return plan


def bearing_about(cube_xy, pose):
    """Direction (rad, odom) from the cube to the robot: what ORBIT changes by -angle."""
    return float(np.arctan2(pose[1] - cube_xy[1], pose[0] - cube_xy[0]))


def head_pan_towards(pose, cube_xy, limit=1.6):
    """Head pan (rad) that points the camera at the cube from the base pose (clipped)."""
    rel = np.asarray(cube_xy[:2], dtype=float) - np.asarray(pose[:2], dtype=float)
    return float(np.clip(wrap_rad(np.arctan2(rel[1], rel[0]) - pose[2]), -limit, limit))


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
    # Longest step of plan time between two commands. A starved control loop (a loaded
    # machine, a simulation faster than real time) leaves the base on its last command
    # or, after the base's command timeout, standing still, while the clock runs on: the
    # plan pauses for the excess, so that the reference does not run away from the base.
    max_step: float = 0.25
    # Settling state: driving to the end point, and the settling time added for that.
    _repositioning: bool = field(default=False, init=False, repr=False)
    _extra_settle_time: float = field(default=0.0, init=False, repr=False)
    # The clock at the last command, and the plan time it was turned into.
    _last_t: float = field(default=None, init=False, repr=False)
    _plan_t: float = field(default=0.0, init=False, repr=False)

    @property
    def plan_time(self):
        """Plan time (s) of the last command: t less the pauses of a starved loop."""
        return self._plan_t

    @property
    def settle_deadline(self):
        """Plan time (s) at which an unsettled base is given up on."""
        return self.plan.duration + self.settle_time + self._extra_settle_time

    def errors(self, t, pose):
        """(ex, ey, e_yaw) of the measured pose against the reference, robot frame."""
        ref, _, _, _ = self.plan.reference(t)
        ex, ey, e_yaw = se2_between(pose, ref)
        return float(ex), float(ey), float(e_yaw)

    def final_errors(self, pose):
        """(bearing error about the cube, heading error, radius error) against the end."""
        end = self.plan.end_pose()
        cube = self.plan.cube_xy
        b_err = wrap_rad(bearing_about(cube, end) - bearing_about(cube, pose))
        r_err = float(np.linalg.norm(np.asarray(pose[:2]) - cube) - self.plan.radius)
        return b_err, wrap_rad(end[2] - pose[2]), r_err

    def settled(self, pose):
        b_err, h_err, r_err = self.final_errors(pose)
        return (abs(b_err) <= self.yaw_tolerance and abs(h_err) <= self.yaw_tolerance
                and abs(r_err) <= self.position_tolerance)

    def command(self, t, pose):
        """(v, ω, phase, done, ok): velocity command at time t for the measured pose;
        done once past the plan and settled (ok) or out of settling time (not ok).
        Plan time follows t in steps of at most `max_step` (`plan_time`)."""
        if self._last_t is not None:
            self._plan_t += min(max(t - self._last_t, 0.0), self.max_step)
        else:
            self._plan_t = t
        self._last_t = t
        t = self._plan_t
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
            return 0.0, self.k_theta * np.sin(wrap_rad(end[2] - pose[2]))
        heading_error = wrap_rad(np.arctan2(offset[1], offset[0]) - pose[2])
        direction = 1.0
        if abs(heading_error) > np.pi / 2:   # the end point is behind: back up to it
            heading_error, direction = wrap_rad(heading_error - np.pi), -1.0
        w = self.k_theta * heading_error
        if abs(heading_error) > np.radians(10):
            return 0.0, w   # face the line first, so the drive does not swing sideways
        return direction * self.k_x * distance * np.cos(heading_error), w
