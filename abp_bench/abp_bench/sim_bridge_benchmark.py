"""Benchmark of the sim bridge: render time per frame (in-process, the node's renderer
settings, the head camera's view of the cube), time per simulation tick, and the running
node's actual publish rates at several speed-ups, measured over DDS.

    sim_bridge_benchmark [--seconds 8] [--speedups 1 10] [--encodings mono8]

It starts the installed `sim_bridge` executable on an isolated ROS domain (localhost
only) for each configuration and prints a Markdown table.
"""

import argparse
import os
import random
import signal
import subprocess
import sys
import time

import numpy as np


def _render_time(encoding, noise_bank=8, frames=100):
    from abp_description import camera_intrinsics
    from abp_description.frames import rot_z
    from abp_description.kinematics import RobotKinematics, look_at_world
    from abp_sim_bridge.flat_renderer import ArcubeRenderer, ImageEffects
    from abp_sim_bridge.rules_physics import Cube

    kin = RobotKinematics()
    intr = camera_intrinsics()
    renderer = ArcubeRenderer(intr.K, intr.width, intr.height, encoding=encoding,
                              effects=ImageEffects(1.0, 0.5, 1.0), supersample=4,
                              noise_bank=noise_bank)
    times = []
    for k in range(frames):
        cube = Cube.on_floor(0.40 + 0.3 * (k % 3), 0.0, rot_z(np.radians(7 * k)))
        q, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), cube.position)
        cam = kin.camera_pose(q)
        t0 = time.perf_counter()
        renderer.render(cam, cube.pose(), (0, 1, 2, 3, 4, 5))
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times[1:]))


def _tick_time(ticks=2000):
    from abp_sim_bridge.rules_physics import Cube, World
    from abp_sim_bridge.rules_world import RulesWorld

    sim = RulesWorld(World(Cube.on_floor(0.4, 0.0), np.zeros(3)))
    sim.set_cmd_vel(0.1, 0.2)
    t0 = time.perf_counter()
    for i in range(ticks):
        if i % 20 == 0:
            sim.set_cmd_vel(0.1, 0.2)
        sim.step()
    return 1e3 * (time.perf_counter() - t0) / ticks


def _executable():
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix('abp_sim_bridge'), 'lib', 'abp_sim_bridge',
                        'sim_bridge')


def _measure_node(speedup, encoding, seconds, camera_rate):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Image, JointState

    from abp_common import names, qos

    proc = subprocess.Popen(
        [_executable(), '--ros-args', '-p', f'speedup:={float(speedup)}', '-p',
         f'camera_encoding:={encoding}', '-p', f'camera_rate:={float(camera_rate)}'],
        stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True)
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('sim_bridge_benchmark', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got = {'clock': [], 'joint_states': [], 'image': []}
    reliable = qos.reliable(1000)

    def stamp_of(msg):
        s = msg.clock if isinstance(msg, Clock) else msg.header.stamp
        return s.sec + s.nanosec * 1e-9

    def collect(name):
        return lambda msg: got[name].append((time.monotonic(), stamp_of(msg)))
    node.create_subscription(Clock, names.CLOCK, collect('clock'), reliable)
    node.create_subscription(JointState, names.JOINT_STATES, collect('joint_states'), reliable)
    node.create_subscription(Image, names.IMAGE, collect('image'), qos.SENSOR_DATA)
    try:
        deadline = time.monotonic() + 30
        while not got['clock'] and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        if not got['clock']:
            raise RuntimeError('the sim_bridge node did not start')
        end = time.monotonic() + 1.0  # settle
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
        for v in got.values():
            v.clear()
        t0 = time.monotonic()
        while time.monotonic() < t0 + seconds:
            executor.spin_once(timeout_sec=0.01)
        wall = time.monotonic() - t0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    clock = np.array([s for _, s in got['clock']])
    sim = float(clock[-1] - clock[0]) if len(clock) > 1 else 0.0
    images = np.array([s for _, s in got['image']])
    produced = (int(round((images[-1] - images[0]) * camera_rate)) + 1
                if len(images) > 1 else len(images))
    return {
        'speedup': speedup, 'encoding': encoding, 'camera_rate': camera_rate,
        'rtf': sim / wall,
        'joint_wall_hz': len(got['joint_states']) / wall,
        'joint_sim_hz': len(got['joint_states']) / sim if sim else 0.0,
        'image_wall_hz': len(images) / wall,
        'image_sim_hz': len(images) / sim if sim else 0.0,
        'image_received': f'{len(images)}/{produced}',
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=8.0, help='wall time per run')
    parser.add_argument('--speedups', type=float, nargs='+', default=[1.0, 10.0])
    parser.add_argument('--encodings', nargs='+', default=['mono8'])
    parser.add_argument('--camera-rate', type=float, default=10.0)
    parser.add_argument('--no-node', action='store_true', help='only the in-process timings')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randrange(1, 102)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)

    import cv2
    cv2.setNumThreads(1)
    print(f'in-process, one thread: simulation tick {_tick_time():.3f} ms '
          '(base + joints + FK + contacts, no publishing)')
    for enc in args.encodings:
        for bank in (8, 0):
            print(f'in-process, one thread: render 640x480 {enc} (supersample 4, blur 0.5, '
                  f'noise 1.0 {"from a bank of 8 frames" if bank else "fresh"}, head camera '
                  f'on the cube): median {_render_time(enc, bank):.2f} ms/frame')
    if args.no_node:
        return 0
    print()
    print('| speedup | encoding | camera Hz (sim) | sim/wall achieved | joint_states Hz wall '
          '| joint_states Hz sim | images Hz wall | images Hz sim | images received |')
    print('|---|---|---|---|---|---|---|---|---|')
    for enc in args.encodings:
        for speedup in args.speedups:
            r = _measure_node(speedup, enc, args.seconds, args.camera_rate)
            print(f"| {r['speedup']:g} | {r['encoding']} | {r['camera_rate']:g} | "
                  f"{r['rtf']:.2f} | {r['joint_wall_hz']:.0f} | {r['joint_sim_hz']:.1f} | "
                  f"{r['image_wall_hz']:.1f} | {r['image_sim_hz']:.1f} | "
                  f"{r['image_received']} |", flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
