"""`scene_loop_benchmark`: the Recognize tasks over several cubes in the closed loop over
DDS (issue 37): the real belief and planner nodes against the model-sampled world process
(tests/helpers/model_world_node.py, K cubes with track ids), on a domain of their own.

    python -m abp_bench.scene_loop_benchmark --scenes 5 --seed 0 --twins --json loop.json

Scene s is `planner_benchmark --objects K`'s scene s of the same seed (its models and its
find targets: `multi_object_benchmark.draw_scene`, robot set), so the figures compare
with `planner_benchmark --objects K --models robot --tables corrected --planners cost
--seed S --trials N` (same scenes, the nodes' tables and default planner; the noise
streams differ: the world draws its own). Per scene: identify_all, find (a cube's model)
and find (a model not in the scene), then with `--single` every cube alone with task ''
(the one-object closed loop) as the baseline. The nodes run with their defaults (planner
cost, planning budget 0.1 s per object decision, stop rule error 0.003).
"""

import argparse
import json
import os
import pathlib
import random
import statistics
import subprocess
import sys
import time

import rclpy
from ament_index_python.packages import get_package_prefix
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor

from abp_belief import population
from abp_common import qos
from abp_msgs.action import Recognize
from abp_msgs.msg import AspectObservation

from .graph_benchmark import terminate_with_parent
from .multi_object_benchmark import draw_scene

WORLD = pathlib.Path('tests/helpers/model_world_node.py')
TASKS = ('identify_all', 'find_present', 'find_absent')


def executable(package, name):
    return os.path.join(get_package_prefix(package), 'lib', package, name)


class Loop:
    """The nodes, the world of the current scene, and a Recognize client."""

    def __init__(self, args, log_dir):
        self.args = args
        self.log_dir = log_dir
        params = ['--ros-args', '-p', 'model_set:=robot', '-p', f'seed:={args.seed}']
        self.nodes = [self._start([executable('abp_belief', 'belief'), *params], 'belief'),
                      self._start([executable('abp_planner', 'planner'), *params], 'planner')]
        self.world = None
        self.node = rclpy.create_node('scene_loop_benchmark')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.client = ActionClient(self.node, Recognize, '/abp/recognize')
        self.observations = 0
        self.node.create_subscription(AspectObservation, '/abp/aspect_observation',
                                      self._on_observation, qos.RELIABLE)

    def _on_observation(self, _msg):
        self.observations += 1

    def _start(self, command, name):
        log = open(self.log_dir / f'{name}.log', 'a')  # noqa: SIM115 -- the child writes it
        return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=terminate_with_parent)

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def start_world(self, models, noise_seed):
        self.stop_world()
        seen = self.observations
        self.world = self._start([sys.executable, str(self.args.world), 'robot',
                                  str(self.args.seed), ','.join(map(str, models)), '', '',
                                  str(noise_seed)], 'world')
        if not self.spin_until(lambda: self.observations > seen + len(models), 60):
            raise RuntimeError('the world published no observation within 60 s')

    def stop_world(self):
        if self.world is not None:
            self.world.terminate()
            self.world.wait(timeout=30)
            self.world = None

    def run(self, goal, timeout=600):
        if not self.client.wait_for_server(timeout_sec=60):
            raise RuntimeError('no /abp/recognize server')
        started = time.monotonic()
        sent = self.client.send_goal_async(goal)
        if not self.spin_until(sent.done, 30) or not sent.result().accepted:
            raise RuntimeError(f'goal {goal.task!r} not accepted')
        result = sent.result().get_result_async()
        if not self.spin_until(result.done, timeout):
            raise RuntimeError(f'goal {goal.task!r} did not finish in {timeout} s')
        return result.result().result, time.monotonic() - started

    def close(self):
        self.stop_world()
        for proc in self.nodes:
            proc.terminate()
        for proc in self.nodes:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
        self.client.destroy()
        self.executor.shutdown()
        self.node.destroy_node()


def score(task, result, truth, names, target):
    """{actions, success, correct, wrong} of one task's result against `truth`
    ({track: model index})."""
    named = {o.track_id: o for o in result.objects}
    # A decided track the world does not have (an association gone wrong) counts as wrong.
    wrong = sum(1 for track, o in named.items() if o.decided and task == 'identify_all'
                and (track not in truth or o.object_id != names[truth[track]]))
    if task == 'identify_all':
        correct = all(track in named and named[track].object_id == names[m]
                      for track, m in truth.items())
    elif task == 'find_present':
        found = truth.get(result.found_track_id)
        correct = found is not None and names[found] == names[target]
        wrong = int(bool(result.found_track_id) and not correct)
    else:
        correct = result.success and not result.found_track_id
        wrong = int(bool(result.found_track_id))
    return {'actions': int(result.actions_taken), 'success': bool(result.success),
            'correct': bool(correct), 'wrong': int(wrong), 'reason': result.reason,
            'per_object': {t: int(o.actions_taken) for t, o in named.items()}}


def run_scene(loop, models, s, args):
    scene = draw_scene(models, args.seed, s, args.objects, args.twins)
    cubes = [c.true_model for c in scene['cubes']]
    truth = {f'cube{j + 1}': m for j, m in enumerate(cubes)}
    loop.start_world(cubes, noise_seed=1000 * args.seed + s)
    record = {'scene': s, 'models': [models.names[m] for m in cubes]}
    goals = {'identify_all': Recognize.Goal(task='identify_all'),
             'find_present': Recognize.Goal(task='find',
                                            target_model=models.names[scene['find_present']]),
             'find_absent': Recognize.Goal(task='find',
                                           target_model=models.names[scene['find_absent']])}
    for task in TASKS:
        result, wall = loop.run(goals[task])
        target = scene['find_present'] if task == 'find_present' else scene['find_absent']
        record[task] = {**score(task, result, truth, models.names, target), 'wall_s': wall}
        print(f'scene {s} {task}: {record[task]["actions"]} actions, correct '
              f'{record[task]["correct"]} ({result.reason})', flush=True)
    if args.single:
        record['single'] = []
        for j, m in enumerate(cubes):
            loop.start_world([m], noise_seed=1000 * args.seed + 100 * (j + 1) + s)
            result, wall = loop.run(Recognize.Goal())
            record['single'].append({'actions': int(result.actions_taken),
                                     'correct': result.object_id == models.names[m],
                                     'wall_s': wall})
        print(f'scene {s} single cubes: {[r["actions"] for r in record["single"]]}', flush=True)
    return record


def summarise(records):
    out = {}
    for task in TASKS:
        rows = [r[task] for r in records]
        out[task] = {'scenes': len(rows), 'correct': sum(r['correct'] for r in rows),
                     'wrong': sum(r['wrong'] for r in rows),
                     'actions_mean': statistics.fmean(r['actions'] for r in rows),
                     'wall_s_median': statistics.median(r['wall_s'] for r in rows)}
    if all('single' in r for r in records):
        sums = [sum(c['actions'] for c in r['single']) for r in records]
        out['single_sum'] = {'actions_mean': statistics.fmean(sums),
                             'correct_cubes': sum(c['correct'] for r in records
                                                  for c in r['single']),
                             'cubes': sum(len(r['single']) for r in records)}
        out['identify_all_over_single'] = out['identify_all']['actions_mean'] / \
            out['single_sum']['actions_mean']
        out['find_present_fewer_than_identify_all'] = 1.0 - \
            out['find_present']['actions_mean'] / out['identify_all']['actions_mean']
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--scenes', type=int, default=5)
    p.add_argument('--objects', type=int, default=3)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--twins', action='store_true', help='as planner_benchmark --twins')
    p.add_argument('--single', action='store_true',
                   help="also every cube alone (task ''): the single-cube baseline")
    p.add_argument('--world', type=pathlib.Path, default=WORLD,
                   help='the model world script (run from the repository root)')
    p.add_argument('--log-dir', type=pathlib.Path, default=pathlib.Path('log/scene_loop'))
    p.add_argument('--json')
    args = p.parse_args(argv)
    if not args.world.exists():
        p.error(f'{args.world}: no model world (run from the repository root or give --world)')
    # A domain of its own, localhost discovery: other graphs on this machine stay apart.
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randrange(102, 200)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    args.log_dir.mkdir(parents=True, exist_ok=True)
    models = population.robot_set(seed=args.seed)
    print(f'domain {os.environ["ROS_DOMAIN_ID"]}, load {os.getloadavg()[0]:.1f}', flush=True)
    rclpy.init()
    loop = Loop(args, args.log_dir)
    records = []
    try:
        for s in range(args.scenes):
            records.append(run_scene(loop, models, s, args))
    finally:
        loop.close()
        rclpy.try_shutdown()
    summary = summarise(records)
    print(json.dumps(summary, indent=2))
    print(f'load at the end {os.getloadavg()[0]:.1f}')
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps({'summary': summary, 'scenes': records},
                                                      indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
