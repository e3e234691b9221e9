"""Which world the sim_bridge node runs, and its camera (plain Python, no rclpy).

`make_world(config, kin, intrinsics, start_time_ns)` returns `(world, camera)` for the
configuration's `world` parameter:

- **rules**: `rules_world.RulesWorld` (contact rules) and `FlatCamera` (flat_renderer's
  ArcubeRenderer): fast, for tests.
- **mujoco**: `FaultyMujocoWorld` (mujoco_world.MujocoWorld with the fault parameters
  turned into physical perturbations, see below) and `MujocoCamera` (MuJoCo's offscreen
  renderer through EGL).

A camera takes a `capture(world, tags)` of the state in the simulation thread (tags: the
face tags of each cube in this frame, -1 = a missed tag, scenario.drawn_tags) and
`render(snapshot)`s it later in the render thread; `close()` frees it (in the render
thread: the MuJoCo renderer's GL context lives in the thread that rendered first).

MuJoCo faults are drawn per manual action: afresh for every arm motion that starts out of
contact (the trajectories of one skill phase, stamped together), never during a contact:
with probability `p_slip_grasp` each hand is held `slip_grasp_opening` further outwards
(the skills squeeze 5 mm: the grasp slips or holds on nothing); with probability
`p_missed_push` each hand is held `missed_push_offset` further outwards (a push passes
beside the cube, a grasp closes on nothing). `p_push_neighbour` has no physical
counterpart (a push pivots the way the contact makes it).
"""

import numpy as np

from abp_description.kinematics import look_at_world

from .flat_renderer import ArcubeRenderer, tag_dictionary
from .rules_world import make_rules_world


def per_cube(tags):
    """Face tags per cube: a flat tuple of six ids (a one-cube scene) as one cube's."""
    return (tuple(tags),) if len(tags) and np.isscalar(tags[0]) else tuple(tags)


def initial_positions(config, kin):
    """The 13 joint positions the world starts with: initial_positions, or the head aimed
    at the cube (look_at_cube), or all zero."""
    q0 = config.settings.initial_positions
    if q0:
        return tuple(q0)
    if config.look_at_cube:
        q, _ = look_at_world(kin, kin.neutral(), np.zeros(3), config.look_at_point)
        return tuple(q)
    return tuple(kin.neutral())


class FlatCamera:
    """The rules world's camera: flat_renderer's ArcubeRenderer."""

    def __init__(self, config, intrinsics):
        cam = config.camera
        self.renderer = ArcubeRenderer(
            intrinsics.K, intrinsics.width, intrinsics.height, edge=cam.cube_size,
            tag_edge=cam.tag_size, dictionary=tag_dictionary(cam.dictionary)[0],
            encoding=cam.encoding, effects=cam.effects,
            supersample=cam.supersample, seed=config.failure_seed, noise_bank=cam.noise_bank)
        self.encoding = cam.encoding
        self.distractors = config.distractors

    def capture(self, world, tags):
        """`tags`: the drawn face tags of each cube (one tuple per cube of the scene)."""
        cubes = [c.pose() for c in world.display_cubes()]
        return world.camera_pose(), cubes, per_cube(tags)

    def render(self, snapshot):
        camera_pose, cube_poses, tags = snapshot
        return self.renderer.render(camera_pose, cube_poses[0], tags[0],
                                    distractors=self.distractors,
                                    more_cubes=list(zip(cube_poses[1:], tags[1:])))

    def close(self):
        pass


class MujocoCamera:
    """The MuJoCo world's head camera (arms and hands in view, can hide tags)."""

    def __init__(self, world, encoding):
        self.world = world
        self.encoding = encoding

    def capture(self, world, tags):
        """`tags`: the drawn face tags of each cube (one tuple per cube of the scene)."""
        blank = tuple((cube, face) for cube, faces in enumerate(per_cube(tags))
                      for face, tag in enumerate(faces) if tag < 0)
        return world.snapshot(), blank

    def render(self, snapshot):
        qpos, blank = snapshot
        return self.world.render(qpos, encoding=self.encoding, blank_faces=blank)

    def close(self):
        self.world.close()


def check_rendering():
    """Raise ValueError (a configuration error: one line with the fix) when MuJoCo cannot
    render offscreen here (no EGL, or a bad MUJOCO_GL)."""
    try:
        from .mujoco_world import EGL_HINT
    except Exception as error:  # noqa: BLE001 -- e.g. MUJOCO_GL invalid: import fails
        raise ValueError(f'cannot load MuJoCo: {error}') from None
    try:
        import mujoco
        model = mujoco.MjModel.from_xml_string('<mujoco/>')
        renderer = mujoco.Renderer(model, 16, 16)
        renderer.close()
    except Exception as error:  # noqa: BLE001 -- any GL failure means the same
        raise ValueError(f'{EGL_HINT} ({type(error).__name__}: {error})') from None


def mujoco_world_class():
    from .mujoco_world import MujocoWorld, draw_contact_fault

    class FaultyMujocoWorld(MujocoWorld):
        """MujocoWorld whose grasp opening is drawn afresh for every arm motion that
        starts out of contact (one draw per set of trajectories stamped together), so each
        manual skill meets the fault probabilities anew. Drawn only after a contact, as it
        was, a missed push (hands 10 cm out, so no contact) stayed drawn for the rest of
        the episode: every later manual action missed the cube and reported success, which
        reads as "no change" (graph_benchmark --faults, episode_trace)."""

        def __init__(self, *args, faults=None, fault_seed=0, **kw):
            super().__init__(*args, **kw)
            self._faults = faults
            self._base_opening = self.settings.grasp_opening
            self._fault_rng = np.random.default_rng([int(fault_seed), 12])
            self._drawn_for_stamp = None
            self._draw_faults()

        def _draw_faults(self):
            f = self._faults
            if f is None or (f.p_slip_grasp <= 0 and f.p_missed_push <= 0):
                return
            extra, what = draw_contact_fault(self._fault_rng, f.p_slip_grasp, f.p_missed_push,
                                             f.slip_grasp_opening, f.missed_push_offset)
            self.set_grasp_opening(self._base_opening + extra)
            if extra:
                from .world_interface import ContactEvent
                self.events.append((self.time_ns, ContactEvent(
                    '', 'fault drawn', f'next contact: {what}, hands {extra * 100:.1f} cm '
                    'further out')))

        def set_trajectory(self, controller, joint_names, points, stamp_s=0.0):
            # Never while a contact episode is open: the hands would jump mid-grasp.
            arms = {arm.controller for arm in self.kin.profile.arms.values()}
            if controller in arms and self._episode is None and \
                    stamp_s != self._drawn_for_stamp:
                self._drawn_for_stamp = stamp_s
                self._draw_faults()
            return super().set_trajectory(controller, joint_names, points, stamp_s)

    return FaultyMujocoWorld


class _Faults:
    def __init__(self, failures, mujoco):
        self.p_slip_grasp = failures.p_slip_grasp
        self.p_missed_push = failures.p_missed_push
        self.slip_grasp_opening = mujoco.slip_grasp_opening
        self.missed_push_offset = mujoco.missed_push_offset


def make_mujoco_world(config, kin, start_time_ns=0):
    from .mujoco_world import MujocoSettings
    m, s = config.mujoco, config.settings
    settings = MujocoSettings(
        rate=s.rate, physics_rate=m.physics_rate, cmd_vel_timeout=s.cmd_vel_timeout,
        orbit_odometry_noise=s.orbit_odometry_noise,
        initial_positions=initial_positions(config, kin), cube_mass=m.cube_mass,
        heavy_mass_ratio=m.heavy_mass_ratio, cube_friction=m.cube_friction,
        floor_friction=m.floor_friction, hand_friction=m.hand_friction,
        hand_torsional_friction=m.hand_torsional_friction, tag_edge=config.camera.tag_size,
        tag_dictionary=config.camera.dictionary,
        friction_scale=m.friction_scale, servo_stiffness_scale=m.servo_stiffness_scale,
        grasp_opening=m.grasp_opening, joint_offsets=m.joint_offsets, shadows=m.shadows,
        offsamples=m.offsamples, seed=config.failure_seed)
    world_class = mujoco_world_class()
    return world_class(config.cube, config.hidden.face_tags, settings, kin, start_time_ns,
                       distractors=config.distractors,
                       more_cubes=[(c, h.face_tags) for c, h in zip(config.cubes[1:],
                                                                     config.hiddens[1:])],
                       faults=_Faults(config.failures, m), fault_seed=config.failure_seed)


def make_world(config, kin, intrinsics, start_time_ns=0):
    """(world, camera) of a sim_bridge configuration (config.build)."""
    if config.world == 'mujoco':
        world = make_mujoco_world(config, kin, start_time_ns)
        return world, MujocoCamera(world, config.camera.encoding)
    return make_rules_world(config, kin, start_time_ns), FlatCamera(config, intrinsics)


__all__ = ['FlatCamera', 'MujocoCamera', 'check_rendering', 'initial_positions', 'per_cube',
           'make_mujoco_world', 'make_world']
