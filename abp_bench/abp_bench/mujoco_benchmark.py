"""Benchmark of the MuJoCo world (issue 12): physics speed, camera cost and the tag
detector's recall on MuJoCo frames (plain Python, no rclpy).

    MUJOCO_GL=egl mujoco_benchmark [--physics-seconds 10] [--repeats 3] [--frames 20]
                                   [--scenes 240] [--seed 0] [--json FILE]

1. **Physics**: `MujocoWorld.step()` (the sim bridge's tick: 50 Hz ticks of 10 MuJoCo steps
   of 2 ms) for robot + cube with no camera, as sim seconds per wall second and per CPU
   second of this process (median over `--repeats`), in three scenarios: idle (arms
   folded, cube in front), driving (base /cmd_vel back and forth along arcs, both arms
   swinging) and the skills' LIFT plan (hands squeeze and raise the cube: hand-cube
   contacts). Also raw `mj_step` on the idle scene (no Python tick).
2. **Camera**: wall ms per frame of the head camera as the sim bridge renders it
   (`MujocoCamera`: a snapshot rendered later, mono8) in the skills' pre-grasp posture
   (LIFT plan, end of the approach phase: hands open beside the cube, both in view),
   for shadows on/off x multisampling 0/4 x 320x240, 640x480, 1280x960 (the vertical
   field of view is kept: K scales with the image). frames/s = 1000 / median ms.
3. **Tag recall**: random scenes (seeded): the robot at a random bearing around the cube
   (random up face and yaw), base turned up to 20 deg off the cube, head aimed at it by
   `look_at`, arms folded (torso pitched at random), raised (the skills' ready posture),
   at pre-grasp (the LIFT plan's) or one hand moved across the line of sight to the cube
   (random arm joints about the ready posture), at camera-to-cube distances stratified over
   0.5-2.0 m. Each frame goes through `abp_perception.detector.TagDetector` with the
   calibrated intrinsics. A tag counts as *visible* when its face turns at most
   `--max-view-angle` (70 deg) from the line of sight and its face lies inside the image,
   and as *unhidden* when MuJoCo rays (`mj_ray`, the rendered geom groups) between the
   camera and a 5 x 5 grid over the whole face (tag and quiet zone) meet no other geom.
   Recall and the median tag-centre position error are given per camera-to-tag distance.

Goals (issue 12): physics >= 20x real time on one core; >= 30 frames/s wall at 640x480
with the arms in view; the detector finds >= 99 % of the visible, unhidden tags within
1.5 m. The machine may be shared: the load average is printed at the start and the end.
"""

import argparse
import json
import os
import sys
import time

os.environ.setdefault('MUJOCO_GL', 'egl')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import numpy as np  # noqa: E402

from abp_belief.cube import R_UP  # noqa: E402
from abp_description.frames import rot_z  # noqa: E402
from abp_description.kinematics import RobotKinematics, look_at  # noqa: E402

NOMINAL_CENTRE = np.array([0.40, 0.0, 0.05])   # m, base_link: the benchmark's cube
RESOLUTIONS = ((320, 240), (640, 480), (1280, 960))
DISTANCE_EDGES = (0.5, 1.0, 1.5, 2.0)          # m, camera to tag centre
GOAL_RANGE = 1.5                               # m: the recall goal's tags
GOALS = {'physics_rtf': 20.0, 'camera_fps': 30.0, 'recall': 0.99}
GRID = 5                                       # rays per face side (occlusion test)
LIFT_SETTLE = 1.0                              # s after the LIFT plan
HAND_ACROSS = 'hand across view'


# -- helpers ----------------------------------------------------------------------------------

def load_average():
    try:
        return tuple(round(v, 2) for v in os.getloadavg())
    except OSError:
        return (float('nan'),) * 3


def scaled_intrinsics(width, height, model=None):
    """K of the MuJoCo head camera at `width` x `height`: the scene keeps the calibrated
    vertical field of view, square pixels and the principal point at the image centre."""
    from abp_description import camera_intrinsics
    intr = camera_intrinsics()
    fovy = 2 * np.arctan(intr.height / (2 * intr.fy))
    if model is not None:
        from abp_sim_bridge.mujoco_scene import CAMERA_NAME
        fovy = np.radians(float(model.cam_fovy[model.camera(CAMERA_NAME).id]))
    f = height / (2 * np.tan(fovy / 2))
    return np.array([[f, 0.0, width / 2 - 0.5], [0.0, f, height / 2 - 0.5], [0.0, 0.0, 1.0]])


def postures(kin):
    """Named robot postures (13 joints) for a cube at NOMINAL_CENTRE, head on the cube:
    'home' (arms folded), 'ready' (arms raised forward, torso half down), 'pre-grasp'
    (the LIFT plan at the end of its approach: hands open beside the cube) and
    HAND_ACROSS (ready; in the recall scenes one arm is then moved so that its hand lies
    across the line of sight, see hand_across_view). Also returns the LIFT plan."""
    from abp_skills.plans import SkillPlanner
    planner = SkillPlanner(kin)
    q_home = planner.home(kin.neutral(), look=NOMINAL_CENTRE)
    plan = planner.plan('lift', q_home, NOMINAL_CENTRE)
    if not plan.ok:
        raise RuntimeError(f'LIFT plan failed: {plan.reason}')
    body = [kin.joint_index(n) for n in kin.profile.body_joints]
    q_pre = q_home.copy()
    q_pre[body] = plan.phases[0].trajectory.positions[-1]
    q_ready = planner.ready(q_home, look=NOMINAL_CENTRE)
    return {'home': q_home, 'ready': q_ready, 'pre-grasp': q_pre, HAND_ACROSS: q_ready}, plan


def make_world(kin, q0, cube_yaw=0.0, **settings):
    from abp_bench.mujoco_skill_runner import make_world as runner_world
    return runner_world(kin, q0=q0, cube_yaw=cube_yaw, **settings)


def _median(values):
    return float(np.median(values)) if len(values) else float('nan')


# -- 1. physics -------------------------------------------------------------------------------

def _swing(world, kin, sim_seconds, amplitude=0.3, period=4.0):
    """Both arms swing sinusoidally about their start positions for `sim_seconds`."""
    from abp_sim_bridge.joint_trajectory_follower import TrajectoryPoint
    times = np.arange(0.25, sim_seconds + 0.5, 0.25)
    for arm in kin.profile.arms.values():
        controller = arm.controller
        joints = arm.joints
        q = world.q[[kin.joint_index(j) for j in joints]]
        shape = np.array([1.0, 0.4, 0.5, 0.8])
        points = [TrajectoryPoint(t, q + amplitude * np.sin(2 * np.pi * t / period) * shape)
                  for t in times]
        world.set_trajectory(controller, list(joints), points)


def drive_command(t, speed=0.3, turn=0.6, period=4.0):
    """Base command at sim time t: backwards along an arc, then forwards back."""
    sign = -1.0 if (t % period) < period / 2 else 1.0
    return sign * speed, -sign * turn


def physics_run(kin, scenario, sim_seconds, q_home, plan=None):
    """One run of `scenario` ('idle', 'drive', 'lift'): sim seconds, wall and CPU seconds
    of MujocoWorld.step(), mean contacts per tick and the manual actions recognised."""
    from abp_bench.mujoco_skill_runner import send_plan
    world = make_world(kin, q_home)
    if scenario == 'lift':
        sim_seconds = send_plan(world, plan) + LIFT_SETTLE
    elif scenario == 'drive':
        _swing(world, kin, sim_seconds)
    elif scenario != 'idle':
        raise ValueError(f'unknown scenario {scenario!r}')
    ticks = max(1, int(np.ceil(sim_seconds / world.dt - 1e-9)))
    contacts = 0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for k in range(ticks):
        if scenario == 'drive':
            world.set_cmd_vel(*drive_command(k * world.dt))
        world.step()
        contacts += world.data.ncon
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    actions = [str(e) for _, e in world.events if e.is_action]
    return {'scenario': scenario, 'sim_s': ticks * world.dt, 'wall_s': wall, 'cpu_s': cpu,
            'contacts_per_tick': contacts / ticks, 'actions': actions,
            'timestep_s': float(world.model.opt.timestep), 'substeps': world.substeps,
            'tick_rate_hz': world.settings.rate,
            'physics_rate_hz': world.substeps * world.settings.rate}


def raw_step_run(kin, sim_seconds, q_home):
    """mj_step alone (no Python tick) on the idle scene: the engine's own speed."""
    from abp_sim_bridge.mujoco_scene import mujoco
    world = make_world(kin, q_home)
    m, d = world.model, world.data
    steps = max(1, int(round(sim_seconds / m.opt.timestep)))
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        mujoco.mj_step(m, d)
    return {'scenario': 'raw mj_step (idle)', 'sim_s': steps * m.opt.timestep,
            'wall_s': time.perf_counter() - wall0, 'cpu_s': time.process_time() - cpu0,
            'contacts_per_tick': float(d.ncon), 'actions': []}


def physics_benchmark(kin, q_home, plan, sim_seconds=10.0, repeats=3):
    """{scenario: summary} with median real-time factors (sim s per wall s and per CPU s)."""
    scenarios = ('idle', 'drive', 'lift', 'raw')
    all_runs = {s: [] for s in scenarios}
    for _ in range(repeats):      # interleaved: a changing machine load hits all alike
        for scenario in scenarios:
            if scenario == 'raw':
                all_runs[scenario].append(raw_step_run(kin, sim_seconds, q_home))
            else:
                all_runs[scenario].append(physics_run(kin, scenario, sim_seconds, q_home,
                                                      plan))
    out = {}
    for scenario, runs in all_runs.items():
        rtf = [r['sim_s'] / r['wall_s'] for r in runs]
        rtf_cpu = [r['sim_s'] / max(r['cpu_s'], 1e-9) for r in runs]
        out[scenario] = {
            'name': runs[0]['scenario'], 'sim_s': runs[0]['sim_s'], 'repeats': repeats,
            'rtf_wall_median': _median(rtf), 'rtf_wall_runs': rtf,
            'rtf_cpu_median': _median(rtf_cpu),
            'contacts_per_tick': _median([r['contacts_per_tick'] for r in runs]),
            'actions': runs[0]['actions']}
        for key in ('timestep_s', 'substeps', 'tick_rate_hz', 'physics_rate_hz'):
            if key in runs[0]:
                out[scenario][key] = runs[0][key]
    return out


# -- 2. camera --------------------------------------------------------------------------------

def arms_in_view(world, q):
    """Fractions of the image showing the arms + hands and the cube (segmentation
    rendering of posture q at the world's camera resolution)."""
    from abp_sim_bridge.mujoco_scene import CAMERA_NAME, CUBE_BODY, mujoco
    m = world.model
    data = mujoco.MjData(m)
    data.qpos[:] = world.data.qpos
    data.qpos[world._qadr] = q
    mujoco.mj_kinematics(m, data)
    intr_h, intr_w = world.settings.height, world.settings.width
    if intr_h is None or intr_w is None:
        from abp_description import camera_intrinsics
        intr = camera_intrinsics()
        intr_h, intr_w = intr.height, intr.width
    renderer = mujoco.Renderer(m, intr_h, intr_w)
    try:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera=CAMERA_NAME)
        seg = renderer.render()
    finally:
        renderer.close()
    geom = np.where(seg[:, :, 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[:, :, 0], -1)
    body = np.where(geom >= 0, m.geom_bodyid[np.clip(geom, 0, None)], -1)
    arm_bodies = [i for i in range(m.nbody)
                  if any(k in m.body(i).name for k in ('shoulder', 'arm', 'hand'))]
    return {'arms': float(np.isin(body, arm_bodies).mean()),
            'cube': float((body == m.body(CUBE_BODY).id).mean())}


def gl_renderer_name():
    try:
        from OpenGL import GL
        name = GL.glGetString(GL.GL_RENDERER)
        return name.decode() if isinstance(name, bytes) else str(name)
    except Exception:  # noqa: BLE001 -- informative only
        return 'unknown'


def camera_benchmark(kin, q, frames=20, budget_s=60.0, resolutions=RESOLUTIONS,
                     shadows=(False, True), offsamples=(0, 4), encoding='mono8',
                     min_frames=3):
    """Per-frame wall and CPU ms of the sim bridge's camera path (snapshot, then render +
    read back + conversion to `encoding`) in posture q, for every combination of the
    settings. One world (and GL context) per setting, warmed up by two frames; then
    rounds of one frame per setting, so that a changing machine load hits every setting
    alike; stops after `frames` rounds, or after `budget_s` of wall time once
    `min_frames` rounds are done. CPU time counts all threads (Mesa's llvmpipe too)."""
    combos = [(sh, ms, w, h) for sh in shadows for ms in offsamples for w, h in resolutions]
    worlds, wall, cpu = [], [[] for _ in combos], [[] for _ in combos]
    gl = 'unknown'
    try:
        for sh, ms, w, h in combos:
            world = make_world(kin, q, width=w, height=h, shadows=sh, offsamples=ms)
            worlds.append(world)
            for _ in range(2):
                world.render(world.snapshot(), encoding=encoding)
            gl = gl_renderer_name()
        start = time.perf_counter()
        for k in range(max(frames, 1)):
            for i, world in enumerate(worlds):
                snapshot = world.snapshot()
                w0, c0 = time.perf_counter(), time.process_time()
                world.render(snapshot, encoding=encoding)
                wall[i].append(1e3 * (time.perf_counter() - w0))
                cpu[i].append(1e3 * (time.process_time() - c0))
            if k + 1 >= min_frames and time.perf_counter() - start > budget_s:
                break
    finally:
        for world in worlds:
            world.close()
    rows = []
    for (sh, ms, w, h), times, cpu_times in zip(combos, wall, cpu):
        med = _median(times)
        rows.append({'shadows': bool(sh), 'offsamples': int(ms), 'width': w, 'height': h,
                     'frames': len(times), 'ms_median': med,
                     'ms_min': float(np.min(times)), 'ms_p90': float(np.percentile(times, 90)),
                     'cpu_ms_median': _median(cpu_times), 'fps': 1e3 / med,
                     'gl_renderer': gl, 'encoding': encoding})
    return rows


# -- 3. tag recall ----------------------------------------------------------------------------

def _camera_distance(kin, q, cube_in_base):
    cam = kin.camera_pose(q)[:3, 3]
    return float(np.linalg.norm(cam - cube_in_base))


def place_robot(kin, q_posture, distance, bearing_in_base, tries=40, max_aim_error=0.02):
    """Joints (head aimed by look_at) and the cube's ground range from the base so that
    the camera is `distance` from the cube centre, the cube `bearing_in_base` rad off the
    base's x axis; None when the posture cannot get that close (or that far), or its head
    cannot aim at the cube there (within `max_aim_error` rad)."""
    def at(r):
        p = np.array([r * np.cos(bearing_in_base), r * np.sin(bearing_in_base),
                      NOMINAL_CENTRE[2]])
        q, aim_error = look_at(kin, q_posture, p)
        return q, p, _camera_distance(kin, q, p), aim_error

    cam_x = kin.camera_pose(q_posture)[0, 3]
    lo, hi = max(0.25, cam_x + 0.05), 4.0
    if at(lo)[2] > distance or at(hi)[2] < distance:
        return None
    for _ in range(tries):
        mid = 0.5 * (lo + hi)
        if at(mid)[2] < distance:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-3:
            break
    q, p, _, aim_error = at(0.5 * (lo + hi))
    if aim_error > max_aim_error:
        return None      # the head cannot aim at the cube from this posture (joint limits)
    return q, float(np.hypot(p[0], p[1]))


def hand_across_view(kin, q, cube_in_base, rng, tries=300, reach=0.09):
    """Arms of q moved at random about their posture until a hand lies between the camera
    and the cube, within `reach` of the line of sight (so it may hide part of the cube);
    q unchanged when no sample does. The camera does not move (arm joints only)."""
    cam = kin.camera_pose(q)[:3, 3]
    ray = cube_in_base - cam
    depth = float(np.linalg.norm(ray))
    ray /= depth
    spread = np.array([0.8, 0.4, 0.8, 0.8])     # pitch, roll, yaw, elbow (rad)
    for _ in range(tries):
        cand = q.copy()
        arms = kin.profile.sides
        sides = [arms[int(rng.integers(len(arms)))]]
        for side in sides:
            idx = [kin.joint_index(j) for j in kin.profile.arm_joints[side]]
            cand[idx] += rng.uniform(-1, 1, 4) * spread
        cand = kin.clip(cand)
        for side in sides:
            rel = kin.hand_pose(cand, side)[:3, 3] - cam
            along = float(rel @ ray)
            if 0.15 < along < depth - 0.1 and np.linalg.norm(rel - along * ray) < reach:
                return cand
    return q


class SceneMaker:
    """Random scenes in one MujocoWorld: qpos of robot and cube set directly (no physics)."""

    def __init__(self, kin, named_postures, width=640, height=480, seed=0,
                 cube_centre=(0.0, 0.0), dictionary='DICT_4X4_50'):
        from abp_sim_bridge.mujoco_scene import BASE_JOINTS, CUBE_BODY, mujoco
        self.mujoco = mujoco
        self.kin = kin
        self.postures = named_postures
        self.world = make_world(kin, named_postures['home'], width=width, height=height,
                                tag_dictionary=dictionary)
        m = self.world.model
        self.model = m
        self.width, self.height = width, height
        self.K = scaled_intrinsics(width, height, m)
        self.rng = np.random.default_rng(seed)
        self.centre = np.array([*cube_centre, NOMINAL_CENTRE[2]])
        self._base_qadr = np.array([m.joint(n).qposadr[0] for n in BASE_JOINTS])
        self._cube_body = m.body(CUBE_BODY).id
        self._cube_qadr = m.joint(m.body(CUBE_BODY).jntadr[0]).qposadr[0]
        self._optical = m.body(self.kin.profile.frames.camera_optical).id
        self.data = mujoco.MjData(m)
        self.edge = self.world.cube_spec.edge
        self.tag_edge = self.world.cube_spec.tag_edge

    def random_scene(self, distance):
        """qpos of a random scene with the camera `distance` from the cube centre, and
        its description; None if no posture reaches that distance."""
        rng, kin = self.rng, self.kin
        names = list(self.postures)
        bearing_in_base = rng.uniform(-np.radians(20), np.radians(20))
        for k in rng.permutation(len(names)):    # the first posture that can aim there
            name = names[k]
            q = self.postures[name].copy()
            if name == 'home':
                q[kin.joint_index(kin.profile.torso.joint)] = rng.uniform(0.0, 1.2)
            placed = place_robot(kin, q, distance, bearing_in_base)
            if placed is not None:
                break
        else:
            return None
        q, ground = placed
        if name == HAND_ACROSS:
            cube = ground * np.array([np.cos(bearing_in_base), np.sin(bearing_in_base), 0.0])
            cube[2] = NOMINAL_CENTRE[2]
            q = hand_across_view(kin, q, cube, rng)
        bearing = rng.uniform(0, 2 * np.pi)     # of the robot, around the cube
        up = int(rng.integers(6))
        cube_yaw = rng.uniform(0, 2 * np.pi)
        base_xy = self.centre[:2] + ground * np.array([np.cos(bearing), np.sin(bearing)])
        base_yaw = bearing + np.pi - bearing_in_base
        rotation = rot_z(cube_yaw) @ R_UP[up]
        qpos = self.world.data.qpos.copy()
        qpos[self._base_qadr] = (*base_xy, np.arctan2(np.sin(base_yaw), np.cos(base_yaw)))
        qpos[self.world._qadr] = q
        quat = np.zeros(4)
        self.mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation).ravel())
        qpos[self._cube_qadr:self._cube_qadr + 3] = self.centre
        qpos[self._cube_qadr + 3:self._cube_qadr + 7] = quat
        return qpos, {'posture': name, 'distance': distance, 'up': up,
                      'cube_yaw_deg': float(np.degrees(cube_yaw)),
                      'bearing_deg': float(np.degrees(bearing)),
                      'torso': float(q[kin.joint_index(kin.profile.torso.joint)])}

    def ground_truth(self, qpos, max_view_angle_deg=70.0, margin_px=2.0):
        """Per face: tag id, tag pose (world), camera distance, view angle, whether face
        and tag lie inside the image, and the hidden fraction of the face (rays)."""
        mujoco, m, d = self.mujoco, self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        cam_pos = d.xpos[self._optical].copy()
        cam_rot = d.xmat[self._optical].reshape(3, 3).copy()
        cube_pos = d.xpos[self._cube_body].copy()
        cube_rot = d.xmat[self._cube_body].reshape(3, 3).copy()
        from abp_sim_bridge.flat_renderer import FACE_TAG_AXES
        h, t = self.edge / 2, self.tag_edge / 2
        grid = np.linspace(-(h - 0.002), h - 0.002, GRID)
        groups = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)   # the rendered groups
        enclosing = self._enclosing(cam_pos, cam_rot)
        faces = []
        for face, tag_id in enumerate(self.world.cube_spec.face_tags):
            axes = cube_rot @ FACE_TAG_AXES[face]
            centre = cube_pos + axes[:, 2] * (h + 0.0003)
            to_cam = cam_pos - centre
            dist = float(np.linalg.norm(to_cam))
            angle = float(np.degrees(np.arccos(np.clip(axes[:, 2] @ to_cam / dist, -1, 1))))
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = axes, centre
            corners = {'face': np.array([[-h, h], [h, h], [h, -h], [-h, -h]]),
                       'tag': np.array([[-t, t], [t, t], [t, -t], [-t, -t]])}
            inside = {}
            for key, c2 in corners.items():
                pts = centre + c2 @ axes[:, :2].T
                pc = (pts - cam_pos) @ cam_rot
                ok = bool(np.all(pc[:, 2] > 0.02))
                if ok:
                    uv = (pc @ self.K.T)[:, :2] / pc[:, 2:3]
                    ok = bool(np.all((uv >= margin_px) & (uv <= np.array(
                        [self.width - 1 - margin_px, self.height - 1 - margin_px]))))
                inside[key] = ok
            hidden = float('nan')
            if angle < 90.0:
                gs, gt = np.meshgrid(grid, grid)
                pts = (centre + 0.001 * axes[:, 2] + gs.reshape(-1, 1) * axes[:, 0]
                       + gt.reshape(-1, 1) * axes[:, 1])
                hidden = float(np.mean([self._blocked(p, cam_pos, groups, enclosing)
                                        for p in pts]))
            faces.append({'face': face, 'tag_id': int(tag_id), 'pose': pose, 'distance': dist,
                          'view_angle_deg': angle, 'face_in_image': inside['face'],
                          'tag_in_image': inside['tag'], 'hidden': hidden,
                          'visible': bool(angle <= max_view_angle_deg and inside['face'])})
        camera = np.eye(4)
        camera[:3, :3], camera[:3, 3] = cam_rot, cam_pos
        return camera, faces

    def _enclosing(self, cam_pos, cam_rot):
        """Geoms the camera sits inside (its own camera_link box and the head's): drawn
        from inside, their back faces are culled, so they hide nothing. A convex geom
        contains the camera when rays both ways along the optical axis meet it."""
        m, d, mujoco = self.model, self.data, self.mujoco
        axis = cam_rot[:, 2].copy()
        inside = set()
        for g in np.flatnonzero((m.geom_group < 3) & (m.geom_type != mujoco.mjtGeom.mjGEOM_MESH)
                                & (m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE)):
            args = (d.geom_xpos[g], d.geom_xmat[g], m.geom_size[g], cam_pos)
            if mujoco.mju_rayGeom(*args, axis, m.geom_type[g]) >= 0 and \
                    mujoco.mju_rayGeom(*args, -axis, m.geom_type[g]) >= 0:
                inside.add(int(g))
        return inside

    def _blocked(self, point, cam_pos, groups, enclosing):
        """Whether a rendered geom other than the cube's (and the ones the camera sits
        in) lies between `point` and the camera: a ray from the point to the camera."""
        vec = cam_pos - point
        length = float(np.linalg.norm(vec))
        vec = vec / length
        geom = np.zeros(1, dtype=np.int32)
        start, travelled = point.copy(), 0.0
        for _ in range(8):
            hit = self.mujoco.mj_ray(self.model, self.data, start, vec, groups, 1,
                                     self._cube_body, geom)
            if hit < 0 or travelled + hit >= length - 1e-4:
                return False
            if int(geom[0]) not in enclosing:
                return True
            travelled += hit + 1e-4
            start = point + travelled * vec
        return False

    def render(self, qpos, encoding='mono8'):
        return self.world.render(qpos, encoding=encoding)

    def close(self):
        self.world.close()


def distance_bucket(distance, edges=DISTANCE_EDGES):
    if distance < edges[0]:
        return f'< {edges[0]:.1f}'
    for lo, hi in zip(edges[:-1], edges[1:]):
        if distance < hi:
            return f'{lo:.1f}-{hi:.1f}'
    return f'>= {edges[-1]:.1f}'


def recall_benchmark(kin, named_postures, scenes=240, seed=0, width=640, height=480,
                     max_view_angle_deg=70.0, edges=DISTANCE_EDGES, dictionary='DICT_4X4_50'):
    """Render `scenes` random scenes (camera-to-cube distance stratified over `edges`)
    of a cube whose tags are of the ArUco `dictionary`, detect them with that dictionary,
    and return one record per face plus per-frame render and detect times."""
    from abp_perception.detector import TagDetector
    maker = SceneMaker(kin, named_postures, width, height, seed, dictionary=dictionary)
    detector = TagDetector(maker.K, None, dictionary, maker.tag_edge)
    records, render_ms, detect_ms, skipped, wrong_ids, out_of_view = [], [], [], 0, 0, 0
    spans = list(zip(edges[:-1], edges[1:]))
    try:
        for i in range(scenes):
            lo, hi = spans[i % len(spans)]
            scene = maker.random_scene(maker.rng.uniform(lo, hi))
            if scene is None:
                skipped += 1
                continue
            qpos, info = scene
            t0 = time.perf_counter()
            gray = maker.render(qpos)
            t1 = time.perf_counter()
            result = detector.detect(gray)
            t2 = time.perf_counter()
            render_ms.append(1e3 * (t1 - t0))
            detect_ms.append(1e3 * (t2 - t1))
            camera, faces = maker.ground_truth(qpos, max_view_angle_deg)
            out_of_view += not any(f['tag_in_image'] and f['view_angle_deg'] < 90
                                   for f in faces)
            found = {}
            for det in result.detections:
                found.setdefault(det.tag_id, det)
            by_id = {f['tag_id']: f for f in faces}
            wrong_ids += sum(1 for tag in found if tag not in by_id or
                             by_id[tag]['view_angle_deg'] >= 90.0)
            for f in faces:
                det = found.get(f['tag_id'])
                rec = {k: v for k, v in f.items() if k != 'pose'}
                rec.update(scene=i, posture=info['posture'], up=info['up'],
                           found=det is not None, position_error=None, normal_error_deg=None,
                           side_px=None)
                if det is not None:
                    pose = camera @ det.pose
                    rec['position_error'] = float(np.linalg.norm(pose[:3, 3] - f['pose'][:3, 3]))
                    rec['normal_error_deg'] = float(np.degrees(np.arccos(np.clip(
                        pose[:3, 2] @ f['pose'][:3, 2], -1.0, 1.0))))
                    rec['side_px'] = float(det.side_px)
                records.append(rec)
    finally:
        maker.close()
    return {'records': records, 'render_ms_median': _median(render_ms),
            'detect_ms_median': _median(detect_ms), 'frames': len(render_ms),
            'skipped_scenes': skipped, 'cube_out_of_view': out_of_view,
            'wrong_ids': wrong_ids, 'width': width, 'height': height, 'dictionary': dictionary,
            'max_view_angle_deg': max_view_angle_deg, 'edges': list(edges)}


def summarise_recall(result):
    """Rows per distance bucket for the visible, unhidden tags (the goal's population),
    for visible but partly hidden tags, and for oblique ones; plus the goal row."""
    recs = result['records']
    edges = result['edges']
    max_angle = result['max_view_angle_deg']

    def row(label, sel):
        n = len(sel)
        hits = [r for r in sel if r['found']]
        err = [1e3 * r['position_error'] for r in hits]
        nerr = [r['normal_error_deg'] for r in hits]
        return {'bucket': label, 'tags': n, 'found': len(hits),
                'recall': len(hits) / n if n else float('nan'),
                'pos_err_mm_median': _median(err),
                'pos_err_mm_p90': float(np.percentile(err, 90)) if err else float('nan'),
                'normal_err_deg_median': _median(nerr)}

    def table(pred):
        sel = [r for r in recs if pred(r)]
        order = [distance_bucket(x, edges) for x in (0.0, *edges)]
        labels = sorted({distance_bucket(r['distance'], edges) for r in sel}, key=order.index)
        rows = [row(b, [r for r in sel if distance_bucket(r['distance'], edges) == b])
                for b in labels]
        goal = [r for r in sel if r['distance'] < GOAL_RANGE]
        rows.append(row(f'all < {GOAL_RANGE:.1f}', goal))
        rows.append(row('all', sel))
        return rows

    def unhidden(r):
        return r['visible'] and r['hidden'] == 0.0

    def partly_hidden(r):
        return r['visible'] and 0.0 < r['hidden'] < 1.0

    def oblique(r):
        return r['face_in_image'] and max_angle < r['view_angle_deg'] < 85.0 and \
            r['hidden'] == 0.0

    misses = [r for r in recs if unhidden(r) and not r['found'] and r['distance'] < GOAL_RANGE]
    goal = [r for r in recs if unhidden(r) and r['distance'] < GOAL_RANGE]
    by_posture = [row(name, [r for r in goal if r['posture'] == name])
                  for name in sorted({r['posture'] for r in recs})]
    return {'unhidden': table(unhidden), 'partly_hidden': table(partly_hidden),
            'unhidden_by_posture': by_posture,
            'oblique': table(oblique), 'misses_within_goal': misses,
            'fully_hidden_visible_faces': sum(1 for r in recs if r['visible'] and
                                              r['hidden'] == 1.0)}


# -- output -----------------------------------------------------------------------------------

def _fmt(v, spec='.1f'):
    return '-' if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def print_physics(phys, out=None):
    out = out or sys.stdout
    first = phys['idle']
    print(f'\n## Physics (no camera; MujocoWorld.step: {first["tick_rate_hz"]:.0f} Hz ticks x '
          f'{first["substeps"]} MuJoCo steps of {1e3 * first["timestep_s"]:.1f} ms = '
          f'{first["physics_rate_hz"]:.0f} Hz physics)\n', file=out)
    print('| scenario | sim s/run | runs | real-time factor, wall (median) | runs (wall) | '
          'real-time factor, CPU (median) | contacts/tick | manual actions |', file=out)
    print('|---|---|---|---|---|---|---|---|', file=out)
    labels = {'idle': 'idle (arms folded, cube in front)',
              'drive': 'driving (cmd_vel 0.3 m/s, 0.6 rad/s arcs) + both arms swinging',
              'lift': "skills' LIFT plan (approach, squeeze, raise, place, retreat)",
              'raw': 'raw mj_step, idle scene (no Python tick)'}
    for key, r in phys.items():
        runs = ', '.join(f'{v:.1f}' for v in r['rtf_wall_runs'])
        print(f'| {labels.get(key, key)} | {r["sim_s"]:.1f} | {r["repeats"]} | '
              f'{r["rtf_wall_median"]:.1f}x | {runs} | {r["rtf_cpu_median"]:.1f}x | '
              f'{r["contacts_per_tick"]:.1f} | {"; ".join(r["actions"]) or "-"} |', file=out)


def print_camera(cam, view, out=None):
    out = out or sys.stdout
    gl = cam[0]['gl_renderer'] if cam else 'unknown'
    print(f"\n## Camera (MujocoCamera path: snapshot -> render -> mono8; skills' pre-grasp "
          f'posture: arms {100 * view["arms"]:.0f} % and cube {100 * view["cube"]:.1f} % of '
          f'the 640x480 image; GL: {gl})\n', file=out)
    print('| shadows | offsamples | resolution | frames | ms/frame wall (median) | min | p90 | '
          'CPU ms/frame, all threads (median) | frames/s = 1000/median |', file=out)
    print('|---|---|---|---|---|---|---|---|---|', file=out)
    for r in cam:
        print(f'| {"on" if r["shadows"] else "off"} | {r["offsamples"]} | '
              f'{r["width"]}x{r["height"]} | {r["frames"]} | {r["ms_median"]:.1f} | '
              f'{r["ms_min"]:.1f} | {r["ms_p90"]:.1f} | {r["cpu_ms_median"]:.1f} | '
              f'{r["fps"]:.1f} |', file=out)


def print_recall(rec, summary, out=None):
    out = out or sys.stdout
    print(f'\n## Tag recall on MuJoCo frames ({rec["dictionary"]} tags, '
          f'{rec["width"]}x{rec["height"]}, '
          f'{rec["frames"]} frames, TagDetector with the scaled calibrated K; visible: face '
          f'within {rec["max_view_angle_deg"]:.0f} deg of the line of sight and inside the '
          f'image; unhidden: no ray to a {GRID}x{GRID} grid over the face blocked)\n',
          file=out)
    print(f'render {rec["render_ms_median"]:.1f} ms/frame, detect '
          f'{rec["detect_ms_median"]:.1f} ms/frame (medians); scenes no posture could '
          f'place: {rec["skipped_scenes"]}; frames with no tag in the image: '
          f'{rec["cube_out_of_view"]}; detections with ids not on a face turned to the '
          f'camera: {rec["wrong_ids"]}; visible faces fully hidden by the arms: '
          f'{summary["fully_hidden_visible_faces"]}\n', file=out)
    for key, title in (('unhidden', "visible, unhidden tags (the goal's population)"),
                       ('partly_hidden', 'visible tags partly hidden by the arms'),
                       ('oblique', f'oblique tags ({rec["max_view_angle_deg"]:.0f}-85 deg), '
                                   'unhidden')):
        print(f'{title}:\n', file=out)
        print('| camera-tag distance (m) | tags | found | recall | position error median '
              '(mm) | p90 (mm) | normal error median (deg) |', file=out)
        print('|---|---|---|---|---|---|---|', file=out)
        for r in summary[key]:
            recall = _fmt(100 * r['recall'] if r['tags'] else None, '.1f')
            print(f'| {r["bucket"]} | {r["tags"]} | {r["found"]} | {recall} % | '
                  f'{_fmt(r["pos_err_mm_median"])} | {_fmt(r["pos_err_mm_p90"])} | '
                  f'{_fmt(r["normal_err_deg_median"])} |', file=out)
        print('', file=out)
    print(f'visible, unhidden tags within {GOAL_RANGE} m by posture:\n', file=out)
    print('| posture | tags | found | recall | position error median (mm) |', file=out)
    print('|---|---|---|---|---|', file=out)
    for r in summary['unhidden_by_posture']:
        recall = _fmt(100 * r['recall'] if r['tags'] else None, '.1f')
        print(f'| {r["bucket"]} | {r["tags"]} | {r["found"]} | {recall} % | '
              f'{_fmt(r["pos_err_mm_median"])} |', file=out)
    print('', file=out)
    misses = summary['misses_within_goal']
    if misses:
        print(f'missed visible, unhidden tags within {GOAL_RANGE} m:\n', file=out)
        print('| scene | tag | distance (m) | view angle (deg) | posture | up face |', file=out)
        print('|---|---|---|---|---|---|', file=out)
        for r in misses[:20]:
            print(f'| {r["scene"]} | {r["tag_id"]} | {r["distance"]:.2f} | '
                  f'{r["view_angle_deg"]:.0f} | {r["posture"]} | {r["up"]} |', file=out)
        print('', file=out)


def print_goals(results, out=None):
    out = out or sys.stdout
    print('## Goals (issue 12)\n', file=out)
    phys = results.get('physics')
    if phys:
        worst = min(phys[k]['rtf_wall_median'] for k in ('idle', 'drive', 'lift'))
        worst_cpu = min(phys[k]['rtf_cpu_median'] for k in ('idle', 'drive', 'lift'))
        goal = GOALS['physics_rtf']
        print(f'- physics >= {goal:.0f}x real time on one core, slowest scenario: '
              f'{worst_cpu:.1f}x per CPU second of this process '
              f'({"met" if worst_cpu >= goal else "NOT met"}), {worst:.1f}x per wall second '
              f'at this machine load ({"met" if worst >= goal else "NOT met"})', file=out)
    cam = results.get('camera')
    if cam:
        base = [r for r in cam if (r['width'], r['height']) == (640, 480) and
                not r['shadows'] and r['offsamples'] == 0]
        if base:
            fps = base[0]['fps']
            ok = 'met' if fps >= GOALS['camera_fps'] else 'NOT met'
            print(f'- camera >= {GOALS["camera_fps"]:.0f} frames/s at 640x480, arms in view '
                  f'(no shadows, no multisampling, the sim bridge default): {fps:.1f}: {ok}',
                  file=out)
    summary = results.get('recall_summary')
    if summary:
        goal = [r for r in summary['unhidden'] if r['bucket'].startswith('all <')][0]
        if goal['tags']:
            ok = 'met' if goal['recall'] >= GOALS['recall'] else 'NOT met'
            print(f'- detector >= {100 * GOALS["recall"]:.0f} % of visible, unhidden tags '
                  f'within {GOAL_RANGE} m: {goal["found"]}/{goal["tags"]} = '
                  f'{100 * goal["recall"]:.1f} %: {ok}', file=out)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _parse_resolution(text):
    try:
        w, h = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected WIDTHxHEIGHT, got {text!r}') from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError('resolution too small')
    return w, h


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=' '.join(__doc__.split('\n\n')[0].split()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='\n'.join(__doc__.splitlines()[2:]))
    parser.add_argument('--physics-seconds', type=float, default=10.0,
                        help='sim seconds per idle / driving run (LIFT runs its plan)')
    parser.add_argument('--repeats', type=int, default=3, help='physics runs per scenario')
    parser.add_argument('--frames', type=int, default=20, help='timed frames per setting')
    parser.add_argument('--frame-budget', type=float, default=60.0,
                        help='wall s for all camera settings together (at least 3 frames '
                             'each)')
    parser.add_argument('--scenes', type=int, default=240, help='tag recall scenes')
    parser.add_argument('--resolution', type=_parse_resolution, default=(640, 480),
                        help='image size of the recall scenes, WIDTHxHEIGHT')
    parser.add_argument('--max-view-angle', type=float, default=70.0,
                        help='deg between a face normal and the line of sight for a tag to '
                             'count as visible')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--dictionary', default='DICT_4X4_50',
                        help="the cube's ArUco dictionary in the recall scenes (OpenCV name, "
                             'e.g. DICT_APRILTAG_36h11; default DICT_4X4_50)')
    parser.add_argument('--skip', nargs='*', default=(),
                        choices=('physics', 'camera', 'recall'), help='sections to skip')
    parser.add_argument('--cpu', type=int, default=None,
                        help='pin the process to this CPU (default: not pinned)')
    parser.add_argument('--json', metavar='FILE', help='also write the results as JSON')
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.frames < 1 or args.scenes < 0:
        parser.error('--repeats and --frames must be >= 1, --scenes >= 0')
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})

    import mujoco
    load_start = load_average()
    t_start = time.perf_counter()
    print('# MuJoCo world benchmark (issue 12)\n')
    print(f'mujoco {mujoco.__version__}, MUJOCO_GL={os.environ.get("MUJOCO_GL")}, '
          f'{os.cpu_count()} CPUs, pinned to {args.cpu if args.cpu is not None else "none"}; '
          f'load average at start (1/5/15 min): {load_start[0]} / {load_start[1]} / '
          f'{load_start[2]}')
    kin = RobotKinematics()
    named, plan = postures(kin)
    results = {'mujoco': mujoco.__version__, 'cpus': os.cpu_count(), 'seed': args.seed,
               'load_average_start': load_start, 'args': vars(args)}
    if 'physics' not in args.skip:
        results['physics'] = physics_benchmark(kin, named['home'], plan, args.physics_seconds,
                                               args.repeats)
        print_physics(results['physics'])
    if 'camera' not in args.skip:
        world = make_world(kin, named['pre-grasp'])
        try:
            view = arms_in_view(world, named['pre-grasp'])
        finally:
            world.close()
        results['camera_view'] = view
        results['camera'] = camera_benchmark(kin, named['pre-grasp'], args.frames,
                                             args.frame_budget)
        print_camera(results['camera'], view)
    if 'recall' not in args.skip and args.scenes > 0:
        width, height = args.resolution
        rec = recall_benchmark(kin, named, args.scenes, args.seed, width, height,
                               args.max_view_angle, dictionary=args.dictionary)
        summary = summarise_recall(rec)
        results['recall'] = {k: v for k, v in rec.items() if k != 'records'}
        results['recall_summary'] = summary
        results['recall_records'] = rec['records']
        print_recall(rec, summary)
    load_end = load_average()
    results['load_average_end'] = load_end
    results['wall_s'] = time.perf_counter() - t_start
    print()
    print_goals(results)
    print(f'\nload average at end (1/5/15 min): {load_end[0]} / {load_end[1]} / {load_end[2]}; '
          f'benchmark wall time {results["wall_s"]:.0f} s')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(_jsonable(results), stream, indent=1)
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
