"""`graph_benchmark`: recognition episodes through the real graph in simulation.

    graph_benchmark --episodes 20 [--world mujoco|rules] [--faults] [--models robot]
                    [--planner cost] [--seed S] [--json FILE] [--no-build] [--record DIR]
                    [--objects I [I ...] --repeats K] [--vary-start]
                    [--operator scripted [--wrong-action-fraction F]]

Each episode is one `scripts/start_graph.sh` run (every node its own process,
over DDS) with a seeded hidden cube from the model set; the result is compared
with the sim's ground truth, in the sim bridge's `--world` (mujoco: MuJoCo physics
and camera; rules: contact rules and flat renderer). --faults injects 10% grasp slips
and missed pushes, 10% missed tags per frame, 2 distractor tags and orbit odometry noise
(in the MuJoCo world slips and misses are hand offsets drawn per manual action, see
docs/SIM_BRIDGE.md). A probe subscribed to /camera/image_raw and /abp/belief measures
the wall-clock latency from an image to the belief update it caused (matched by header
stamp). --record DIR keeps one rosbag2 bag per episode (DIR/episode-NN-object-I) and
DIR/labels.yaml (bag -> true object): the input of `episode_trace` and `learn_atg --bags`.
--objects and --repeats choose the hidden cubes instead of the seeded draw (the listed
model indices, in --repeats rounds), and --vary-start gives each episode its own cube
start (up face, yaw) and failure seed, so that repeated episodes of one cube are
different experience.
--operator scripted runs each episode as `start_graph.sh --operator scripted` instead: no
robot, the MuJoCo world's fixed camera and a scripted person doing each request
(docs/OPERATOR.md), who does the wrong action --wrong-action-fraction of the time
(seeded with --seed).
Prints a Markdown table; the figures go in docs/BENCHMARKS.md.
"""

import argparse
import ctypes
import json
import os
import pathlib
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image

from abp_belief.cube import TRANSITION_RULES
from abp_common import names, qos
from abp_msgs.msg import AspectObservation, Belief

from .episode_trace import model_set_of

# The sim bridge's section of a --params file, in any namespace.
SIM_BRIDGE_PARAMS = '/**/sim_bridge:\n  ros__parameters:\n'
FAULTS_YAML = SIM_BRIDGE_PARAMS + """    p_slip_grasp: 0.1
    p_missed_push: 0.1
    p_missed_tag: 0.1
    distractors: 2
    orbit_odometry_noise: [0.01, 0.02]
"""


def repo_root():
    env = os.environ.get('ABP_REPO')
    return pathlib.Path(env) if env else pathlib.Path(__file__).resolve().parents[2]


class LatencyProbe:
    """Wall-clock time from an image's arrival to the belief stamped with it, and to the
    aspect observation stamped with it (every frame). Images are keyed by stamp, so
    the keys are cleared between episodes (each episode's sim clock starts at 0)."""

    def __init__(self):
        self.context = rclpy.context.Context()
        # No rclpy signal handler: Ctrl-C must reach the episode loop as KeyboardInterrupt
        # so that the running graph is stopped cleanly.
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('latency_probe', context=self.context)
        self.image_times = {}
        self.latencies_ms = []
        self.observation_latencies_ms = []
        self.node.create_subscription(Image, names.IMAGE, self._on_image, qos.SENSOR_DATA)
        self.node.create_subscription(Belief, names.BELIEF, self._on_belief,
                                      qos.LATCHED_READER)
        self.node.create_subscription(AspectObservation, names.ASPECT_OBSERVATION,
                                      self._on_observation, qos.RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    @staticmethod
    def _key(stamp):
        return stamp.sec, stamp.nanosec

    def _on_image(self, msg):
        self.image_times[self._key(msg.header.stamp)] = time.monotonic()

    def new_episode(self):
        self.image_times = {}

    def _on_observation(self, msg):
        arrived = self.image_times.get(self._key(msg.header.stamp))
        if arrived is not None:
            self.observation_latencies_ms.append((time.monotonic() - arrived) * 1e3)

    def _on_belief(self, msg):
        arrived = self.image_times.get(self._key(msg.header.stamp))
        if arrived is not None:  # corrections only: predictions carry the action's stamp
            self.latencies_ms.append((time.monotonic() - arrived) * 1e3)

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='graph_benchmark', description=__doc__.split('\n\n')[0])
    parser.add_argument('--episodes', type=int, default=None,
                        help='episodes, each a hidden cube drawn with --seed (default 20; '
                        'not with --objects)')
    parser.add_argument('--objects', type=int, nargs='+', metavar='I', default=None,
                        help='hidden cubes by model index, in this order, instead of the draw')
    parser.add_argument('--repeats', type=int, default=1,
                        help='with --objects: episodes per listed cube (default 1)')
    parser.add_argument('--vary-start', action='store_true',
                        help="each episode draws the cube's up face, yaw and the sim "
                        "bridge's failure seed from (--seed, episode number)")
    parser.add_argument('--world', choices=('mujoco', 'rules'), default='mujoco',
                        help='the sim bridge world (default mujoco, as start_graph.sh)')
    parser.add_argument('--no-build', action='store_true',
                        help='do not run scripts/bootstrap.sh before each episode')
    parser.add_argument('--models', default=None,
                        help="as start_graph.sh --models (default: the robot profile's "
                             'learned model set, else robot)')
    parser.add_argument('--robot-profile', default='', metavar='YAML',
                        help="as start_graph.sh --robot-profile: the robot's profile "
                             '(default the uBot-6)')
    parser.add_argument('--tables', choices=TRANSITION_RULES, default=None,
                        help='as start_graph.sh --tables (default: paper in the rules world, '
                        'else corrected)')
    parser.add_argument('--planner', default='cost', help='as start_graph.sh --planner')
    parser.add_argument('--seed', type=int, default=0, help='model-set seed')
    parser.add_argument('--faults', action='store_true')
    parser.add_argument('--dictionary', default=None,
                        help="the cubes' ArUco dictionary, as start_graph.sh --dictionary "
                             "(default: the nodes' own, DICT_4X4_50)")
    parser.add_argument('--one-process', action='store_true',
                        help='as start_graph.sh --one-process: the nodes in one process')
    parser.add_argument('--speedup', type=float, default=10.0)
    parser.add_argument('--timeout', type=float, default=900.0, help='per episode, wall s')
    parser.add_argument('--json', default='')
    parser.add_argument('--operator', choices=('scripted',), default=None,
                        help='as start_graph.sh --operator scripted: a scripted person and a '
                        'fixed camera instead of the robot (no sim bridge)')
    parser.add_argument('--wrong-action-fraction', type=float, default=None, metavar='F',
                        help='with --operator scripted: share of the requests done wrong')
    parser.add_argument('--record', metavar='DIR', default='',
                        help='record each episode to a bag in DIR (a new or empty directory) '
                        'and write DIR/labels.yaml')
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error('--repeats must be >= 1')
    if args.operator is None and args.wrong_action_fraction is not None:
        parser.error('--wrong-action-fraction goes with --operator scripted')
    if args.operator and (args.faults or args.vary_start or args.one_process):
        parser.error('--operator scripted has no sim bridge: no --faults, --vary-start or '
                     '--one-process')
    if args.objects is None:
        if args.repeats > 1:
            parser.error('--repeats needs --objects')
        args.episodes = 20 if args.episodes is None else args.episodes
    elif args.episodes is not None:
        parser.error('--episodes and --objects exclude each other')
    else:
        args.episodes = len(args.objects) * args.repeats
    if args.episodes < 1:
        parser.error('--episodes must be >= 1')
    profile_models = None
    if args.robot_profile:
        from abp_description.robot_profile import ProfileError, load_profile

        args.robot_profile = os.path.abspath(args.robot_profile)
        try:
            profile_models = load_profile(args.robot_profile).models
        except ProfileError as error:
            parser.error(f'--robot-profile: {error}')
    if args.models is None:
        args.models = profile_models or 'robot'
    return args


def episode_objects(args, count):
    """The hidden cube (model index) of each episode: --objects in rounds (each listed cube
    once per round, --repeats rounds, so that a run stopped early has covered every cube
    about equally), or a seeded draw from the model set's `count` models."""
    if args.objects is None:
        return [int(i) for i in np.random.default_rng(args.seed).choice(
            count, size=args.episodes, replace=args.episodes > count)]
    unknown = [i for i in args.objects if not 0 <= i < count]
    if unknown:
        raise SystemExit(f'graph_benchmark: --objects {unknown} not in the model set '
                         f'(indices 0-{count - 1})')
    return list(args.objects) * args.repeats


def episode_params(args, number):
    """The sim bridge parameters (YAML) of episode `number`: the fault injection, and with
    --vary-start a start and failure seed of its own (seeded, so a run can be repeated).
    The yaw is a 45° step +-5°, away from the boundary between two discrete states, so that
    the ground truth's state is the one the robot sees."""
    text = FAULTS_YAML if args.faults else ''
    if args.vary_start:
        rng = np.random.default_rng([args.seed, number])
        yaw = np.deg2rad(45.0 * int(rng.integers(8)) - 180.0 + rng.uniform(-5.0, 5.0))
        start = (f'    cube_up_face: {int(rng.integers(6))}\n'
                 f'    cube_yaw: {float(yaw):.4f}\n'
                 f'    failure_seed: {1000 * args.seed + number}\n'
                 f'    distractor_seed: {1000 * args.seed + number}\n')
        text = (text or SIM_BRIDGE_PARAMS) + start
    return text


def record_dir(path):
    """DIR of --record, made if needed; refused if it holds anything (rosbag2 never
    overwrites a bag, and a stale labels file would mislabel the new bags)."""
    record = pathlib.Path(path)
    if record.exists() and (not record.is_dir() or any(record.iterdir())):
        raise SystemExit(f'graph_benchmark: --record {record} must be a new or empty directory')
    record.mkdir(parents=True, exist_ok=True)
    return record.resolve()


PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h)
# Looked up here, not in the child: a forked child of a threaded process must not dlopen.
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl


def terminate_with_parent():
    """In the child before exec: SIGTERM when the driver dies, however it dies (a SIGKILL, a
    test's timeout), so that start_graph.sh's trap stops the graph rather than leave it
    running on the domain."""
    _PRCTL(PR_SET_PDEATHSIG, int(signal.SIGTERM))


def stop_graph(proc):
    """SIGTERM lets start_graph.sh stop its nodes (SIGINT is ignored by scripts started in
    the background of a non-interactive shell); if it has not ended within 60 s (a loaded
    machine), SIGKILL to its whole process group, so that no node is orphaned."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def tables_of(args) -> str:
    """The ATG tables the graph's belief and planner use (start_graph.sh's choice)."""
    if os.path.isfile(args.models):
        return 'file'
    return args.tables or ('paper' if args.world == 'rules' else 'corrected')


def run_episode(args, index, workdir, params_file, bag=None):
    result_file = workdir / f'episode-{index}.json'
    world = (['--operator', args.operator] if args.operator else ['--world', args.world])
    if args.wrong_action_fraction is not None:
        world += ['--wrong-action-fraction', str(args.wrong_action_fraction)]
    cmd = [str(repo_root() / 'scripts' / 'start_graph.sh'), *world,
           '--models', args.models,
           '--seed', str(args.seed), '--object', str(index), '--planner', args.planner,
           '--speedup', str(args.speedup), '--result-json', str(result_file),
           '--log-dir', str(workdir / f'logs-{index}'), '--timeout', str(args.timeout)]
    if args.tables:
        cmd += ['--tables', args.tables]
    if params_file:
        cmd += ['--params', str(params_file)]
    if args.no_build:
        cmd += ['--no-build']
    if args.one_process:
        cmd += ['--one-process']
    if args.dictionary:
        cmd += ['--dictionary', args.dictionary]
    if args.robot_profile:
        cmd += ['--robot-profile', args.robot_profile]
    if bag is not None:
        cmd += ['--record', str(bag)]
    started = time.monotonic()
    # stderr kept: where the episode ends without a result, it says why.
    errors = workdir / f'episode-{index}.stderr'
    # Its own session: stop_graph can kill the whole graph without killing this process.
    with open(errors, 'wb') as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err,
                                start_new_session=True, preexec_fn=terminate_with_parent)
    try:
        proc.wait(timeout=args.timeout + 120)
    except subprocess.TimeoutExpired:
        stop_graph(proc)
        return {'object': index, 'hung': True, 'correct': False,
                'wall_s': time.monotonic() - started}
    except KeyboardInterrupt:
        stop_graph(proc)
        raise
    result = json.loads(result_file.read_text()) if result_file.exists() else {}
    result.update(object=index, hung=False, wall_s=time.monotonic() - started)
    if args.operator:
        result.update(operator_actions(workdir / f'logs-{index}' / 'scripted_operator.log'))
    result.setdefault('correct', False)
    if 'status' not in result:
        # No result from the client: the graph never came up, or no goal ran to its end.
        lines = errors.read_text(errors='replace').strip().splitlines()
        result['no_result'] = lines[-1] if lines else f'start_graph.sh exited {proc.returncode}'
    return result


def operator_actions(log):
    """{'operator_actions': N, 'wrong_actions': W} from a scripted operator's log (its
    `did ...` lines name a wrong action as such)."""
    done = [line for line in (log.read_text(errors='replace').splitlines()
                              if log.exists() else []) if ']: did ' in line]
    return {'operator_actions': len(done),
            'wrong_actions': sum('(wrong action)' in line for line in done)}


def verdict(result):
    """correct | WRONG (named the wrong object) | not identified (the goal aborted: the
    planner stopped without an identification, and said why) | no result (the client
    wrote none: the graph did not come up, or the goal timed out) | hung."""
    if result['hung']:
        return 'hung'
    if 'no_result' in result:
        return 'no result'
    # recognize_client's 'correct' is already false for an aborted goal.
    if not result.get('success'):
        return 'not identified'
    return 'correct' if result['correct'] else 'WRONG'


def summarise(results, latencies, observation_latencies, args):
    n = len(results)
    verdicts = [verdict(r) for r in results]
    correct = verdicts.count('correct')
    likely_right = sum(v == 'not identified' and bool(r.get('most_likely_correct'))
                       for v, r in zip(verdicts, results))
    done = [r for r in results if 'actions' in r]
    lat = np.array(latencies) if latencies else np.array([np.nan])
    obs = np.array(observation_latencies) if observation_latencies else np.array([np.nan])
    rows = [
        ('episodes', f'{n}'),
        ('correct', f'{correct}/{n} ({100.0 * correct / n:.1f} %)'),
        ('wrong (succeeded on the wrong object)', f"{verdicts.count('WRONG')}"),
        ('not identified (aborted with a reason)',
         f"{verdicts.count('not identified')}"
         + (f' ({likely_right} with the right most likely object)' if likely_right else '')),
        ('no result (the graph did not come up, or the goal timed out)',
         f"{verdicts.count('no result')}"),
        ('hung (no result within the timeout)', f"{verdicts.count('hung')}"),
        ('mean actions', f"{statistics.mean(r['actions'] for r in done):.2f}" if done else '-'),
        *([('operator actions done wrong',
            f"{sum(r['wrong_actions'] for r in results)} of "
            f"{sum(r['operator_actions'] for r in results)}")] if args.operator else []),
        ('mean wall time of the recognition (s)' if args.operator else
         'mean sim time per episode (s)',
         f"{statistics.mean(r['elapsed_s'] for r in done):.1f}" if done else '-'),
        ('median wall time per episode (s)',
         f"{statistics.median(r['wall_s'] for r in results):.1f}"),
        # The issue 39 figure: simulated seconds of the episodes over their wall seconds,
        # start-up and shut-down included.
        *([] if args.operator else [(
            'sim s / wall s, start-up included (all episodes)',
            f"{sum(r['elapsed_s'] for r in done) / sum(r['wall_s'] for r in done):.2f}"
            if done else '-')]),
        ('image -> belief latency, median / p95 (ms)',
         f'{np.nanmedian(lat):.1f} / {np.nanpercentile(lat, 95):.1f} ({len(latencies)} updates)'),
        ('image -> aspect observation latency, median / p95 (ms)',
         f'{np.nanmedian(obs):.1f} / {np.nanpercentile(obs, 95):.1f} '
         f'({len(observation_latencies)} frames)'),
    ]
    where = (f'scripted operator, fixed camera, wrong actions '
             f'{args.wrong_action_fraction or 0:.0%}' if args.operator else f'{args.world} world')
    sim = ('' if args.operator else
           f", {'with' if args.faults else 'without'} fault injection, speed-up "
           f'{args.speedup:g}')
    title = (f"{where}, {args.models} models ({tables_of(args)} tables), "
             f"planner {args.planner}{sim}{', one process' if args.one_process else ''}"
             f"{f', {args.dictionary} tags' if args.dictionary else ''}"
             f"{f', robot {pathlib.Path(args.robot_profile).stem}' if args.robot_profile else ''}")
    lines = [f'**{title}**', '', '| measure | value |', '|---|---|']
    lines += [f'| {k} | {v} |' for k, v in rows]
    return '\n'.join(lines)


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    # Ctrl-C and SIGTERM end the run through KeyboardInterrupt, which stops the
    # running graph first (even when started with SIGINT ignored, e.g. by `nohup`).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    model_names = model_set_of(args.models, args.seed).names
    objects = episode_objects(args, len(model_names))
    record = record_dir(args.record) if args.record else None
    interrupted = False
    labels = []
    probe = LatencyProbe()
    results = []
    with tempfile.TemporaryDirectory(prefix='abp-graph-bench-') as tmp:
        workdir = pathlib.Path(tmp)
        try:
            for number, index in enumerate(objects, 1):
                probe.new_episode()
                params = episode_params(args, number)
                params_file = workdir / f'params-{number}.yaml' if params else None
                if params_file:
                    params_file.write_text(params)
                bag = record / f'episode-{number:02d}-object-{index}' if record else None
                result = run_episode(args, int(index), workdir, params_file, bag)
                results.append(result)
                if bag is not None and bag.exists():
                    # Written after every episode, so that an interrupted run keeps its labels.
                    labels.append(f'{bag.name}: {model_names[int(index)]}')
                    (record / 'labels.yaml').write_text('\n'.join(labels) + '\n')
                print(f'[{number}/{args.episodes}] object {index}: {verdict(result)} '
                      f"{result.get('object_id', '-')} (truth {result.get('ground_truth', '-')}) "
                      f"{result.get('actions', '-')} actions, {result['wall_s']:.0f} s wall"
                      + (f": {result['no_result']}" if 'no_result' in result else ''),
                      file=sys.stderr, flush=True)
        except KeyboardInterrupt:
            # The finished episodes are still summarised and written: a long run stopped
            # early keeps what it measured.
            interrupted = True
            print(f'[graph_benchmark] interrupted; the running graph was stopped; the '
                  f'summary covers the {len(results)} finished episodes', file=sys.stderr)
        finally:
            probe.close()
    if not results:
        return 130
    table = summarise(results, probe.latencies_ms, probe.observation_latencies_ms, args)
    print(table)
    if args.json:
        with open(args.json, 'w') as out:
            json.dump({'args': vars(args), 'tables': tables_of(args),
                       'interrupted': interrupted, 'results': results,
                       'latencies_ms': probe.latencies_ms,
                       'observation_latencies_ms': probe.observation_latencies_ms}, out,
                      indent=2)
    if interrupted:
        return 130
    return 0 if all(verdict(r) == 'correct' for r in results) else 1


if __name__ == '__main__':
    sys.exit(main())
