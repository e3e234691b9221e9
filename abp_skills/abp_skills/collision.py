"""Arm self-collision and clearance checks on simple shapes (plain NumPy, no rclpy).

The arms are capsules (upper arm shoulder->elbow, forearm elbow->hand) and the hands are
balls; the body is oriented boxes and cylinders. Radii, shapes and the links they hang on
come from the robot profile's `collision` and `arms` (the uBot-6: chassis, torso and head
boxes, wheel cylinders). Checked pairs: hand-hand and arm vs arm for every two arms
(which also catches crossed forearms), each forearm and hand against every body shape,
each upper arm against the shapes it is not attached to (the profile's shoulder_bodies),
everything against the floor, and optionally arm parts against obstacle boxes (the cube).
`check` returns (ok, reason) with the first violation, worded for a refusal.
"""

from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pinocchio as pin

UPPER, FOREARM, HAND = 0, 1, 2
PART_NAMES = ('upper arm', 'forearm', 'hand')


@dataclass(frozen=True)
class Box:
    """An oriented box: 4x4 pose of its centre and half extents (3,)."""

    name: str
    pose: np.ndarray
    half: np.ndarray

    def distance(self, points):
        """Distances (>= 0) of points (N, 3) from the box (0 inside)."""
        local = (np.asarray(points, dtype=float) - self.pose[:3, 3]) @ self.pose[:3, :3]
        outside = np.maximum(np.abs(local) - self.half, 0.0)
        return np.linalg.norm(outside, axis=-1)


@dataclass(frozen=True)
class Cylinder:
    """A cylinder: 4x4 pose of its centre (axis = local y), radius and half length."""

    name: str
    pose: np.ndarray
    radius: float
    half_length: float

    def distance(self, points):
        local = (np.asarray(points, dtype=float) - self.pose[:3, 3]) @ self.pose[:3, :3]
        radial = np.maximum(np.hypot(local[..., 0], local[..., 2]) - self.radius, 0.0)
        axial = np.maximum(np.abs(local[..., 1]) - self.half_length, 0.0)
        return np.hypot(radial, axial)


def cylinder_from(frame_pose, offset, radius, half_length, name):
    pose = np.array(frame_pose, dtype=float)
    pose[:3, 3] = pose[:3, 3] + pose[:3, :3] @ np.asarray(offset, dtype=float)
    return Cylinder(name, pose, float(radius), float(half_length))


def box_from(frame_pose, offset, half, name):
    pose = np.array(frame_pose, dtype=float)
    pose[:3, 3] = pose[:3, 3] + pose[:3, :3] @ np.asarray(offset, dtype=float)
    return Box(name, pose, np.asarray(half, dtype=float))


def segment_distance(p1, q1, p2, q2):
    """Smallest distance between segments p1-q1 and p2-q2 (closest-point formula)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    eps = 1e-12
    if a <= eps and e <= eps:
        return float(np.linalg.norm(r))
    if a <= eps:
        s, t = 0.0, np.clip(f / e, 0.0, 1.0)
    else:
        c = d1 @ r
        if e <= eps:
            s, t = np.clip(-c / a, 0.0, 1.0), 0.0
        else:
            b = d1 @ d2
            denom = a * e - b * b
            s = np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > eps else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = np.clip(-c / a, 0.0, 1.0), 0.0
            elif t > 1.0:
                s, t = np.clip((b - c) / a, 0.0, 1.0), 1.0
    return float(np.linalg.norm((p1 + d1 * s) - (p2 + d2 * t)))


class SelfCollision:
    """Clearance checks of the arms against each other, the body and the floor."""

    def __init__(self, kin, margin=0.01, floor_margin=0.0):
        self.kin = kin
        self.margin = float(margin)
        self.floor_margin = float(floor_margin)
        profile = kin.profile
        geometry = profile.collision
        self.sides = profile.sides
        self.UPPER_ARM_RADIUS = geometry.upper_arm_radius
        self.FOREARM_RADIUS = geometry.forearm_radius
        self.HAND_RADIUS = geometry.hand_radius
        self._bodies = geometry.bodies
        self._shoulder_bodies = set(geometry.shoulder_bodies)
        self._arm_frames = {s: (a.upper_arm_link, a.forearm_link, a.hand_frame)
                            for s, a in profile.arms.items()}
        names = [n for s in self.sides for n in self._arm_frames[s]]
        names += [b.frame for b in self._bodies if b.frame not in names]
        self._frames = names
        self._fids = [kin.model.getFrameId(n) for n in names]
        nu, nf = len(self._UPPER_FRAC), len(self._FORE_FRAC)
        self._radii = np.concatenate([np.full(nu, self.UPPER_ARM_RADIUS),
                                      np.full(nf, self.FOREARM_RADIUS), [self.HAND_RADIUS]])
        self._parts = np.concatenate([np.full(nu, UPPER), np.full(nf, FOREARM), [HAND]])
        pair = self._radii[:, None] + self._radii[None, :]
        both_upper = (self._parts == UPPER)[:, None] & (self._parts == UPPER)[None, :]
        self._pair_radii = np.where(both_upper, -np.inf, pair)  # shoulders 30 cm apart

    def shapes(self, q):
        """Capsules/balls of the arms ({side: dict}) and the body shapes at joint positions q."""
        model, data = self.kin.model, self.kin.data
        pin.framesForwardKinematics(model, data, self.kin.to_pinocchio(q))
        pose = {n: data.oMf[f].homogeneous for n, f in zip(self._frames, self._fids)}
        arms = {}
        for s in self.sides:
            upper, fore, hand = self._arm_frames[s]
            arms[s] = {'shoulder': pose[upper][:3, 3].copy(),
                       'elbow': pose[fore][:3, 3].copy(), 'hand': pose[hand][:3, 3].copy()}
        boxes = [box_from(pose[b.frame], b.offset, b.box, b.name) if b.box is not None else
                 cylinder_from(pose[b.frame], b.offset, b.radius, b.half_length, b.name)
                 for b in self._bodies]
        return arms, boxes

    def hand_positions(self, q):
        arms, _ = self.shapes(q)
        return {s: arms[s]['hand'] for s in self.sides}

    # Sample fractions along the upper arm (0.22 m) and the forearm (0.23 m), 1.5 cm apart:
    # the upper arm without its shoulder end, the forearm without its last 3 cm (the hand
    # ball covers them).
    _UPPER_FRAC = np.linspace(0.0, 1.0, 16)[2:]
    _FORE_FRAC = np.linspace(0.0, 1.0, 17)[:-2]

    def _arm_points(self, arm):
        """Sample points along one arm with their radii and part labels."""
        s, e, h = arm['shoulder'], arm['elbow'], arm['hand']
        upper = s + self._UPPER_FRAC[:, None] * (e - s)
        fore = e + self._FORE_FRAC[:, None] * (h - e)
        return np.vstack([upper, fore, h[None, :]]), self._radii, self._parts

    def check(self, q, obstacles=(), touching=(), sides=None):
        """(ok, reason) for joint positions q.

        `obstacles`: shapes (e.g. the cube's Box) that no arm part may enter; the hands in
        `touching` may touch them (a grasp or a push contact), but not their forearms.
        `sides`: the arms to check against the body and obstacles (all by default)."""
        arms, shapes = self.shapes(q)
        m = self.margin
        rh = self.HAND_RADIUS
        points = {s: self._arm_points(arms[s]) for s in self.sides}
        for a, b in combinations(self.sides, 2):
            d = float(np.linalg.norm(arms[a]['hand'] - arms[b]['hand']))
            if d < 2 * rh + m:
                return False, f'self-collision: hands {100 * d:.1f} cm apart'
            (ap, _, aparts), (bp, _, bparts) = points[a], points[b]
            gap = np.linalg.norm(ap[:, None, :] - bp[None, :, :], axis=-1) - self._pair_radii
            i, j = np.unravel_index(int(np.argmin(gap)), gap.shape)
            if gap[i, j] < m:
                if aparts[i] == FOREARM and bparts[j] == FOREARM:
                    what = 'forearms cross'
                else:
                    what = (f'{a} {PART_NAMES[aparts[i]]} touches the {b} '
                            f'{PART_NAMES[bparts[j]]}')
                return False, f'self-collision: {what} ({100 * gap[i, j]:.1f} cm)'
        checked = [s for s in self.sides if sides is None or s in sides]
        pts = np.vstack([points[s][0] for s in checked])
        radii = np.concatenate([self._radii for _ in checked])
        parts = np.concatenate([self._parts for _ in checked])
        owner = np.repeat(np.arange(len(checked)), len(self._radii))
        for shape in shapes:
            clearance = shape.distance(pts) - radii
            if shape.name in self._shoulder_bodies:
                clearance[parts == UPPER] = np.inf  # attached at the shoulder
            k = int(np.argmin(clearance))
            if clearance[k] < m:
                return False, (f'self-collision: {checked[owner[k]]} {PART_NAMES[parts[k]]} '
                               f'touches the {shape.name} ({100 * clearance[k]:.1f} cm)')
        low = pts[:, 2] - radii
        k = int(np.argmin(low))
        if low[k] < self.floor_margin - 1e-9:
            return False, f'{checked[owner[k]]} {PART_NAMES[parts[k]]} would touch the floor'
        exempt = np.isin(owner, [n for n, s in enumerate(checked) if s in touching]) \
            & (parts == HAND)
        for shape in obstacles:
            clearance = shape.distance(pts) - radii
            clearance[exempt] = np.inf
            k = int(np.argmin(clearance))
            if clearance[k] < 0.5 * m:
                return False, (f'{checked[owner[k]]} {PART_NAMES[parts[k]]} would hit the '
                               f'{shape.name}')
        return True, ''
