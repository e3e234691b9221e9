"""The rules world: the simulated robot and ARcube, stepped at a fixed rate of simulation
time, with manual actions decided by contact rules (plain NumPy + Pinocchio, no rclpy);
one of the worlds the sim_bridge node wraps.

Each `step()` advances the simulation clock by one period 1/rate:

1. **Base** (diff drive): the last /cmd_vel (v, w) is applied while it is younger than
   `cmd_vel_timeout` (sim time), else the base stops. The true base pose and the odometry
   pose integrate the same twist exactly (arcs). Odometry noise
   (`orbit_odometry_noise` = (sigma_m, sigma_rad)): each base motion (from the first
   non-zero twist until the base stops) ends with the *true* pose displaced by
   N(0, sigma_m^2) in x and y and N(0, sigma_rad^2) in yaw; /odom does not see it.
   The wheel joints turn with the odometry twist (radius and track from the URDF).
2. **Joints**: each controller's `TrajectoryFollower` gives the desired positions; the
   joints move towards them at no more than their URDF velocity limits (so a feasible
   trajectory is tracked exactly) and stay within the position limits.
3. **Contacts**: the hand-ball centres (Pinocchio FK over the joints, placed by the true
   base pose) go to the `ContactTracker`, which calls rules_physics.

The base does not collide with the cube, and the arms and hands touch the cube only
through the contact rules (no collision otherwise).

Several cubes (num_cubes > 1): the contact rules act on one cube at a time, the *active*
one in `world.cube`; between contact episodes (no grasp, both hands well away from it)
the active cube becomes the one nearest the hands, so a manual action acts on the cube
the hands reach. The cubes do not touch each other (they stand `cube_spacing` apart).
"""

from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from abp_description.frames import base_to_world, integrate_twist, wrap_rad
from abp_description.kinematics import RobotKinematics, look_at_world

from .joint_trajectory_follower import TrajectoryFollower
from .rules_contact import ContactParams, ContactTracker
from .rules_physics import Physics, World, discrete_state
from .world_interface import CommandInputs, ContactEvent

# Hands farther than this from the active cube's centre are out of contact with it (its
# contact reach is under 0.15 m for a 10 cm cube): another cube may become the active one.
ACTIVE_CUBE_RELEASE_M = 0.2


@dataclass
class SimSettings:
    rate: float = 50.0                       # Hz of simulation time
    cmd_vel_timeout: float = 0.5             # s of simulation time
    orbit_odometry_noise: tuple = (0.0, 0.0)  # (m, rad) per base motion
    initial_positions: tuple = ()            # 13 joint positions, () = all zero (neutral)
    contact: ContactParams = field(default_factory=ContactParams)

    def __post_init__(self):
        if not (np.isfinite(self.rate) and 0 < self.rate <= 10000):
            raise ValueError(f'rate must be in (0, 10000] Hz, got {self.rate}')
        if not (np.isfinite(self.cmd_vel_timeout) and self.cmd_vel_timeout > 0):
            raise ValueError(f'cmd_vel_timeout must be > 0 s, got {self.cmd_vel_timeout}')
        noise = tuple(float(v) for v in self.orbit_odometry_noise)
        if len(noise) != 2 or min(noise) < 0 or not np.all(np.isfinite(noise)):
            raise ValueError('orbit_odometry_noise must be [sigma_m, sigma_rad], both >= 0, '
                             f'got {list(self.orbit_odometry_noise)}')
        self.orbit_odometry_noise = noise

    @property
    def period_ns(self):
        return int(round(1e9 / self.rate))


class RulesWorld(CommandInputs):
    """Robot (joints + base) and ARcube world, advanced by `step()`."""

    def __init__(self, world: World, settings=None, kinematics=None, start_time_ns=0,
                 other_cubes=()):
        self.settings = settings or SimSettings()
        # Every cube of the scene; world.cube is cubes[self.active], the one in contact.
        self.cubes = [world.cube, *other_cubes]
        self.active = 0
        self.kin = kinematics if kinematics is not None else RobotKinematics()
        self.world = world
        self.period_ns = self.settings.period_ns
        self.dt = self.period_ns * 1e-9
        self.time_ns = int(start_time_ns)
        kin = self.kin
        self.joint_names = kin.joint_names
        q0 = self.settings.initial_positions
        if len(q0) == 0:
            q0 = kin.neutral()
        if len(q0) != kin.nq:
            raise ValueError(f'initial_positions must give {kin.nq} joint positions '
                             f'({", ".join(kin.joint_names)}), got {len(q0)}')
        q0 = np.asarray(q0, dtype=float)
        if not kin.within_limits(q0, tol=1e-6):
            bad = [n for n, v, lo, hi in zip(kin.joint_names, q0, kin.lower_limits,
                                             kin.upper_limits) if not lo - 1e-6 <= v <= hi + 1e-6]
            raise ValueError(f'initial_positions outside the joint limits: {bad}')
        self.q = q0.copy()
        self.qd = np.zeros(kin.nq)
        self._lower, self._upper = kin.lower_limits, kin.upper_limits
        self._vmax = np.where(np.isfinite(kin.velocity_limits) & (kin.velocity_limits > 0),
                              kin.velocity_limits, np.inf)
        self.controllers = {}
        for name, joints in kin.profile.controller_joints.items():
            idx = np.array([kin.joint_index(j) for j in joints])
            follower = TrajectoryFollower(joints, kin.lower_limits[idx], kin.upper_limits[idx])
            follower.hold(self.q[idx])
            self.controllers[name] = (follower, idx)
        self._wheel_idx = np.array([kin.joint_index(j) for j in kin.profile.base.wheel_joints],
                                   dtype=int)
        self._hand_fids = {s: kin.model.getFrameId(f) for s, f in kin.profile.hand_frames.items()}
        self.wheel_radius, self.wheel_track = self._wheel_geometry()
        self.twist = (0.0, 0.0)    # applied (odometry) twist
        self._moving = False
        self.contacts = ContactTracker(self.settings.contact, kin.profile.sides)
        self.manual_actions = 0
        self.last_outcome = ''
        self.events = []           # (time_ns, ContactEvent) of this world, oldest first
        self.hands = self._hand_positions()

    # -- geometry ---------------------------------------------------------------------
    def _wheel_geometry(self):
        model = self.kin.model
        left_joint, right_joint = self.kin.profile.base.wheel_joints
        left = model.jointPlacements[model.getJointId(left_joint)].translation
        right = model.jointPlacements[model.getJointId(right_joint)].translation
        # The base frame is on the floor under the axle: the axle height is the wheel radius.
        return float(left[2]), float(abs(left[1] - right[1]))

    def _hand_positions(self):
        kin = self.kin
        pin.framesForwardKinematics(kin.model, kin.data, kin.to_pinocchio(self.q))
        x, y, yaw = self.world.robot_pose
        c, s = np.cos(yaw), np.sin(yaw)
        out = {}
        for side, fid in self._hand_fids.items():
            p = kin.data.oMf[fid].translation
            out[side] = np.array([x + c * p[0] - s * p[1], y + s * p[0] + c * p[1], p[2]])
        return out

    def camera_pose(self):
        """World (odom) pose of the camera optical frame from FK and the true base pose."""
        return base_to_world(self.world.robot_pose) @ self.kin.camera_pose(self.q)

    # -- commands ---------------------------------------------------------------------

    # -- the tick -----------------------------------------------------------------------
    def step(self):
        """Advance one period; returns the ContactEvents of this tick."""
        dt = self.dt
        t_next_ns = self.time_ns + self.period_ns
        t_next = t_next_ns * 1e-9
        # Base.
        v = w = 0.0
        # A command drives the base for cmd_vel_timeout after its receipt, then it stops.
        if self.cmd is not None and \
                self.time_ns - self.cmd_time_ns < self.settings.cmd_vel_timeout * 1e9 - 1:
            v, w = self.cmd
        world = self.world
        world.robot_pose = integrate_twist(world.robot_pose, v, w, dt)
        world.odometry_pose = integrate_twist(world.odometry_pose, v, w, dt)
        moving = v != 0.0 or w != 0.0
        if self._moving and not moving:
            self._odometry_error()
        self._moving = moving
        self.twist = (v, w)
        # Joints: towards the controllers' desired positions, within the velocity limits.
        q_prev = self.q.copy()
        desired = q_prev.copy()
        for follower, idx in self.controllers.values():
            desired[idx] = follower.sample(t_next, q_prev[idx])
        max_step = self._vmax * dt
        step = np.minimum(np.maximum(desired - q_prev, -max_step), max_step)
        self.q = np.minimum(np.maximum(q_prev + step, self._lower), self._upper)
        wheel_rates = np.array([v - w * self.wheel_track / 2, v + w * self.wheel_track / 2])
        wheel_rates /= self.wheel_radius
        self.q[self._wheel_idx] += wheel_rates * dt
        self.qd = (self.q - q_prev) / dt
        self.qd[self._wheel_idx] = wheel_rates
        self.time_ns = t_next_ns
        # Contacts.
        self.hands = self._hand_positions()
        if len(self.cubes) > 1:
            self._choose_active_cube()
        events = self.contacts.update(world, self.hands, world.robot_pose)
        for event in events:
            self.events.append((self.time_ns, event))
            if event.is_action:
                self.manual_actions += 1
            self.last_outcome = str(event)
        return events

    def _choose_active_cube(self):
        """Between contact episodes, hand the contact rules the cube nearest the hands."""
        if self.contacts.grasp is not None:
            return
        self.cubes[self.active] = self.world.cube
        hands = np.array(list(self.hands.values()))
        distance = [float(np.min(np.linalg.norm(hands - c.position, axis=1)))
                    for c in self.cubes]
        nearest = int(np.argmin(distance))
        if nearest != self.active and distance[self.active] > ACTIVE_CUBE_RELEASE_M:
            self.active = nearest
            self.world.cube = self.cubes[nearest]
            self.contacts.reset()

    def _odometry_error(self):
        sigma_m, sigma_rad = self.settings.orbit_odometry_noise
        if sigma_m <= 0 and sigma_rad <= 0:
            return
        rng = self.world.rng
        err = np.array([rng.normal(0.0, sigma_m) if sigma_m > 0 else 0.0,
                        rng.normal(0.0, sigma_m) if sigma_m > 0 else 0.0,
                        rng.normal(0.0, sigma_rad) if sigma_rad > 0 else 0.0])
        pose = self.world.robot_pose
        self.world.robot_pose = np.array([pose[0] + err[0], pose[1] + err[1],
                                          wrap_rad(pose[2] + err[2])])
        self.events.append((self.time_ns, ContactEvent(
            '', 'odometry error', f'dx {err[0]:+.3f} m, dy {err[1]:+.3f} m, '
            f'dyaw {np.degrees(err[2]):+.1f} deg')))

    # -- state for the publishers -----------------------------------------------------
    def display_cube(self, index=0):
        """Cube `index` of the scene as drawn (carried by the hands during a grasp)."""
        if index == self.active:
            return self.contacts.display_cube(self.world)
        return self.cubes[index]

    def display_cubes(self):
        return [self.display_cube(i) for i in range(len(self.cubes))]

    def discrete_state(self, index=0):
        """(up, yaw) of resting cube `index` relative to the true base (MODEL.md)."""
        cube = self.world.cube if index == self.active else self.cubes[index]
        return discrete_state(cube, self.world.robot_pose)

    def odometry_twist(self):
        return self.twist

    def base_in_odom(self):
        return self.world.odometry_pose.copy()


def make_rules_world(config, kin, start_time_ns=0):
    """The rules world a sim_bridge configuration (`config.build`) describes: the base at
    the odom origin facing +x and, when `look_at_cube` is set and no initial_positions are
    given, the head aimed at the cube."""
    settings = config.settings
    if not settings.initial_positions and config.look_at_cube:
        q0, _ = look_at_world(kin, kin.neutral(), np.zeros(3), config.look_at_point)
        settings = replace(settings, initial_positions=tuple(q0))
    world = World(config.cube, np.zeros(3), config.failures, Physics(),
                  seed=config.failure_seed)
    return RulesWorld(world, settings, kin, start_time_ns, other_cubes=config.cubes[1:])


__all__ = ['RulesWorld', 'SimSettings', 'make_rules_world']
