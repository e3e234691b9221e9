"""Benchmark of the MuJoCo world (no rclpy): physics real-time factor on one core, render
frames per second with the arms in view, and what shadows, resolution and anti-aliasing cost.

    MUJOCO_GL=egl python -m abp_sim_bridge.bench_mujoco [--repeats 5]

Goals (issue 12): physics >= 20x real time for robot + cube; >= 30 frames/s at 640x480.
Medians over `--repeats` runs are printed (the machine is shared: single runs are noisy).
"""

import argparse
import time

import numpy as np

from abp_belief.cube import R_UP
from abp_description.kinematics import RobotKinematics, look_at_world

from .joint_trajectory_follower import TrajectoryPoint
from .mujoco_scene import CubeSpec
from .mujoco_world import MujocoSettings, MujocoWorld

CUBE_XY = (0.40, 0.0)
# Torso half down, arms raised forward (the skills' "ready" posture): hands in the image.
READY = {'torso_pitch_joint': 0.3,
         'left_shoulder_pitch_joint': -0.9, 'left_shoulder_roll_joint': 0.25,
         'left_elbow_joint': -1.0,
         'right_shoulder_pitch_joint': -0.9, 'right_shoulder_roll_joint': -0.25,
         'right_elbow_joint': -1.0}


def arms_in_view(kin, iterations=100):
    """Hands open beside the cube (as before a grasp), head on the cube: damped
    least-squares IK over the torso and arms from the ready posture."""
    q = kin.q_from_mapping(READY)
    joints = [kin.joint_index(n) for n in READY] + [
        kin.joint_index(f'{s}_upper_arm_yaw_joint') for s in ('left', 'right')]
    targets = {'left': np.array([CUBE_XY[0], 0.14, 0.10]),
               'right': np.array([CUBE_XY[0], -0.14, 0.10])}
    for _ in range(iterations):
        err = np.concatenate([t - kin.hand_pose(q, s)[:3, 3] for s, t in targets.items()])
        jac = np.vstack([kin.frame_jacobian(q, f'{s}_hand_link')[:3, joints]
                         for s in targets])
        step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-3 * np.eye(6), err)
        q[joints] += np.clip(step, -0.2, 0.2)
        q = kin.clip(q)
    q, _ = look_at_world(kin, q, (0.0, 0.0, 0.0), (*CUBE_XY, 0.05))
    return q


def make_world(kin, heavy_face=4, **settings):
    cube = CubeSpec(position=(*CUBE_XY, 0.05), rotation=R_UP[4], heavy_face=heavy_face)
    return MujocoWorld(cube, (0, 1, 2, 3, 4, 5),
                       MujocoSettings(initial_positions=tuple(arms_in_view(kin)), **settings),
                       kin)


def physics_real_time_factor(kin, sim_seconds=4.0):
    """Sim time / wall time of `MujocoWorld.step` (50 Hz ticks, 500 Hz physics) while the
    arms swing and the base turns (robot + cube, contacts with the floor)."""
    world = make_world(kin)
    arm = ('left_shoulder_pitch_joint', 'left_shoulder_roll_joint', 'left_upper_arm_yaw_joint',
           'left_elbow_joint')
    q = world.q[[kin.joint_index(j) for j in arm]]
    swing = [TrajectoryPoint(t, q + 0.3 * np.sin(t) * np.array([1.0, 0.5, 0.5, 1.0]))
             for t in np.arange(0.5, sim_seconds + 0.5, 0.5)]
    world.set_trajectory('left_arm_controller', list(arm), swing)
    ticks = int(round(sim_seconds / world.dt))
    start = time.perf_counter()
    for k in range(ticks):
        if k % 10 == 0:
            world.set_cmd_vel(0.0, 0.3)
        world.step()
    return sim_seconds / (time.perf_counter() - start)


def render_fps(kin, width=640, height=480, shadows=False, offsamples=0, frames=30):
    world = make_world(kin, width=width, height=height, shadows=shadows,
                       offsamples=offsamples)
    world.render()  # GL context, textures upload
    start = time.perf_counter()
    for _ in range(frames):
        world.render()
    fps = frames / (time.perf_counter() - start)
    world.close()
    return fps


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args(argv)
    kin = RobotKinematics()
    rtf = [physics_real_time_factor(kin) for _ in range(args.repeats)]
    print(f'physics real-time factor (robot + cube, 500 Hz, one core): median '
          f'{np.median(rtf):.1f}x  (runs: {", ".join(f"{r:.1f}" for r in rtf)}; goal >= 20x)')
    fps = [render_fps(kin) for _ in range(args.repeats)]
    print(f'render 640x480, arms in view, no shadows, no multisampling: median '
          f'{np.median(fps):.1f} frames/s (goal >= 30)')
    print('\n| shadows | multisampling | resolution | frames/s (median) | ms/frame |')
    print('|---|---|---|---|---|')
    for shadows, offsamples, (w, h) in ((False, 0, (320, 240)), (False, 0, (640, 480)),
                                        (False, 0, (1280, 960)), (False, 4, (640, 480)),
                                        (True, 0, (640, 480)), (True, 4, (640, 480))):
        frames = 5 if shadows else 20
        runs = [render_fps(kin, w, h, shadows, offsamples, frames) for _ in range(3)]
        med = float(np.median(runs))
        print(f'| {"on" if shadows else "off"} | {offsamples} | {w}x{h} | {med:.1f} | '
              f'{1000 / med:.1f} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
