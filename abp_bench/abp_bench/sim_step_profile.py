"""`graph_profile sim-step`: the sim bridge's tick, profiled without ROS (plain Python).

    python -m abp_bench.graph_profile sim-step [--world mujoco|rules] [--ticks 500]
        [--camera-rate 10] [--top 15]

Builds the world and camera as the sim_bridge node does (abp_sim_bridge.config defaults,
`worlds.make_world`), drives the base in a slow turn, and times apart what one tick of the
node's simulation thread does (the physics step; copying joint states and odometry out;
the camera snapshot) and what its render thread does (one render per camera period),
then prints the top cProfile entries over all the ticks.
"""

import argparse
import cProfile
import io
import pstats
import statistics
import sys
import time


def build(world):
    from abp_description import camera_intrinsics
    from abp_description.kinematics import RobotKinematics
    from abp_sim_bridge import config as cfg
    from abp_sim_bridge.worlds import make_world

    values = {spec.name: spec.default for spec in cfg.PARAMETERS}
    values['world'] = world
    config = cfg.build(values)
    sim, camera = make_world(config, RobotKinematics(), camera_intrinsics(), 0)
    return config, sim, camera


def run(world, ticks, camera_rate):
    config, sim, camera = build(world)
    every = max(1, round(config.settings.rate / camera_rate)) if camera_rate > 0 else 0
    parts = {'physics step': [], 'joint state + odometry copy': [], 'camera snapshot': [],
             'render (render thread)': []}
    sim.set_cmd_vel(0.05, 0.2)
    camera.render(camera.capture(sim, tuple(config.hidden.face_tags)))  # GL context, caches
    profile = cProfile.Profile()
    profile.enable()
    for k in range(ticks):
        if k % 10 == 0:
            sim.set_cmd_vel(0.05, 0.2)       # within cmd_vel_timeout
        t0 = time.perf_counter()
        sim.step()
        t1 = time.perf_counter()
        sim.q.tolist()
        sim.qd.tolist()
        _ = sim.world.odometry_pose, sim.twist
        t2 = time.perf_counter()
        parts['physics step'].append(t1 - t0)
        parts['joint state + odometry copy'].append(t2 - t1)
        if every and k % every == 0:
            snap = camera.capture(sim, tuple(config.hidden.face_tags))
            t3 = time.perf_counter()
            camera.render(snap)
            t4 = time.perf_counter()
            parts['camera snapshot'].append(t3 - t2)
            parts['render (render thread)'].append(t4 - t3)
    profile.disable()
    camera.close()
    return config, parts, profile


def markdown(world, config, parts, ticks):
    tick_s = 1.0 / config.settings.rate
    lines = [f'**sim bridge tick, {world} world: {config.settings.rate:g} Hz ticks, '
             f'{ticks} ticks**', '', '| part | median ms | mean ms | calls |', '|---|---|---|---|']
    for name, times in parts.items():
        if times:
            lines.append(f'| {name} | {1e3 * statistics.median(times):.3f} | '
                         f'{1e3 * statistics.fmean(times):.3f} | {len(times)} |')
    sim_cost = sum(statistics.fmean(parts[p]) for p in ('physics step',
                                                         'joint state + odometry copy'))
    lines += ['', f'simulation thread alone: {tick_s / sim_cost:.1f}x real time at most '
              '(one core, no ROS publishing)']
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='graph_profile sim-step',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--world', choices=('mujoco', 'rules'), default='mujoco')
    parser.add_argument('--ticks', type=int, default=500)
    parser.add_argument('--camera-rate', type=float, default=10.0,
                        help='renders per simulated second (0: none)')
    parser.add_argument('--top', type=int, default=15, help='cProfile entries shown')
    args = parser.parse_args(argv)
    config, parts, profile = run(args.world, args.ticks, args.camera_rate)
    print(markdown(args.world, config, parts, args.ticks))
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats('tottime').print_stats(args.top)
    print('\n```\n' + out.getvalue().strip() + '\n```')
    return 0


if __name__ == '__main__':
    sys.exit(main())
