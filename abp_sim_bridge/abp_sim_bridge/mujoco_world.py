"""The simulated robot and ARcube world on MuJoCo (plain Python, no rclpy): a drop-in
alternative to `sim_world.SimWorld` for the sim_bridge node.

Each `step()` advances the simulation clock by one node period 1/rate, in several MuJoCo
steps of at most 2 ms (physics at >= 500 Hz of sim time):

1. **Base**: the last /cmd_vel (v, w) applies while it is younger than `cmd_vel_timeout`
   (sim time), else (0, 0); it is rate-limited to the base's velocity and acceleration
   limits and turned into world-frame rates of the planar joints (velocity servos).
   Odometry is ideal wheel odometry: it follows the base's true motion, and /odom's twist
   is the measured one.
   Odometry noise (`orbit_odometry_noise`): each base motion (from the first non-zero
   twist until the base stops) ends with the *true* base displaced by N(0, sigma_m^2) in
   x and y and N(0, sigma_rad^2) in yaw; /odom does not see it (as SimWorld).
2. **Joints**: each controller's `TrajectoryFollower` gives the desired positions (no faster
   than the URDF velocity limits, within the position limits), interpolated over the
   MuJoCo steps and fed to the position servos with velocity feed-forward.
3. **Contacts** are MuJoCo's. Manual actions are *recognised* from them, never decided:
   an episode starts when a hand touches the cube and ends when no hand has touched it for
   `release_time` and the cube has come to rest; it is a PUSH (one hand), a LIFT or a FLIP
   (both hands together, raised; FLIP when the hands also moved towards the robot), and its
   effect is what the discrete state did (MODEL.md's up face x 45-deg yaw step).

Faults are perturbations of physical quantities, not outcome rules: `friction_scale`
(cube, floor and hand pads), `servo_stiffness_scale` (a weaker squeeze), `grasp_opening`
(each hand held this far outwards: less squeeze, or none) and `joint_offsets`
(calibration errors that move the hands off their planned path).
"""

from dataclasses import dataclass, field

import numpy as np

from abp_description import camera_intrinsics
from abp_description.frames import se2_between, se2_compose, wrap_rad
from abp_description.kinematics import RobotKinematics

from .flat_renderer import DEFAULT_DICTIONARY
from .joint_trajectory_follower import TrajectoryFollower
from .mujoco_scene import (
    BASE_JOINTS,
    CAMERA_NAME,
    CUBE_BODY,
    CUBE_GEOM,
    HAND_GEOM_SUFFIX,
    CubeSpec,
    CubeState,
    SceneSettings,
    build_model,
    cube_prefix,
    discrete_state,
    hand_bodies,
    mujoco,
    rendered_as,
)
from .world_interface import CommandInputs, ContactEvent

EGL_HINT = ('MuJoCo offscreen rendering needs EGL (MUJOCO_GL=egl): install it with '
            '`apt-get install libegl1 libgl1-mesa-dri` or use the project Docker image')


def draw_contact_fault(rng, p_slip_grasp, p_missed_push, slip_grasp_opening,
                       missed_push_offset):
    """(grasp opening m, label) of one contact episode: a slipping grasp and a missed push
    drawn independently (in that order) with their probabilities; the opening is what
    each hand is held further out, the label names the faults drawn ('' for none)."""
    slip = rng.random() < p_slip_grasp
    miss = rng.random() < p_missed_push
    opening = slip * slip_grasp_opening + miss * missed_push_offset
    label = ' and '.join(n for n, on in (('slip', slip), ('missed push', miss)) if on)
    return opening, label


@dataclass
class MujocoSettings:
    rate: float = 50.0                       # Hz of simulation time (node ticks)
    physics_rate: float = 500.0              # Hz, at least: MuJoCo steps per second
    cmd_vel_timeout: float = 0.5             # s of simulation time
    orbit_odometry_noise: tuple = (0.0, 0.0)  # (m, rad) per base motion
    initial_positions: tuple = ()            # 13 joint positions, () = all zero
    max_linear_velocity: float = 0.5         # m/s, base
    max_linear_acceleration: float = 1.0     # m/s^2
    max_angular_velocity: float = 1.5        # rad/s
    max_angular_acceleration: float = 3.0    # rad/s^2
    # The cube's physics.
    cube_mass: float = 0.75                  # kg
    heavy_mass_ratio: float = 0.625          # heavy slab / total (centre of mass 2.5 cm off)
    cube_friction: float = 0.5
    floor_friction: float = 0.5
    hand_friction: float = 1.0
    hand_torsional_friction: float = 0.001   # m
    tag_edge: float = 0.08                   # m
    tag_dictionary: str = DEFAULT_DICTIONARY  # ArUco (OpenCV name) of the cube's tags
    # Faults as perturbations of physical quantities.
    friction_scale: float = 1.0              # multiplies every friction coefficient
    servo_stiffness_scale: float = 1.0       # multiplies the arm and torso servo gains
    grasp_opening: float = 0.0               # m, each hand held this far outwards
    joint_offsets: tuple = ()                # 13 rad added to the servo set points
    # Episodes of hand-cube contact (events).
    release_time: float = 0.3                # s without a hand on the cube
    settle_timeout: float = 3.0              # s, after release, to wait for rest
    grasp_raise: float = 0.03                # m the hands rise for a LIFT or FLIP
    flip_back: float = 0.02                  # m the hands move towards the robot for a FLIP
    # Camera.
    shadows: bool = False
    offsamples: int = 0
    width: int | None = None
    height: int | None = None
    seed: int = 0                            # odometry noise

    def __post_init__(self):
        if not (np.isfinite(self.rate) and 0 < self.rate <= 10000):
            raise ValueError(f'rate must be in (0, 10000] Hz, got {self.rate}')
        if not self.physics_rate >= 500:
            raise ValueError('physics_rate must be >= 500 Hz')
        if not self.cmd_vel_timeout > 0:
            raise ValueError('cmd_vel_timeout must be > 0 s')
        noise = tuple(float(v) for v in self.orbit_odometry_noise)
        if len(noise) != 2 or min(noise) < 0 or not np.all(np.isfinite(noise)):
            raise ValueError('orbit_odometry_noise must be [sigma_m, sigma_rad], both >= 0')
        self.orbit_odometry_noise = noise
        for name in ('friction_scale', 'servo_stiffness_scale', 'cube_mass',
                     'max_linear_velocity', 'max_linear_acceleration',
                     'max_angular_velocity', 'max_angular_acceleration'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if self.joint_offsets and len(self.joint_offsets) != 13:
            raise ValueError('joint_offsets must give 13 values (URDF joint order) or none')

    @property
    def period_ns(self):
        return int(round(1e9 / self.rate))


class _WorldView:
    """What the node reads from `SimWorld.world`: true and odometry base poses."""

    def __init__(self, owner):
        self._owner = owner

    @property
    def robot_pose(self):
        return self._owner.robot_pose()

    @property
    def odometry_pose(self):
        return self._owner.odometry_pose.copy()

    @property
    def cube(self):
        return self._owner.display_cube()

    def state(self):
        return self._owner.discrete_state()


@dataclass
class _Episode:
    """One stretch of hand-cube contact, from first touch to rest after release."""

    start_state: tuple
    start_pose: np.ndarray
    start_mid: np.ndarray                      # hands' midpoint (base frame) at first touch
    touched: set = field(default_factory=set)
    grasped: bool = False                      # both hands on the cube at the same tick
    max_cube_rise: float = 0.0
    max_hand_rise: float = 0.0                 # of the midpoint while grasped
    max_back: float = 0.0                      # towards the robot while grasped
    last_touch_ns: int = 0


class MujocoWorld(CommandInputs):
    """Robot (base + 13 joints) and ARcube on MuJoCo, advanced by `step()`.

    `cube`: anything with `position` (centre, world), `rotation` (body -> world),
    `heavy_face` (None or body face 0..5) and `edge` (m), e.g. the node's configured
    cube or a `mujoco_scene.CubeSpec`; `face_tags`: tag ids on body faces +x -x +y -y +z -z;
    `robot_pose`: the true base pose (x, y, yaw) at the start (odometry starts there too).
    `more_cubes`: (cube, face_tags) of further cubes (free bodies; a contact episode is
    with the cube a hand touches first, the *active* cube).
    """

    def __init__(self, cube, face_tags=(0, 1, 2, 3, 4, 5), settings=None,
                 kinematics=None, start_time_ns=0, robot_pose=(0.0, 0.0, 0.0),
                 distractors=(), more_cubes=()):
        self.settings = s = settings or MujocoSettings()
        self.kin = kin = kinematics if kinematics is not None else RobotKinematics()
        self.period_ns = s.period_ns
        self.dt = self.period_ns * 1e-9
        self.substeps = max(1, int(np.ceil(self.dt * s.physics_rate - 1e-9)))
        self.time_ns = int(start_time_ns)
        self.cube_specs = [CubeSpec(
            position=c.position, rotation=c.rotation, face_tags=tuple(tags),
            edge=c.edge, tag_edge=s.tag_edge, mass=s.cube_mass, heavy_face=c.heavy_face,
            heavy_mass_ratio=s.heavy_mass_ratio, friction=s.cube_friction * s.friction_scale,
            dictionary=s.tag_dictionary) for c, tags in [(cube, face_tags), *more_cubes]]
        self.cube_spec = self.cube_specs[0]
        self.scene_settings = SceneSettings(
            timestep=self.dt / self.substeps,
            hand_friction=s.hand_friction * s.friction_scale,
            hand_torsional_friction=s.hand_torsional_friction * s.friction_scale,
            floor_friction=s.floor_friction * s.friction_scale,
            servo_stiffness_scale=s.servo_stiffness_scale, shadows=s.shadows,
            offsamples=s.offsamples, width=s.width, height=s.height)
        profile = kin.profile
        self.model, self.spec = build_model(self.cube_spec, self.scene_settings, distractors,
                                            profile, self.cube_specs[1:])
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.joint_names = kin.joint_names
        self._qadr = np.array([m.joint(n).qposadr[0] for n in kin.joint_names])
        self._vadr = np.array([m.joint(n).dofadr[0] for n in kin.joint_names])
        wheels = profile.base.wheel_joints
        self._wheel_idx = np.array([kin.joint_index(n) for n in wheels], dtype=int)
        servo_names = [n for n in kin.joint_names if n not in wheels]
        self._servo_idx = np.array([kin.joint_index(n) for n in servo_names])
        self._servo_act = np.array([m.actuator(n).id for n in servo_names])
        # Position servo: force = kp (ctrl - q) - kv qd; ctrl = q* + (kv / kp) qd* tracks qd*.
        self._lead = -m.actuator_biasprm[self._servo_act, 2] / m.actuator_gainprm[
            self._servo_act, 0]
        self._base_qadr = np.array([m.joint(n).qposadr[0] for n in BASE_JOINTS])
        self._base_vadr = np.array([m.joint(n).dofadr[0] for n in BASE_JOINTS])
        self._base_act = np.array([m.actuator(n).id for n in BASE_JOINTS])
        self._cube_body = m.body(CUBE_BODY).id
        self._cube_qadr = m.joint(m.body(CUBE_BODY).jntadr[0]).qposadr[0]
        self._cube_geom = m.geom(CUBE_GEOM).id
        hands = hand_bodies(profile)
        self._hand_body = {side: m.body(body).id for side, body in hands.items()}
        self._hand_geom = {side: m.geom(body + HAND_GEOM_SUFFIX).id
                           for side, body in hands.items()}
        self._optical_body = m.body(profile.frames.camera_optical).id
        prefixes = [cube_prefix(i) for i in range(len(self.cube_specs))]
        self._cube_bodies = [m.body(p).id for p in prefixes]
        self._cube_geoms = [m.geom(f'{p}_box').id for p in prefixes]
        self._face_geoms = np.array([[m.geom(f'{p}_face_{f}').id for f in range(6)]
                                     for p in prefixes])
        self._active = 0   # the cube of the contact episode (the last one touched)
        self.heavy_face = cube.heavy_face
        self.edge = cube.edge

        q0 = s.initial_positions
        q0 = kin.neutral() if len(q0) == 0 else np.asarray(q0, dtype=float)
        if q0.shape != (kin.nq,):
            raise ValueError(f'initial_positions must give {kin.nq} joint positions, '
                             f'got {len(q0)}')
        if not kin.within_limits(q0, tol=1e-6):
            raise ValueError('initial_positions outside the joint limits')
        self._vmax = np.where(np.isfinite(kin.velocity_limits) & (kin.velocity_limits > 0),
                              kin.velocity_limits, np.inf)
        self._grasp_opening = s.grasp_opening
        self._offsets = self._set_point_offsets()
        d = self.data
        d.qpos[self._qadr] = q0
        d.qpos[self._base_qadr] = robot_pose
        self.q = q0 - self._offsets
        self.qd = np.zeros(kin.nq)
        self._desired = q0.copy()
        d.ctrl[self._servo_act] = q0[self._servo_idx] + self._offsets[self._servo_idx]
        mujoco.mj_forward(m, d)
        self.controllers = {}
        for name, joints in profile.controller_joints.items():
            idx = np.array([kin.joint_index(j) for j in joints])
            follower = TrajectoryFollower(joints, kin.lower_limits[idx], kin.upper_limits[idx])
            follower.hold(q0[idx])
            self.controllers[name] = (follower, idx)
        self.wheel_radius, self.wheel_track = _wheel_geometry(kin)
        self.odometry_pose = np.asarray(robot_pose, dtype=float).copy()
        # Odometry = this SE(2) transform o true base pose (identity until an error).
        self._odom_from_world = np.zeros(3)
        self._twist_cmd = np.zeros(2)   # rate-limited (v, w)
        self.twist = (0.0, 0.0)         # measured (v, w), what /odom reports
        self._moving = False
        self.rng = np.random.default_rng(s.seed)
        self.manual_actions = 0
        self.last_outcome = ''
        self.events = []                # (time_ns, ContactEvent), oldest first
        self._episode = None
        self._release_ns = None
        self.world = _WorldView(self)
        self._renderer = None
        self._render_data = None

    def _set_point_offsets(self):
        s, kin = self.settings, self.kin
        offsets = np.zeros(kin.nq)
        if len(s.joint_offsets):
            offsets += np.asarray(s.joint_offsets, dtype=float)
        if self._grasp_opening:
            # The profile names the joints that open the hands, in rad per m outwards.
            for joint, gain in kin.profile.grasp_opening_joints.items():
                offsets[kin.joint_index(joint)] += gain * self._grasp_opening
        return offsets

    def set_grasp_opening(self, opening):
        """Hold each hand `opening` m outwards of its commanded path from now on (a fault
        drawn per manual action; settings.grasp_opening is the start value)."""
        self._grasp_opening = float(opening)
        self._offsets = self._set_point_offsets()

    @property
    def grasp_opening(self):
        return self._grasp_opening

    # -- the tick -----------------------------------------------------------------------
    def step(self):
        """Advance one period; returns the ContactEvents of this tick."""
        s, m, d = self.settings, self.model, self.data
        dt = self.dt
        t_next_ns = self.time_ns + self.period_ns
        # Base command: held for cmd_vel_timeout, then rate-limited to the base limits.
        target = np.zeros(2)
        if self.cmd is not None and \
                self.time_ns - self.cmd_time_ns < s.cmd_vel_timeout * 1e9 - 1:
            target = np.array(self.cmd)
        vmax = np.array([s.max_linear_velocity, s.max_angular_velocity])
        amax = np.array([s.max_linear_acceleration, s.max_angular_acceleration]) * dt
        target = np.clip(target, -vmax, vmax)
        twist = self._twist_cmd + np.clip(target - self._twist_cmd, -amax, amax)
        # Joints: desired positions at the end of the tick, within the velocity limits.
        prev = self._desired
        desired = prev.copy()
        for follower, idx in self.controllers.values():
            desired[idx] = follower.sample(t_next_ns * 1e-9, self.q[idx])
        max_step = self._vmax * dt
        desired = prev + np.clip(desired - prev, -max_step, max_step)
        desired = np.clip(desired, self.kin.lower_limits, self.kin.upper_limits)
        velocity = (desired - prev) / dt
        servo = self._servo_idx
        lead = self._lead * velocity[servo] + self._offsets[servo]
        n = self.substeps
        fractions = np.arange(1, n + 1) / n
        servo_ctrl = prev[servo] + np.outer(fractions, (desired - prev)[servo]) + lead
        twists = self._twist_cmd + np.outer(fractions, twist - self._twist_cmd)
        base_moves = bool(np.any(twists != 0))
        yaw_adr, base_act, servo_act = self._base_qadr[2], self._base_act, self._servo_act
        for k in range(n):
            if base_moves:
                v, w = twists[k]
                yaw = d.qpos[yaw_adr]
                d.ctrl[base_act] = (v * np.cos(yaw), v * np.sin(yaw), w)
            d.ctrl[servo_act] = servo_ctrl[k]
            mujoco.mj_step(m, d)
        self._twist_cmd = twist
        self._desired = desired
        self.time_ns = t_next_ns
        measured = self._measured_twist()
        self.twist = (float(measured[0]), float(measured[1]))
        self.odometry_pose = se2_compose(self._odom_from_world, self.robot_pose())
        # Joint states: servo joints from MuJoCo, wheels from the measured twist. The set
        # point offsets (joint_offsets, a drawn grasp opening) are calibration errors: the
        # joint's own encoder is off by the same amount, so the robot reads its command
        # back while the hand is elsewhere (otherwise every later skill aborts on arrival).
        q_prev = self.q
        self.q = d.qpos[self._qadr] - self._offsets
        self.qd = d.qvel[self._vadr].copy()
        wheel_rates = np.array([measured[0] - measured[1] * self.wheel_track / 2,
                                measured[0] + measured[1] * self.wheel_track / 2])
        wheel_rates /= self.wheel_radius
        self.q[self._wheel_idx] = q_prev[self._wheel_idx] + wheel_rates * dt
        self.qd[self._wheel_idx] = wheel_rates
        moving = bool(np.any(target != 0) or np.any(twist != 0))
        if self._moving and not moving:
            self._odometry_error()
        self._moving = moving
        return self._track_contacts()

    def _measured_twist(self):
        d = self.data
        xd, yd, wd = d.qvel[self._base_vadr]
        yaw = d.qpos[self._base_qadr[2]]
        return np.array([xd * np.cos(yaw) + yd * np.sin(yaw), wd])

    def _odometry_error(self):
        sigma_m, sigma_rad = self.settings.orbit_odometry_noise
        if sigma_m <= 0 and sigma_rad <= 0:
            return
        rng = self.rng
        err = np.array([rng.normal(0.0, sigma_m) if sigma_m > 0 else 0.0,
                        rng.normal(0.0, sigma_m) if sigma_m > 0 else 0.0,
                        rng.normal(0.0, sigma_rad) if sigma_rad > 0 else 0.0])
        self.data.qpos[self._base_qadr] += err
        mujoco.mj_forward(self.model, self.data)
        # Odometry stays where it was: the error is what it did not see.
        self._odom_from_world = se2_compose(
            self.odometry_pose, se2_between(self.robot_pose(), np.zeros(3)))
        self.events.append((self.time_ns, ContactEvent(
            '', 'odometry error', f'dx {err[0]:+.3f} m, dy {err[1]:+.3f} m, '
            f'dyaw {np.degrees(err[2]):+.1f} deg')))

    # -- manual actions recognised from the contacts --------------------------------------
    def hands_touching(self, index=None):
        """The sides whose hand ball touches cube `index` (None: the active cube) now."""
        d = self.data
        ncon = d.ncon
        if ncon == 0:
            return set()
        geoms = d.contact.geom[:ncon]
        cube = self._cube_geoms[self._active if index is None else index]
        with_cube = np.any(geoms == cube, axis=1)
        return {side for side, g in self._hand_geom.items()
                if np.any(with_cube & np.any(geoms == g, axis=1))}

    def _hands_mid_in_base(self):
        """The middle of the hands (of the one hand of a one-armed robot), in the base frame."""
        mid = np.mean(list(self.hand_positions().values()), axis=0)
        x, y, yaw = self.robot_pose()
        c, s = np.cos(yaw), np.sin(yaw)
        rel = mid - np.array([x, y, 0.0])
        return np.array([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]])

    def _track_contacts(self):
        s = self.settings
        touching = self.hands_touching()
        now = self.time_ns
        ep = self._episode
        if ep is None and not touching and len(self._cube_bodies) > 1:
            # Out of an episode: the next one is with whichever cube a hand touches.
            for index in range(len(self._cube_bodies)):
                if self.hands_touching(index):
                    self._active, touching = index, self.hands_touching(index)
                    break
        if ep is None:
            if not touching:
                return []
            ep = self._episode = _Episode(self.discrete_state(), self.cube_pose(),
                                          self._hands_mid_in_base())
        if touching:
            ep.touched |= touching
            ep.last_touch_ns = now
            self._release_ns = None
        pose = self.cube_pose()
        ep.max_cube_rise = max(ep.max_cube_rise, pose[2, 3] - ep.start_pose[2, 3])
        if len(touching) == 2:
            if not ep.grasped:
                ep.grasped, ep.start_mid = True, self._hands_mid_in_base()
            move = self._hands_mid_in_base() - ep.start_mid
            ep.max_hand_rise = max(ep.max_hand_rise, move[2])
            ep.max_back = max(ep.max_back, -move[0])  # towards the robot: -x in base_link
        if touching or (now - ep.last_touch_ns) < s.release_time * 1e9:
            return []
        vel = self.data.qvel[self._cube_dofs()]
        waited = (now - ep.last_touch_ns) * 1e-9
        if (np.linalg.norm(vel[:3]) > 0.01 or np.linalg.norm(vel[3:]) > 0.1) and \
                waited < s.settle_timeout:
            return []
        event = self._classify(ep)
        self._episode = None
        self.events.append((now, event))
        if event.is_action:
            self.manual_actions += 1
        self.last_outcome = str(event)
        return [event]

    def _cube_dofs(self):
        adr = self.model.body_dofadr[self._cube_bodies[self._active]]
        return np.arange(adr, adr + 6)

    def _classify(self, ep):
        s = self.settings
        end_state = self.discrete_state()
        end_pose = self.cube_pose()
        moved = float(np.linalg.norm(end_pose[:2, 3] - ep.start_pose[:2, 3]))
        states = f'state {8 * ep.start_state[0] + ep.start_state[1]} -> ' \
                 f'{8 * end_state[0] + end_state[1]}, moved {moved * 100:.1f} cm'
        if ep.grasped and ep.max_hand_rise >= s.grasp_raise:
            action = 'FLIP' if ep.max_back >= s.flip_back else 'LIFT'
            if ep.max_cube_rise < 0.01:
                effect = 'slipped'
            else:
                effect = 'unchanged' if end_state == ep.start_state else 'rotated'
            detail = f'raised {ep.max_cube_rise * 100:.1f} cm, {states}'
            return ContactEvent(action, effect, detail)
        if ep.grasped:
            return ContactEvent('', 'grasp released', states)
        if end_state == ep.start_state:
            effect = 'slid' if moved > 0.01 else 'unchanged'
        elif end_state[0] == ep.start_state[0]:
            effect = 'pivoted'
        else:
            effect = 'rotated'
        hand = '/'.join(sorted(ep.touched))
        return ContactEvent('PUSH', effect, f'{hand} hand, {states}')

    # -- state for the publishers -----------------------------------------------------
    def robot_pose(self):
        """True base pose (x, y, yaw) in the world."""
        x, y, yaw = self.data.qpos[self._base_qadr]
        return np.array([x, y, wrap_rad(yaw)])

    def base_in_odom(self):
        return self.odometry_pose.copy()

    def odometry_twist(self):
        return self.twist

    def hand_positions(self):
        return {side: self.data.xpos[b].copy() for side, b in self._hand_body.items()}

    def camera_pose(self):
        """World pose of camera_optical_frame (z forward, x right, y down)."""
        out = np.eye(4)
        out[:3, :3] = self.data.xmat[self._optical_body].reshape(3, 3)
        out[:3, 3] = self.data.xpos[self._optical_body]
        return out

    def cube_pose(self, index=None):
        """4x4 world pose of cube `index`'s body frame (continuous ground truth; None: the
        active cube, the only one of a one-cube scene)."""
        body = self._cube_bodies[self._active if index is None else index]
        out = np.eye(4)
        out[:3, :3] = self.data.xmat[body].reshape(3, 3)
        out[:3, 3] = self.data.xpos[body]
        return out

    def display_cube(self, index=0):
        """Cube `index`'s pose and hidden mass, for the ground-truth message."""
        pose, spec = self.cube_pose(index), self.cube_specs[index]
        return CubeState(pose[:3, 3], pose[:3, :3], spec.heavy_face, spec.edge,
                         spec.mass_offset)

    def discrete_state(self, index=None):
        """(up, yaw) of cube `index` (None: the active one) relative to the true base."""
        return discrete_state(self.cube_pose(index), self.robot_pose())

    # -- camera -------------------------------------------------------------------------
    def snapshot(self):
        """Copy of the state a frame needs (render it later, e.g. in another thread)."""
        return self.data.qpos.copy()

    def render(self, qpos=None, encoding='rgb8', blank_faces=()):
        """Head camera image (HxWx3 uint8 RGB, or BGR / mono8) of the current state or of
        a `snapshot()`; the tags of `blank_faces` are not drawn (a missed tag: the face
        shows blank): body faces of the first cube, or (cube, face) pairs. The first call
        creates the GL context in the calling thread; call it from one thread only."""
        if self._renderer is None:
            s, intr = self.settings, camera_intrinsics()
            try:
                self._renderer = mujoco.Renderer(self.model, s.height or intr.height,
                                                 s.width or intr.width)
            except Exception as error:  # noqa: BLE001 -- any GL failure means the same
                raise RuntimeError(f'{EGL_HINT} ({type(error).__name__}: {error})') from None
            self._render_data = mujoco.MjData(self.model)
        data = self.data
        if qpos is not None:
            data = self._render_data
            data.qpos[:] = qpos
            mujoco.mj_kinematics(self.model, data)
            mujoco.mj_camlight(self.model, data)
        self._renderer.update_scene(data, camera=CAMERA_NAME)
        if len(blank_faces):
            self._blank(data, blank_faces)
        return rendered_as(self._renderer.render(), encoding)

    def _blank(self, data, faces):
        """Sink the tag quads of `faces` into the cube (its white box face then hides them)."""
        pairs = [(0, f) if np.isscalar(f) else tuple(f) for f in faces]
        hidden = {int(self._face_geoms[c, f]): self._cube_bodies[c] for c, f in pairs}
        scene = self._renderer.scene
        for i in range(scene.ngeom):
            geom = scene.geoms[i]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and geom.objid in hidden:
                centre = data.xpos[hidden[geom.objid]]
                geom.pos[:] = centre + 0.5 * (geom.pos - centre)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _wheel_geometry(kin):
    """(radius, track) of the profile's wheel joints (left, right): the axle height above
    the base frame on the floor, and the wheels' distance apart."""
    model = kin.model
    left_joint, right_joint = kin.profile.base.wheel_joints
    left = model.jointPlacements[model.getJointId(left_joint)].translation
    right = model.jointPlacements[model.getJointId(right_joint)].translation
    return float(left[2]), float(abs(left[1] - right[1]))


__all__ = ['ContactEvent', 'CubeState', 'EGL_HINT', 'MujocoSettings', 'MujocoWorld',
           'discrete_state', 'draw_contact_fault']
