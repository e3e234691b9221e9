"""The manual skills' arm plans (PUSH, LIFT, FLIP) and the postures and motion building
blocks they are made of (no rclpy): ``ArmPlanner``, the base of ``plans.SkillPlanner``
(which adds the plan requests, ORBIT, the base approach and feasibility). ``plans``
documents the motions.
"""

import numpy as np

from abp_description.kinematics import look_at
from abp_description.robot_profile import ORBIT_FIELDS

from .base_motion import BaseLimits
from .collision import SelfCollision
from .ik import HandIK
from .motion_profiles import (
    Limits,
    SampledTrajectory,
    TrajectoryError,
    joint_trajectory,
    path_profile,
    sample_profile,
)
from .plan_types import CubeFrame, Phase, PlanError, SkillConfig, SkillPlan

__all__ = ['ArmPlanner', 'default_config']

# The postures (home, ready, reach) are the robot profile's (`RobotProfile.postures`): for
# the uBot-6 folded arms in front of the chest, clear of the wheels (home); arms raised
# forward and a little apart, torso half down, between home and the postures near the
# cube, clear of the chassis and torso (ready); a forward reach towards the floor, the IK
# seed of the manual skills (reach).
READY_TORSO_MARGIN = 0.1   # rad: a torso bent further than ready's goes home via ready


def default_config(profile):
    """SkillConfig defaults for the robot of `profile`: its first push arm, its ORBIT radii
    and base limits (the uBot-6's are SkillConfig's own defaults)."""
    orbit, push = profile.base.orbit, profile.skill_arms('push')
    return SkillConfig(push_hand=push[0] if push else SkillConfig.push_hand,
                       orbit_min_radius=orbit.min_radius, orbit_max_radius=orbit.max_radius,
                       base=BaseLimits(**{f: getattr(orbit, f) for f in ORBIT_FIELDS}))


class ArmPlanner:
    """The arms' side of the skills: postures, IK-timed hand paths and joint-space moves
    checked for collisions, and the PUSH / LIFT / FLIP plans built from them
    (``_plan_<skill>(q0, cube)``: a SkillPlan, or PlanError saying why not)."""

    def __init__(self, kin, config=None):
        self.kin = kin
        self.config = (config or default_config(kin.profile)).validate()
        self.ik = HandIK(kin, tol=self.config.ik_tolerance)
        self.collision = SelfCollision(kin, margin=self.config.collision_margin)
        # Joint names, arms and the torso come from the robot profile of the kinematics.
        self.profile = kin.profile
        self.sides = self.profile.sides
        self.body_joints = self.profile.body_joints
        torso = self.profile.torso
        self._torso = kin.joint_index(torso.joint) if torso is not None else None
        self._body_idx = np.array([kin.joint_index(n) for n in self.body_joints])
        push_hands = self.profile.skill_arms('push')
        if push_hands and self.config.push_hand not in push_hands:
            raise ValueError(f'push_hand must be one of {", ".join(push_hands)} (the robot '
                             f"profile's push arms), got {self.config.push_hand!r}")
        vel = kin.velocity_limits[self._body_idx] * self.config.joint_velocity_scale
        self.joint_limits = Limits(vel, self.config.joint_acceleration, self.config.joint_jerk)

    # -- postures ---------------------------------------------------------------------
    def _set_arm(self, q, side, posture):
        values = self.profile.postures[posture].arms[side]
        for name, v in zip(self.profile.arms[side].joints, values):
            q[self.kin.joint_index(name)] = v
        return q

    def _set_posture(self, q, posture):
        """The torso and every arm at the profile's `posture`."""
        self._set_torso(q, self.profile.postures[posture].torso)
        for side in self.sides:
            self._set_arm(q, side, posture)
        return q

    def home(self, q=None, look=None):
        """Torso upright, arms folded, head looking at `look` (base_link) if given."""
        q = self.kin.neutral() if q is None else np.array(q, dtype=float)
        self._set_posture(q, 'home')
        if look is not None:
            q, _ = look_at(self.kin, q, look)
        return self.kin.clip(q)

    def reach_seed(self, q):
        return self._set_posture(np.array(q, dtype=float), 'reach')

    def ready(self, q, look=None):
        q = self._set_posture(np.array(q, dtype=float), 'ready')
        if look is not None:
            q, _ = look_at(self.kin, q, look)
        return self.kin.clip(q)

    def _set_torso(self, q, value):
        if self._torso is not None and value is not None:
            q[self._torso] = value

    def _torso_pitch(self, q):
        return 0.0 if self._torso is None else q[self._torso]

    def _park_idle_arm(self, q, sides):
        """Keep the idle arms (`sides`) folded as at home, compensating the torso pitch."""
        q = q.copy()
        for side in sides:
            self._set_arm(q, side, 'home')
            i = self.kin.joint_index(self.profile.arms[side].joints[0])
            q[i] = self.profile.postures['home'].arms[side][0] - self._torso_pitch(q)
        return self.kin.clip(q)

    # -- building blocks ----------------------------------------------------------------
    def _solve(self, targets, q_seed, what, q_rest=None):
        seeds = [self.reach_seed(q_seed)]
        result = self.ik.solve(targets, q_seed, use_torso=True, q_rest=q_rest, seeds=seeds)
        if not result.success:
            raise PlanError(f'{what}: {result.reason}')
        return result.q

    def _body(self, q):
        return np.asarray(q, dtype=float)[self._body_idx]

    def _full(self, body, template):
        q = np.array(template, dtype=float)
        q[self._body_idx] = body
        return q

    def _free_move(self, q_from, waypoints):
        try:
            return joint_trajectory(self.body_joints, self._body(q_from),
                                    [self._body(w) for w in waypoints], self.joint_limits,
                                    self.config.sample_dt)
        except TrajectoryError as error:
            raise PlanError(str(error)) from error

    def _path_move(self, q_from, paths, what, idle=None):
        """Hands along polylines ({side: (M, 3)}), parametrised by the first hand's arc
        length, timed by a Ruckig path profile; IK at every sample (head held)."""
        cfg = self.config
        sides = tuple(paths)
        lead = np.asarray(paths[sides[0]], dtype=float)
        seg = np.linalg.norm(np.diff(lead, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        length = float(cum[-1])
        if length < 1e-6:
            return SampledTrajectory.hold(self.body_joints, self._body(q_from))
        scale = 1.0
        for _ in range(4):
            profile = path_profile(length, cfg.cartesian_velocity * scale,
                                   cfg.cartesian_acceleration * scale,
                                   cfg.cartesian_jerk * scale)
            times, s, _, _ = sample_profile(profile, cfg.sample_dt)
            q = np.array(q_from, dtype=float)
            qs = []
            for si in s[:, 0]:
                targets = {}
                for side in sides:
                    pts = np.asarray(paths[side], dtype=float)
                    targets[side] = np.array([np.interp(si, cum, pts[:, k]) for k in range(3)])
                result = self.ik.solve(targets, q, use_torso=True, q_rest=q)
                if not result.success:
                    raise PlanError(f'{what}: {result.reason}')
                q = result.q
                if idle is not None:
                    q = self._park_idle_arm(q, idle)
                qs.append(self._body(q))
            pos = np.array(qs)
            vel = np.gradient(pos, times, axis=0) if len(times) > 1 else np.zeros_like(pos)
            ratio = float(np.max(np.abs(vel) / (self.kin.velocity_limits[self._body_idx]
                                                 * cfg.joint_velocity_scale)))
            if ratio <= 1.05:
                acc = (np.gradient(vel, times, axis=0) if len(times) > 1
                       else np.zeros_like(pos))
                return SampledTrajectory(self.body_joints, times, pos, vel, acc)
            scale /= ratio * 1.1
        raise PlanError(f'{what}: the hand path needs joint speeds above the limits')

    def _check(self, phase, template, obstacles=(), touching=(), every=None):
        """Every `every`-th sample (default `check_stride`) clear of self-collision, floor
        and obstacles. A phase that starts in contact (e.g. the URDF's all-zero posture,
        whose hanging hands overlap the wheels) may leave it; once clear, it must stay
        clear."""
        traj = phase.trajectory
        every = every or self.config.check_stride
        escaping = True
        for k in list(range(0, len(traj.times), every)) + [len(traj.times) - 1]:
            q = self._full(traj.positions[k], template)
            ok, why = self.collision.check(q, obstacles=obstacles, touching=touching)
            if ok:
                escaping = False
            elif not (escaping and k < len(traj.times) - 1):
                raise PlanError(f'{phase.name} phase: {why}')

    def cube_frame(self, centre):
        cfg = self.config
        c = np.asarray(centre, dtype=float).reshape(3).copy()
        if not cfg.use_estimated_height:
            c[2] = cfg.support_height + cfg.cube_size / 2
        return CubeFrame.from_centre(c, cfg.cube_size)

    # -- the manual skills --------------------------------------------------------------
    def _plan_push(self, q0, cube):
        cfg = self.config
        side = cfg.push_hand
        idle = tuple(s for s in self.sides if s != side)
        h, r = cube.half, cfg.hand_radius
        contact = cube.point(h + r, 0.0, 0.0)
        pre = cube.point(h + r + cfg.approach_gap, 0.0, 0.0)
        hover = pre + [0.0, 0.0, cfg.hover_height]
        end = cube.point(h + r - cfg.push_stroke, 0.0, 0.0)
        look = cube.centre
        rest = self.reach_seed(q0)
        q_hover = self._park_idle_arm(self._solve({side: hover}, q0, 'hover above the push',
                                                  rest), idle)
        q_hover, _ = look_at(self.kin, q_hover, look)
        q_pre = self._park_idle_arm(self._solve({side: pre}, q_hover, 'pre-contact', q_hover),
                                    idle)
        q_pre, _ = look_at(self.kin, q_pre, look)
        approach = Phase('approach', self._free_move(
            q0, [self.ready(q0, look), q_hover, q_pre]))
        contact_t = self._path_move(q_pre, {side: np.array([pre, contact])}, 'contact', idle)
        q_contact = self._full(contact_t.end, q_pre)
        stroke_t = self._path_move(q_contact, {side: np.array([contact, end])}, 'stroke', idle)
        q_end = self._full(stroke_t.end, q_pre)
        back = end + cube.x * cfg.approach_gap
        back_t = self._path_move(q_end, {side: np.array([end, back])}, 'back off', idle)
        q_back = self._full(back_t.end, q_pre)
        pushed = cube.centre - cube.x * cfg.push_stroke
        q_home = self.home(q0, look=pushed)
        home_t = self._free_move(q_back, [self._lifted(q_back, side, cfg.hover_height),
                                          self.ready(q0, pushed), q_home])
        retreat = Phase('retreat', SampledTrajectory.concat([back_t, home_t]))
        phases = [approach, Phase('contact', contact_t), Phase('stroke', stroke_t), retreat]
        obstacles = [cube.box()]
        self._check(approach, q0, obstacles)
        self._check(phases[1], q0, obstacles, touching=(side,))
        self._check(phases[2], q0)
        self._check(retreat, q0)
        targets = {'contact': contact, 'pre_contact': pre, 'stroke_end': end, 'hover': hover}
        return SkillPlan('push', True, '', phases, {side: targets})

    def _lifted(self, q, side, dz):
        """Joints with the hand(s) raised by dz (IK; on failure, unchanged)."""
        sides = (side,) if isinstance(side, str) else tuple(side)
        pos = self.ik.hand_positions(q)
        result = self.ik.solve({s: pos[s] + [0.0, 0.0, dz] for s in sides}, q, q_rest=q)
        return result.q if result.success else q

    def _grasp_points(self, cube, along_x, squeeze, pair):
        """Hand centres on the robot's left (-y_V) and right (+y_V) faces, for the arms
        `pair` (the profile's arms of a two-hand skill, the one on the left first)."""
        cfg = self.config
        w = cube.half + cfg.hand_radius - squeeze
        return {pair[0]: cube.point(along_x, -w, 0.0), pair[1]: cube.point(along_x, w, 0.0)}

    def _two_hand_approach(self, q0, cube, along_x, squeeze, pair):
        cfg = self.config
        grasp = self._grasp_points(cube, along_x, squeeze, pair)
        opened = self._opened(cube, grasp, squeeze)
        hover = {s: p + [0.0, 0.0, cfg.hover_height] for s, p in opened.items()}
        rest = self.reach_seed(q0)
        q_hover = self._solve(hover, q0, 'hover above the grasp', rest)
        q_hover, _ = look_at(self.kin, q_hover, cube.centre)
        q_open = self._solve(opened, q_hover, 'pre-grasp', q_hover)
        q_open, _ = look_at(self.kin, q_open, cube.centre)
        approach = Phase('approach', self._free_move(
            q0, [self.ready(q0, cube.centre), q_hover, q_open]))
        close = self._path_move(q_open, {s: np.array([opened[s], grasp[s]]) for s in pair},
                                'grasp')
        q_grasp = self._full(close.end, q_open)
        return (approach, Phase('contact', close, pressing=squeeze > 0), q_grasp, grasp,
                opened, hover)

    def _opened(self, cube, held, squeeze):
        """{side: xyz}: the hands of `held` moved out along y_V to `approach_gap` clear of
        the faces they press `squeeze` into."""
        out = self.config.approach_gap + squeeze
        return {s: p + out * (cube.y if s == 'right' else -cube.y) for s, p in held.items()}

    @staticmethod
    def _grasp_obstacle(cube, squeeze):
        """The cube as the closing hands' arms meet it: the squeeze is a force set-point,
        the balls stop at the ±y faces and each arm stays `squeeze` further out than
        commanded, so the arms' clearance is checked against a cube that much narrower."""
        return cube.box(squeeze_y=squeeze)

    def _release(self, q_from, cube, held, q0, look, squeeze, what='release'):
        """Open the hands sideways from `held` ({side: xyz}), lift them, go home."""
        cfg = self.config
        opened = self._opened(cube, held, squeeze)
        open_t = self._path_move(q_from, {s: np.array([held[s], opened[s]]) for s in held},
                                 what)
        q_open = self._full(open_t.end, q_from)
        q_up = self._lifted(q_open, tuple(held), cfg.hover_height)
        home = self._free_move(q_open, [q_up, self.ready(q0, look), self.home(q0, look=look)])
        return Phase('retreat', SampledTrajectory.concat([open_t, home]))

    def _plan_lift(self, q0, cube):
        cfg = self.config
        approach, contact, q_grasp, grasp, _, _ = self._two_hand_approach(
            q0, cube, 0.0, cfg.grasp_squeeze, self.profile.skill_arms('lift'))
        up = {s: p + [0.0, 0.0, cfg.lift_height] for s, p in grasp.items()}
        raise_t = self._path_move(q_grasp, {s: np.array([grasp[s], up[s]]) for s in grasp},
                                  'lift')
        q_up = self._full(raise_t.end, q_grasp)
        lower_t = self._path_move(q_up, {s: np.array([up[s], grasp[s]]) for s in grasp},
                                  'place')
        q_down = self._full(lower_t.end, q_grasp)
        stroke = Phase('stroke', SampledTrajectory.concat([raise_t, lower_t]),
                       pressing=cfg.grasp_squeeze > 0)
        retreat = self._release(q_down, cube, grasp, q0, cube.centre, cfg.grasp_squeeze)
        phases = [approach, contact, stroke, retreat]
        obstacles = [cube.box()]
        self._check(approach, q0, obstacles)
        self._check(contact, q0, [self._grasp_obstacle(cube, cfg.grasp_squeeze)],
                    touching=tuple(grasp))
        self._check(stroke, q0)
        self._check(retreat, q0)
        return SkillPlan('lift', True, '', phases,
                         {'grasp': grasp, 'raised': up})

    def _plan_flip(self, q0, cube):
        cfg = self.config
        approach, contact, q_grasp, grasp, _, _ = self._two_hand_approach(
            q0, cube, cfg.flip_grasp_offset, cfg.flip_squeeze, self.profile.skill_arms('flip'))
        roll = np.radians(cfg.flip_roll_deg)
        phi = np.linspace(0.0, roll, 19)
        frac_up = np.sin(phi) / max(np.sin(min(roll, np.pi / 2)), 1e-9)
        frac_back = (1 - np.cos(phi)) / max(1 - np.cos(min(roll, np.pi / 2)), 1e-9)
        roll_paths = {s: np.array([grasp[s] + cfg.flip_up * fu * np.array([0, 0, 1.0])
                                   + cfg.flip_back * fb * cube.x
                                   for fu, fb in zip(frac_up, frac_back)])
                      for s in grasp}
        roll_t = self._path_move(q_grasp, roll_paths, 'roll')
        q_rolled = self._full(roll_t.end, q_grasp)
        rolled = {s: roll_paths[s][-1] for s in grasp}
        # Put it down straight below where the roll left it. Carrying it forward again as
        # it lands pushes the top of a rolled cube on past its quarter turn (towards a
        # half turn) and tips over a cube held without turning (wedged between the hands
        # at an odd yaw); lowered vertically, each lands on the face it hangs on.
        placed = {s: p + cfg.flip_back * cube.x for s, p in grasp.items()}
        place_t = self._path_move(q_rolled, {s: np.array([rolled[s], placed[s]])
                                             for s in grasp}, 'put down')
        q_placed = self._full(place_t.end, q_grasp)
        stroke = Phase('stroke', SampledTrajectory.concat([roll_t, place_t]),
                       pressing=cfg.flip_squeeze > 0)
        retreat = self._release(q_placed, cube, placed, q0, cube.centre, cfg.flip_squeeze)
        phases = [approach, contact, stroke, retreat]
        obstacles = [cube.box()]
        self._check(approach, q0, obstacles)
        self._check(contact, q0, [self._grasp_obstacle(cube, cfg.flip_squeeze)],
                    touching=tuple(grasp))
        self._check(stroke, q0)
        self._check(retreat, q0)
        return SkillPlan('flip', True, '', phases,
                         {'grasp': grasp, 'rolled': rolled, 'placed': placed})

    def go_home(self, q, look=None, tolerance=0.05):
        """Free move to the home posture (via the ready posture when the torso is bent
        or the arms are far from home); None when already there."""
        q = np.asarray(q, dtype=float)
        q_home = self.home(q, look=look)
        torso = () if self._torso is None else (self._torso,)
        arms = np.array([*torso, *(self.kin.joint_index(n) for s in self.sides
                                   for n in self.profile.arms[s].joints)])
        if np.max(np.abs(q[arms] - q_home[arms])) <= tolerance:
            return None
        via = []
        ready_torso = self.profile.postures['ready'].torso or 0.0
        if self._torso_pitch(q) > ready_torso + READY_TORSO_MARGIN:
            via.append(self.ready(q, look))
        return self._free_move(q, [*via, q_home])
