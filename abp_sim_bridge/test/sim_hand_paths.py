"""Test helper: real hand trajectories for PUSH, LIFT and FLIP, and MODEL.md's physics
table written out literally (no import of the code under test's physics).

The hand paths are Cartesian waypoints of the hand-ball centres (base_link, robot at the
odom origin facing +x) turned into joint positions by a small damped-least-squares IK on
`RobotKinematics.frame_jacobian` (torso + arms), densely enough (<= 1 cm apart) that the
joint-space interpolation of the trajectory controller keeps the hands on the path.
"""

import numpy as np

from abp_description.controllers import ARM_JOINTS, CONTROLLERS, SIDES, TORSO_JOINT
from abp_description.frames import rot_z_deg
from abp_description.kinematics import RobotKinematics

# The controllers that move the hands (the head's does not).
CONTROLLER_JOINTS = {c: joints for c, joints in CONTROLLERS.items() if c != 'head_controller'}
HAND_RADIUS = 0.03


class DlsIK:
    """Position IK for the hand balls: damped least squares over the torso and arms."""

    def __init__(self, kin=None):
        self.kin = kin or RobotKinematics()
        k = self.kin
        self.torso = k.joint_index(TORSO_JOINT)
        self.arm = {s: [k.joint_index(j) for j in ARM_JOINTS[s]] for s in SIDES}

    def hand(self, q, side):
        return self.kin.frame_pose(q, f'{side}_hand_link')[:3, 3]

    def solve(self, targets, q_seed, tol=2e-4, iters=200):
        k = self.kin
        q = np.array(q_seed, dtype=float)
        active = [self.torso] + [i for s in SIDES if s in targets for i in self.arm[s]]
        lo, hi = k.lower_limits[active] + 0.01, k.upper_limits[active] - 0.01
        err = np.inf
        for _ in range(iters):
            e, jac = [], []
            for side, target in targets.items():
                frame = f'{side}_hand_link'
                e.append(np.asarray(target) - k.frame_pose(q, frame)[:3, 3])
                jac.append(k.frame_jacobian(q, frame)[:3, active])
            e, J = np.concatenate(e), np.vstack(jac)
            err = float(np.abs(e).max())
            if err < tol:
                return q
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(len(e)), e)
            q[active] = np.clip(q[active] + np.clip(dq, -0.2, 0.2), lo, hi)
        raise AssertionError(f'IK did not converge (error {err:.4f} m) for {targets}')


def _dense(points, step=0.01):
    """Cartesian polyline -> points at most `step` apart (first point excluded)."""
    out = []
    for a, b in zip(points[:-1], points[1:]):
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out += [a + (b - a) * (i / n) for i in range(1, n + 1)]
    return out


class Plan:
    """Joint waypoints (times, q) for the torso and both arms."""

    def __init__(self, kin):
        self.kin = kin
        self.times, self.qs = [], []

    def add(self, t, q):
        self.times.append(float(t))
        self.qs.append(np.array(q, dtype=float))

    @property
    def duration(self):
        return self.times[-1]

    def controller_points(self):
        """{controller: (joint names, [(time_from_start, positions)])}."""
        out = {}
        for ctrl, joints in CONTROLLER_JOINTS.items():
            idx = [self.kin.joint_index(j) for j in joints]
            out[ctrl] = (joints, [(t, q[idx].tolist()) for t, q in zip(self.times, self.qs)])
        return out


def hand_path(action, cube_xy=(0.40, 0.0), edge=0.10, kin=None, ik=None, q_start=None,
              speed=0.08, push_depth=0.045, hand='left'):
    """Joint waypoints moving the hands through `action`'s contact motion on a cube at
    `cube_xy` whose faces are aligned with the base axes (robot at the origin, facing +x).

    PUSH: one hand at face-centre height through the front-face centre along +x, `push_depth`
    past the face plane. LIFT: both hands on the +-y faces at their centres, squeeze, raise
    7 cm, lower, open. FLIP: both hands on the +-y faces 1.5 cm from the robot-side edge,
    roll up 6 cm and back 6 cm, open. Then the hands retract to the start posture."""
    ik = ik or DlsIK(kin)
    kin = ik.kin
    q = kin.neutral() if q_start is None else np.array(q_start, dtype=float)
    cx, cy = cube_xy
    h = edge / 2
    r = HAND_RADIUS
    plan = Plan(kin)
    plan.add(0.0, q)
    t = 0.0
    current = {s: ik.hand(q, s) for s in SIDES}

    def go(targets_list, seconds=None):
        """Move through Cartesian targets ({side: xyz}); unlisted hands keep their place."""
        nonlocal q, t, current
        for targets in targets_list:
            full = {s: np.asarray(targets.get(s, current[s]), float) for s in SIDES}
            dist = max(np.linalg.norm(full[s] - current[s]) for s in SIDES)
            pts = _dense([np.concatenate([current[s] for s in SIDES]),
                          np.concatenate([full[s] for s in SIDES])])
            dt = (seconds if seconds is not None else dist / speed) / len(pts)
            for p in pts:
                tg = {'left': p[:3], 'right': p[3:]}
                q = ik.solve(tg, q)
                t += max(dt, 0.02)
                plan.add(t, q)
            current = full

    def swing(q_target, seconds):
        nonlocal q, t, current
        t += seconds
        q = np.array(q_target, dtype=float)
        plan.add(t, q)
        current = {s: ik.hand(q, s) for s in SIDES}

    # A comfortable "ready" posture in front of the body, above the cube's height.
    ready = {'left': np.array([cx - 0.17, cy + 0.14, 0.17]),
             'right': np.array([cx - 0.17, cy - 0.14, 0.17])}
    seed = kin.neutral()
    seed[ik.torso] = 0.6
    for s in SIDES:
        seed[ik.arm[s][0]], seed[ik.arm[s][3]] = -0.8, -0.8
    q_ready = ik.solve(ready, seed)
    swing(q_ready, 2.0)
    if action == 'PUSH':
        other = 'right' if hand == 'left' else 'left'
        x_touch = cx - h - r
        go([{hand: [x_touch - 0.04, cy, h + 0.06], other: ready[other]},
            {hand: [x_touch - 0.04, cy, h]},
            {hand: [x_touch + push_depth, cy, h]},
            {hand: [x_touch - 0.06, cy, h]},
            {hand: ready[hand]}])
    elif action in ('LIFT', 'FLIP'):
        gx = cx if action == 'LIFT' else cx - h + 0.015
        out_y, in_y = h + r + 0.04, h + r - 0.005
        go([{'left': [gx, cy + out_y, h + 0.06], 'right': [gx, cy - out_y, h + 0.06]},
            {'left': [gx, cy + out_y, h], 'right': [gx, cy - out_y, h]},
            {'left': [gx, cy + in_y, h], 'right': [gx, cy - in_y, h]}])
        if action == 'LIFT':
            go([{'left': [gx, cy + in_y, h + 0.07], 'right': [gx, cy - in_y, h + 0.07]},
                {'left': [gx, cy + in_y, h], 'right': [gx, cy - in_y, h]},
                {'left': [gx, cy + out_y, h], 'right': [gx, cy - out_y, h]},
                {'left': [gx, cy + out_y, h + 0.08], 'right': [gx, cy - out_y, h + 0.08]}])
        else:
            bx, bz = gx - 0.06, h + 0.06
            go([{'left': [bx, cy + in_y, bz], 'right': [bx, cy - in_y, bz]},
                {'left': [bx, cy + out_y, bz], 'right': [bx, cy - out_y, bz]},
                {'left': [bx, cy + out_y, bz + 0.05], 'right': [bx, cy - out_y, bz + 0.05]}])
        go([ready])
    else:
        raise ValueError(action)
    swing(kin.neutral() if q_start is None else q_start, 2.0)
    return plan


# -- MODEL.md's physics, written out from the text -------------------------------------

def rx(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def ry(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                        float)


def model_md_rotation(action, d):
    """MODEL.md "Actions and their physics": the rotation in V of a manual action on an
    aligned cube whose mass lies in V direction `d` (None = uniform)."""
    def is_(v):
        return d is not None and np.allclose(d, v)
    if action == 'PUSH':
        if is_([0, 1, 0]):
            return rot_z_deg(-45)     # d = +y: yaw -= 1
        if is_([0, -1, 0]):
            return rot_z_deg(45)      # d = -y: yaw += 1
        return np.eye(3)       # none, +-x, +-z: slides
    if action == 'LIFT':
        if is_([0, 0, 1]):
            return ry(180)
        if is_([1, 0, 0]):
            return ry(90)
        if is_([-1, 0, 0]):
            return ry(-90)
        return np.eye(3)       # none, -z, +-y
    if action == 'FLIP':
        if d is None:
            return ry(-90)
        for v, rot in (([1, 0, 0], ry(90)), ([-1, 0, 0], ry(-90)), ([0, 0, 1], ry(180)),
                       ([0, 0, -1], np.eye(3)), ([0, 1, 0], rx(-90)), ([0, -1, 0], rx(90))):
            if is_(v):
                return rot
    raise ValueError(action)


def view_rotation(cube_rotation_world, cube_xy, robot_xy=(0.0, 0.0)):
    """Body -> V rotation (V: x from the cube towards the robot, z up)."""
    x = np.array([robot_xy[0] - cube_xy[0], robot_xy[1] - cube_xy[1], 0.0])
    x /= np.linalg.norm(x)
    view = np.column_stack([x, np.cross([0, 0, 1.0], x), [0, 0, 1.0]])
    return view.T @ np.asarray(cube_rotation_world)


def expected_state(action, mass_index, rel_rotation):
    """MODEL.md state index after `action` from the body->V rotation `rel_rotation`."""
    from abp_belief.cube import state_from_rotation

    d = None if mass_index == 0 else rel_rotation @ FACE_NORMALS[mass_index - 1]
    return state_from_rotation(model_md_rotation(action, d) @ rel_rotation)
