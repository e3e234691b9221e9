"""The skills' motions as phases of joint trajectories, and their feasibility (no rclpy).

Everything is placed relative to the cube's estimated centre in `base_link` and the view
frame V of docs/MODEL.md (x_V horizontal from the cube towards the robot, z up, y_V on
the robot's right). The hands are balls: the contact ball of `hand_radius` (the sim
bridge's 0.03 m, docs/INTERFACES.md) touches a face when its centre is `hand_radius`
from the face plane.

- PUSH (one hand, `push_hand`): hover above the pre-contact point, go down in front of
  the front face, touch it (contact), push `push_stroke` along -x_V through the face
  centre (stroke), back off and go home (retreat).
- LIFT: both hands beside the ±y_V faces at their centres, close in (contact, squeezing
  `grasp_squeeze`), raise by `lift_height` and lower again (stroke), open and go home.
  The squeeze is the grip force of the position-servoed arms: the pads' torsional
  friction, proportional to it, is what keeps a cube gripped off its centre of mass
  (the estimate's error) from swinging about the hand axis.
- FLIP: as LIFT but the contacts are `flip_grasp_offset` towards the robot from the face
  centres (inside the third of the face nearest the robot), squeezing only `flip_squeeze`
  (at an odd yaw the hands meet the two front faces at 45°, and pads with a friction
  coefficient above 1 jam in that wedge; a light squeeze lets it slip rather than carry
  the cube through the roll; the roll itself needs little grip); the stroke rolls the hands up
  by `flip_up` and back towards the robot by `flip_back` along a quarter ellipse, then
  lowers them straight down and lets go: the cube is set down where the roll left it.
- ORBIT: `base_motion.plan_orbit` for the base; feasibility here (radius, clearance).

Free motions are joint-space Ruckig segments; contact, stroke and release moves are
straight (or elliptic) hand paths timed by a Ruckig path profile and mapped to joints by
IK at every sample. Every sample of every phase is checked for self-collision and floor
clearance (free motions also against the cube). A plan that fails says why.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from abp_belief.cube import ACTIONS, ORBIT_STEPS
from abp_description.controllers import ARM_JOINTS, BODY_JOINTS, SIDES, TORSO_JOINT, other_side
from abp_description.frames import se2_compose
from abp_description.kinematics import look_at

from .base_motion import BaseLimits, plan_orbit
from .collision import Box, SelfCollision
from .ik import HandIK, mirror_arm
from .motion_profiles import (
    Limits,
    SampledTrajectory,
    TrajectoryError,
    joint_trajectory,
    path_profile,
    sample_profile,
)

MANUAL_SKILLS = ('push', 'lift', 'flip')
# The ATG's actions (ACTIONS, in the planner's and the belief's order) and the ORBIT
# angles: ORBIT(θ) turns the cube's relative yaw by θ = 45° x the belief's ORBIT_STEPS,
# so the angle the base drives is the yaw change the belief predicts.
YAW_STEP_DEG = 45.0
ORBIT_ACTIONS = {name: YAW_STEP_DEG * steps for name, steps in ORBIT_STEPS.items()}
# An Orbit goal may also ask for -180 deg: the same view change, driven the other way round.
ORBIT_ANGLES_DEG = (*ORBIT_ACTIONS.values(), -180.0)
PHASES = ('approach', 'contact', 'stroke', 'retreat')

# Folded arms (in front of the chest, clear of the wheels): left arm joint values;
# the right arm mirrors them.
HOME_ARM = (0.5, 0.2, 0.0, -2.0)
# A forward reach towards the floor: a seed for the IK of the manual skills.
REACH_ARM = (-1.2, 0.1, 0.0, -0.45)
REACH_TORSO = 1.0
# Arms raised forward and a little apart, torso half down: the via posture between home
# and the postures near the cube (keeps the arms clear of the chassis and torso).
READY_ARM = (-0.9, 0.25, 0.0, -1.0)
READY_TORSO = 0.3


# A cube off straight ahead by more than this makes a manual skill turn the base first.
APPROACH_BEARING_TOLERANCE = np.radians(5.0)


@dataclass
class SkillConfig:
    """Geometry and motion parameters of the skills (the node's ROS parameters)."""

    cube_size: float = 0.10            # m, ARcube edge
    support_height: float = 0.0        # m, height of the surface under the cube in base_link
    use_estimated_height: bool = False  # True: take the cube's z from the estimate
    hand_radius: float = 0.03          # m, contact ball of a hand
    # How far the grasps press into the faces: the position-servoed arms' grip force.
    # (The URDF's pads are 0.035 m balls, so they are commanded 5 mm further in still.)
    grasp_squeeze: float = 0.015       # m, LIFT
    flip_squeeze: float = 0.0          # m, FLIP: a light grip (see the module doc)
    approach_gap: float = 0.05         # m, free space between a hand and a face before contact
    hover_height: float = 0.08         # m, via point above the pre-contact posture
    push_hand: str = 'right'
    push_stroke: float = 0.05          # m, hand travel beyond first contact
    lift_height: float = 0.08          # m
    flip_grasp_offset: float = 0.03    # m, contacts this far from the face centres to the robot
    flip_up: float = 0.07              # m
    flip_back: float = 0.06            # m
    flip_roll_deg: float = 90.0
    joint_velocity_scale: float = 0.5  # fraction of the URDF velocity limits
    joint_acceleration: float = 2.0    # rad/s^2
    joint_jerk: float = 10.0           # rad/s^3
    cartesian_velocity: float = 0.08   # m/s, hand speed on contact/stroke paths
    cartesian_acceleration: float = 0.3
    cartesian_jerk: float = 2.0
    sample_dt: float = 0.05            # s between trajectory points
    ik_tolerance: float = 0.002        # m
    collision_margin: float = 0.01     # m
    check_stride: int = 2              # collision-check every n-th trajectory sample
    feasibility_check_stride: int = 2  # the same for feasibility answers, on a 0.1 s grid
    base_approach: bool = True         # manual skills first drive to manipulation_distance
    # m, cube centre from base_link for PUSH/LIFT/FLIP. The middle of the distances where
    # all three plans clear the body (0.41-0.51 m within 5 deg of straight ahead; closer,
    # an upper arm passes the chassis within collision_margin), so that the approach's
    # landing error (OrbitTracker's 2 cm) and approach_tolerance stay inside it.
    manipulation_distance: float = 0.45
    max_base_approach: float = 0.35    # m, the furthest a manual skill drives to get there
    approach_tolerance: float = 0.03   # m; and bearing 5 deg: closer needs no base motion
    orbit_min_radius: float = 0.30     # m (turning in place must clear the cube)
    orbit_max_radius: float = 1.00
    base: BaseLimits = field(default_factory=BaseLimits)

    def validate(self):
        positive = ('cube_size', 'hand_radius', 'approach_gap', 'push_stroke', 'lift_height',
                    'flip_up', 'flip_back', 'flip_roll_deg', 'joint_velocity_scale',
                    'joint_acceleration', 'joint_jerk', 'cartesian_velocity',
                    'cartesian_acceleration', 'cartesian_jerk', 'sample_dt', 'ik_tolerance',
                    'orbit_min_radius', 'orbit_max_radius', 'manipulation_distance',
                    'approach_tolerance')
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if int(self.check_stride) < 1 or int(self.feasibility_check_stride) < 1:
            raise ValueError('check_stride and feasibility_check_stride must be >= 1')
        if self.push_hand not in SIDES:
            raise ValueError(f"push_hand must be 'left' or 'right', got {self.push_hand!r}")
        for name in ('grasp_squeeze', 'flip_squeeze'):
            if not 0 <= getattr(self, name) < self.hand_radius:
                raise ValueError(f'{name} must be in [0, hand_radius)')
        if not 0 <= self.flip_grasp_offset < self.cube_size / 2:
            raise ValueError('flip_grasp_offset must be in [0, cube_size / 2)')
        if self.joint_velocity_scale > 1:
            raise ValueError('joint_velocity_scale must be <= 1')
        if self.max_base_approach < 0:
            raise ValueError('max_base_approach must be >= 0')
        if self.orbit_min_radius >= self.orbit_max_radius:
            raise ValueError('orbit_min_radius must be < orbit_max_radius')
        return self


@dataclass
class CubeFrame:
    """The cube centre and its view frame V in base_link."""

    centre: np.ndarray
    x: np.ndarray        # horizontal, from the cube towards the robot (front-face normal)
    y: np.ndarray        # z × x: on the robot's right
    size: float

    @classmethod
    def from_centre(cls, centre, size):
        c = np.asarray(centre, dtype=float).reshape(3)
        x = np.array([-c[0], -c[1], 0.0])
        n = np.linalg.norm(x)
        if n < 1e-6:
            raise ValueError('the cube centre is above the base origin')
        x /= n
        y = np.cross([0.0, 0.0, 1.0], x)
        return cls(c, x, y, float(size))

    @property
    def half(self):
        return self.size / 2

    @property
    def distance(self):
        return float(np.hypot(self.centre[0], self.centre[1]))

    def point(self, vx, vy, vz):
        """A point given in V coordinates (origin at the cube centre), in base_link."""
        return self.centre + vx * self.x + vy * self.y + np.array([0.0, 0.0, vz])

    def box(self, grow=0.0, squeeze_y=0.0):
        """The cube as a Box, grown by `grow` and narrowed by `squeeze_y` along y_V."""
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = self.x, self.y, (0.0, 0.0, 1.0)
        pose[:3, 3] = self.centre
        half = np.full(3, self.half + grow)
        half[1] -= squeeze_y
        return Box('cube', pose, half)


@dataclass
class Phase:
    name: str
    trajectory: SampledTrajectory   # over BODY_JOINTS
    # The hands press into the cube (a squeeze > 0): the faces stop the arms short of the
    # commanded path, so the joints do not arrive at its end (contact_goal_tolerance).
    pressing: bool = False

    @property
    def duration(self):
        return self.trajectory.duration


@dataclass
class SkillPlan:
    skill: str
    ok: bool
    reason: str = ''
    phases: list = field(default_factory=list)
    targets: dict = field(default_factory=dict)   # named hand targets, for inspection

    @property
    def duration(self):
        return float(sum(p.duration for p in self.phases))


class PlanError(RuntimeError):
    pass


class SkillPlanner:
    """Builds the skills' plans from the current joints and the cube's estimate."""

    def __init__(self, kin, config=None):
        self.kin = kin
        self.config = (config or SkillConfig()).validate()
        self.ik = HandIK(kin, tol=self.config.ik_tolerance)
        self.collision = SelfCollision(kin, margin=self.config.collision_margin)
        self._body_idx = np.array([kin.joint_index(n) for n in BODY_JOINTS])
        vel = kin.velocity_limits[self._body_idx] * self.config.joint_velocity_scale
        self.joint_limits = Limits(vel, self.config.joint_acceleration, self.config.joint_jerk)

    def with_config(self, **changes):
        return SkillPlanner(self.kin, replace(self.config, **changes))

    # -- postures ---------------------------------------------------------------------
    def _set_arm(self, q, side, values):
        values = values if side == 'left' else mirror_arm(values)
        for name, v in zip(ARM_JOINTS[side], values):
            q[self.kin.joint_index(name)] = v
        return q

    def home(self, q=None, look=None):
        """Torso upright, arms folded, head looking at `look` (base_link) if given."""
        q = self.kin.neutral() if q is None else np.array(q, dtype=float)
        q[self.kin.joint_index(TORSO_JOINT)] = 0.0
        for side in SIDES:
            self._set_arm(q, side, HOME_ARM)
        if look is not None:
            q, _ = look_at(self.kin, q, look)
        return self.kin.clip(q)

    def reach_seed(self, q):
        q = np.array(q, dtype=float)
        q[self.kin.joint_index(TORSO_JOINT)] = REACH_TORSO
        for side in SIDES:
            self._set_arm(q, side, REACH_ARM)
        return q

    def ready(self, q, look=None):
        q = np.array(q, dtype=float)
        q[self.kin.joint_index(TORSO_JOINT)] = READY_TORSO
        for side in SIDES:
            self._set_arm(q, side, READY_ARM)
        if look is not None:
            q, _ = look_at(self.kin, q, look)
        return self.kin.clip(q)

    def _park_idle_arm(self, q, side):
        """Keep the idle arm folded as at home, compensating the torso pitch."""
        q = q.copy()
        self._set_arm(q, side, HOME_ARM)
        i = self.kin.joint_index(ARM_JOINTS[side][0])
        q[i] = HOME_ARM[0] - q[self.kin.joint_index(TORSO_JOINT)]
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
            return joint_trajectory(BODY_JOINTS, self._body(q_from),
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
            return SampledTrajectory.hold(BODY_JOINTS, self._body(q_from))
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
                return SampledTrajectory(BODY_JOINTS, times, pos, vel, acc)
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
    def plan(self, skill, q_current, cube_centre, **overrides):
        """SkillPlan for 'push', 'lift' or 'flip' from joints `q_current` (13) with the cube
        centre at `cube_centre` (base_link). Overrides: push_stroke, lift_height,
        flip_roll_deg (goal fields)."""
        if skill not in MANUAL_SKILLS:
            raise ValueError(f'unknown manual skill {skill!r}')
        planner = self.with_config(**{k: v for k, v in overrides.items() if v})
        try:
            cube = planner.cube_frame(cube_centre)
            return getattr(planner, f'_plan_{skill}')(np.asarray(q_current, float), cube)
        except PlanError as error:
            return SkillPlan(skill, False, str(error))
        except ValueError as error:
            return SkillPlan(skill, False, str(error))

    def _plan_push(self, q0, cube):
        cfg = self.config
        side = cfg.push_hand
        idle = other_side(side)
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

    def _grasp_points(self, cube, along_x, squeeze):
        """Hand centres on the robot's left (-y_V) and right (+y_V) faces."""
        cfg = self.config
        w = cube.half + cfg.hand_radius - squeeze
        return {'left': cube.point(along_x, -w, 0.0), 'right': cube.point(along_x, w, 0.0)}

    def _two_hand_approach(self, q0, cube, along_x, squeeze):
        cfg = self.config
        grasp = self._grasp_points(cube, along_x, squeeze)
        opened = self._opened(cube, grasp, squeeze)
        hover = {s: p + [0.0, 0.0, cfg.hover_height] for s, p in opened.items()}
        rest = self.reach_seed(q0)
        q_hover = self._solve(hover, q0, 'hover above the grasp', rest)
        q_hover, _ = look_at(self.kin, q_hover, cube.centre)
        q_open = self._solve(opened, q_hover, 'pre-grasp', q_hover)
        q_open, _ = look_at(self.kin, q_open, cube.centre)
        approach = Phase('approach', self._free_move(
            q0, [self.ready(q0, cube.centre), q_hover, q_open]))
        close = self._path_move(q_open, {s: np.array([opened[s], grasp[s]]) for s in SIDES},
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
        open_t = self._path_move(q_from, {s: np.array([held[s], opened[s]]) for s in SIDES},
                                 what)
        q_open = self._full(open_t.end, q_from)
        q_up = self._lifted(q_open, SIDES, cfg.hover_height)
        home = self._free_move(q_open, [q_up, self.ready(q0, look), self.home(q0, look=look)])
        return Phase('retreat', SampledTrajectory.concat([open_t, home]))

    def _plan_lift(self, q0, cube):
        cfg = self.config
        approach, contact, q_grasp, grasp, _, _ = self._two_hand_approach(
            q0, cube, 0.0, cfg.grasp_squeeze)
        up = {s: p + [0.0, 0.0, cfg.lift_height] for s, p in grasp.items()}
        raise_t = self._path_move(q_grasp, {s: np.array([grasp[s], up[s]]) for s in SIDES},
                                  'lift')
        q_up = self._full(raise_t.end, q_grasp)
        lower_t = self._path_move(q_up, {s: np.array([up[s], grasp[s]]) for s in SIDES},
                                  'place')
        q_down = self._full(lower_t.end, q_grasp)
        stroke = Phase('stroke', SampledTrajectory.concat([raise_t, lower_t]),
                       pressing=cfg.grasp_squeeze > 0)
        retreat = self._release(q_down, cube, grasp, q0, cube.centre, cfg.grasp_squeeze)
        phases = [approach, contact, stroke, retreat]
        obstacles = [cube.box()]
        self._check(approach, q0, obstacles)
        self._check(contact, q0, [self._grasp_obstacle(cube, cfg.grasp_squeeze)],
                    touching=SIDES)
        self._check(stroke, q0)
        self._check(retreat, q0)
        return SkillPlan('lift', True, '', phases,
                         {'grasp': grasp, 'raised': up})

    def _plan_flip(self, q0, cube):
        cfg = self.config
        approach, contact, q_grasp, grasp, _, _ = self._two_hand_approach(
            q0, cube, cfg.flip_grasp_offset, cfg.flip_squeeze)
        roll = np.radians(cfg.flip_roll_deg)
        phi = np.linspace(0.0, roll, 19)
        frac_up = np.sin(phi) / max(np.sin(min(roll, np.pi / 2)), 1e-9)
        frac_back = (1 - np.cos(phi)) / max(1 - np.cos(min(roll, np.pi / 2)), 1e-9)
        roll_paths = {s: np.array([grasp[s] + cfg.flip_up * fu * np.array([0, 0, 1.0])
                                   + cfg.flip_back * fb * cube.x
                                   for fu, fb in zip(frac_up, frac_back)])
                      for s in SIDES}
        roll_t = self._path_move(q_grasp, roll_paths, 'roll')
        q_rolled = self._full(roll_t.end, q_grasp)
        rolled = {s: roll_paths[s][-1] for s in SIDES}
        # Put it down straight below where the roll left it. Carrying it forward again as
        # it lands pushes the top of a rolled cube on past its quarter turn (towards a
        # half turn) and tips over a cube held without turning (wedged between the hands
        # at an odd yaw); lowered vertically, each lands on the face it hangs on.
        placed = {s: p + cfg.flip_back * cube.x for s, p in grasp.items()}
        place_t = self._path_move(q_rolled, {s: np.array([rolled[s], placed[s]])
                                             for s in SIDES}, 'put down')
        q_placed = self._full(place_t.end, q_grasp)
        stroke = Phase('stroke', SampledTrajectory.concat([roll_t, place_t]),
                       pressing=cfg.flip_squeeze > 0)
        retreat = self._release(q_placed, cube, placed, q0, cube.centre, cfg.flip_squeeze)
        phases = [approach, contact, stroke, retreat]
        obstacles = [cube.box()]
        self._check(approach, q0, obstacles)
        self._check(contact, q0, [self._grasp_obstacle(cube, cfg.flip_squeeze)],
                    touching=SIDES)
        self._check(stroke, q0)
        self._check(retreat, q0)
        return SkillPlan('flip', True, '', phases,
                         {'grasp': grasp, 'rolled': rolled, 'placed': placed})

    # -- ORBIT --------------------------------------------------------------------------
    def orbit_radius(self, current_distance, requested=0.0):
        """The radius ORBIT drives at: `requested` if > 0, else the current distance,
        clamped into [orbit_min_radius, orbit_max_radius]."""
        cfg = self.config
        r = requested if requested and requested > 0 else current_distance
        return float(np.clip(r, cfg.orbit_min_radius, cfg.orbit_max_radius))

    def orbit_feasibility(self, angle_deg, cube_centre, requested_radius=0.0):
        """(ok, reason, radius) for ORBIT(angle_deg) with the cube at `cube_centre`."""
        cfg = self.config
        if not any(abs(angle_deg - a) < 1e-6 for a in ORBIT_ANGLES_DEG):
            return False, (f'orbit angle {angle_deg:g} deg is not one of '
                           f'{", ".join(f"{a:g}" for a in ORBIT_ANGLES_DEG)}'), 0.0
        if requested_radius and not (cfg.orbit_min_radius <= requested_radius
                                     <= cfg.orbit_max_radius):
            return False, (f'orbit radius {requested_radius:.2f} m outside '
                           f'[{cfg.orbit_min_radius:.2f}, {cfg.orbit_max_radius:.2f}] m'), 0.0
        c = np.asarray(cube_centre, dtype=float)
        dist = float(np.hypot(c[0], c[1]))
        if dist > cfg.orbit_max_radius + 0.5:
            return False, (f'cube {dist:.2f} m away: too far to orbit (max radius '
                           f'{cfg.orbit_max_radius:.2f} m)'), 0.0
        return True, '', self.orbit_radius(dist, requested_radius)

    def orbit_plan(self, angle_deg, base_pose, cube_centre, requested_radius=0.0):
        """OrbitPlan in the odom frame from the base pose (x, y, yaw) and the cube centre
        in base_link."""
        ok, reason, radius = self.orbit_feasibility(angle_deg, cube_centre, requested_radius)
        if not ok:
            raise PlanError(reason)
        c = np.asarray(cube_centre, dtype=float)
        cube_xy = se2_compose(base_pose, (c[0], c[1], 0.0))[:2]
        return plan_orbit(base_pose, cube_xy, np.radians(angle_deg), radius, self.config.base)

    def go_home(self, q, look=None, tolerance=0.05):
        """Free move to the home posture (via the ready posture when the torso is bent
        or the arms are far from home); None when already there."""
        q = np.asarray(q, dtype=float)
        q_home = self.home(q, look=look)
        arms = np.array([self.kin.joint_index(n) for n in
                         (TORSO_JOINT, *ARM_JOINTS['left'], *ARM_JOINTS['right'])])
        if np.max(np.abs(q[arms] - q_home[arms])) <= tolerance:
            return None
        via = []
        if q[self.kin.joint_index(TORSO_JOINT)] > READY_TORSO + 0.1:
            via.append(self.ready(q, look))
        return self._free_move(q, [*via, q_home])

    # -- the base approach of the manual skills ----------------------------------------
    def base_approach(self, cube_centre):
        """(needed, ok, reason, cube_after): whether a manual skill first drives the base
        (turn to face the cube, straight to `manipulation_distance`), whether it may, and
        the cube centre in base_link after it (nominal)."""
        cfg = self.config
        c = np.asarray(cube_centre, dtype=float).reshape(3)
        dist = float(np.hypot(c[0], c[1]))
        bearing = float(np.arctan2(c[1], c[0]))
        needed = cfg.base_approach and (abs(dist - cfg.manipulation_distance)
                                        > cfg.approach_tolerance
                                        or abs(bearing) > APPROACH_BEARING_TOLERANCE)
        if not needed:
            return False, True, '', c
        if abs(dist - cfg.manipulation_distance) > cfg.max_base_approach:
            return True, False, (
                f'cube {dist:.2f} m away: out of reach (the base approaches only within '
                f'{cfg.manipulation_distance:.2f} +- {cfg.max_base_approach:.2f} m)'), c
        return True, True, '', np.array([cfg.manipulation_distance, 0.0, c[2]])

    # -- feasibility of the ATG's actions ------------------------------------------------
    def feasibility(self, action, q_current, cube_centre):
        """(ok, reason) of an ACTIONS name at the cube estimate."""
        if action in ORBIT_ACTIONS:
            ok, reason, _ = self.orbit_feasibility(ORBIT_ACTIONS[action], cube_centre)
            return ok, reason
        if action in ('PUSH', 'LIFT', 'FLIP'):
            _, ok, reason, cube_after = self.base_approach(cube_centre)
            if not ok:
                return False, reason
            # The same plan on a coarser time grid (a skill that runs plans it again in full).
            coarse = self.with_config(check_stride=self.config.feasibility_check_stride,
                                      sample_dt=max(self.config.sample_dt, 0.1))
            plan = coarse.plan(action.lower(), q_current, cube_after)
            return plan.ok, plan.reason
        return False, f'unknown action {action!r} (expected one of {", ".join(ACTIONS)})'



__all__ = ['ACTIONS', 'APPROACH_BEARING_TOLERANCE', 'CubeFrame', 'MANUAL_SKILLS', 'ORBIT_ACTIONS',
           'ORBIT_ANGLES_DEG', 'PHASES', 'Phase', 'PlanError', 'SkillConfig', 'SkillPlan',
           'SkillPlanner']
