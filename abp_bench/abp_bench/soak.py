"""`soak`: many Recognize goals on one running graph, and a crash test.

    python -m abp_bench.soak --episodes 100 [--faults] [--world rules|mujoco] [--speedup X]
                             [--kill NODE[+NODE] ...] [--seed S] [--namespace NS]
                             [--json FILE] [--no-build]

One `scripts/start_graph.sh --serve` graph (every node its own process over DDS, respawn
on) stays up for the whole run. Before each episode this driver draws a hidden model from
the robot set, sets it on the sim bridge (`model_index`, `failure_seed`) and resets the
world, waits for the sim's ground truth to name it, then sends one Recognize goal.

Soak: after every episode the resident memory (VmRSS) of each node process is read
from /proc; the report gives each node's growth from episode 10 to the last.

Crash test (`--kill`): for each named node in turn, an episode is started, the node
is killed with SIGKILL right after the first action is done, and the episode must end
(correct, or aborted with a reason; a killed planner loses its goal, which the driver
tells from a new planner process). The node must then be back (a new process, active
again: the lifecycle manager brings a respawned node up), and the next goal must
succeed with the right object. `--kill a+b` kills both nodes together in one episode;
each must be back before the next goal. The first goal waits for the manager's graph_ready.
The crash episodes come after the `--episodes` soak episodes. At the end the graph is
stopped with Ctrl-C and no process of it may be left.

The isolation of DDS (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE) is the caller's
environment, inherited by the graph. Exit code 0 when every check held, 1 otherwise.
"""

import argparse
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
from action_msgs.msg import GoalStatus
from lifecycle_msgs.srv import GetState
from rcl_interfaces.srv import SetParameters
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from abp_belief.population import robot_set
from abp_common import names, qos
from abp_common.graph_nodes import SIM, graph_nodes
from abp_common.server_handshake import wait_until_answering
from abp_msgs.action import Recognize
from abp_msgs.msg import ExecutedAction, SimGroundTruth

from .graph_benchmark import FAULTS_YAML, repo_root, terminate_with_parent

# The sim graph's long-running nodes: node name -> (package, executable).
GRAPH_NODES = {node.name: (node.package, node.executable) for node in graph_nodes(SIM)}
SIM_BRIDGE = '/sim_bridge'
GRAPH_READY = '/lifecycle_manager/graph_ready'
# Memory growth is measured from this episode (the first ones warm caches up).
RSS_BASELINE_EPISODE = 10


def graph_pids(log_dir):
    """{node name: [pid, ...]} of the graph's node processes, told by their executable
    path and by the log directory in their parameter file argument."""
    found = {name: [] for name in GRAPH_NODES}
    marker = str(log_dir).encode()
    for entry in pathlib.Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / 'cmdline').read_bytes()
        except OSError:
            continue  # gone meanwhile
        if marker not in cmdline:
            continue
        for name, (package, executable) in GRAPH_NODES.items():
            if f'/lib/{package}/{executable}\0'.encode() in cmdline:
                found[name].append(int(entry.name))
    return found


def leftover_processes(log_dir):
    """Every process whose command line names the log directory (nodes, supervisors)."""
    marker = str(log_dir).encode()
    left = []
    for entry in pathlib.Path('/proc').iterdir():
        if entry.name.isdigit() and entry.name != str(os.getpid()):
            try:
                if marker in (entry / 'cmdline').read_bytes():
                    left.append(int(entry.name))
            except OSError:
                pass
    return left


def rss_kib(pids):
    """Summed VmRSS of `pids` in KiB (a process that is gone counts 0)."""
    total = 0
    for pid in pids:
        try:
            for line in pathlib.Path(f'/proc/{pid}/status').read_text().splitlines():
                if line.startswith('VmRSS:'):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total


class Graph:
    """`start_graph.sh --serve` as a child process; its output is kept (for a failure's
    report)."""

    def __init__(self, args, log_dir, start_model):
        self.log_dir = log_dir
        command = [str(repo_root() / 'scripts' / 'start_graph.sh'), '--serve', '--world',
                   args.world, '--seed', str(args.seed), '--speedup', str(args.speedup),
                   '--object', str(start_model), '--log-dir', str(log_dir)]
        if args.no_build:
            command.append('--no-build')
        if getattr(args, 'namespace', ''):
            command += ['--namespace', args.namespace]
        if args.faults:
            faults = log_dir.parent / 'faults.yaml'
            faults.write_text(FAULTS_YAML)
            command += ['--params', str(faults)]
        self.lines = []
        self._lock = threading.Lock()
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, start_new_session=True,
                                     preexec_fn=terminate_with_parent)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.proc.stdout:
            with self._lock:
                self.lines.append(line.rstrip('\n'))

    def tail(self, count=30):
        with self._lock:
            return '\n'.join(self.lines[-count:])

    def stop(self, timeout=60.0, int_grace=5.0):
        """Ctrl-C to start_graph.sh (its trap stops every node); True if it ended in time.

        SIGTERM follows if SIGINT did not end it within `int_grace` s: a shell started in
        the background of a non-interactive shell (a CI runner, `cmd &` in a script)
        inherits SIGINT ignored, and bash cannot trap a signal ignored on entry."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=int_grace)
            return True
        except subprocess.TimeoutExpired:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=timeout - int_grace)
            return True
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            return False


class Driver:
    """The ROS side: hides a cube, sends goals, watches the executed actions."""

    def __init__(self, context, namespace=''):
        """`namespace`: the graph's (start_graph.sh --namespace); '' is the root."""
        self.namespace = namespace
        ns = names.absolute
        self.node = rclpy.create_node('soak_driver', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.recognize = ActionClient(self.node, Recognize, ns(names.RECOGNIZE, namespace))
        sim_bridge = ns(SIM_BRIDGE.lstrip('/'), namespace)
        self.set_params = self.node.create_client(SetParameters,
                                                  f'{sim_bridge}/set_parameters')
        self.reset_world = self.node.create_client(Trigger, f'{sim_bridge}/reset_world')
        self.truth = None
        self.executed = []
        self.node.create_subscription(SimGroundTruth, ns(names.GROUND_TRUTH, namespace),
                                      self._on_truth, qos.LATCHED)
        self.node.create_subscription(ExecutedAction, ns(names.EXECUTED_ACTION, namespace),
                                      self.executed.append, qos.reliable(50))
        # The lifecycle manager's verdict: every node active, their topics matched.
        self.graph_ready = False
        self.node.create_subscription(Bool, ns(GRAPH_READY.lstrip('/'), namespace),
                                      self._on_graph_ready, qos.LATCHED)

    def _on_graph_ready(self, msg):
        self.graph_ready = msg.data

    def _on_truth(self, msg):
        self.truth = msg

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while not predicate() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        return predicate()

    def call(self, client, request, timeout=30.0, attempt_s=3.0):
        """A service call, asked again every `attempt_s` (the server may be new: a respawn)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.spin_until(client.service_is_ready, deadline - time.monotonic()):
                break
            future = client.call_async(request)
            if self.spin_until(future.done, min(attempt_s, deadline - time.monotonic())):
                return future.result()
            client.remove_pending_request(future)
        raise RuntimeError(f'no answer from {client.srv_name} within {timeout:.0f} s')

    def hide(self, model_index, object_id, failure_seed, timeout=60.0):
        """Put model `model_index` in the sim world and wait until its ground truth says so."""
        request = SetParameters.Request(parameters=[
            Parameter('model_index', value=int(model_index)).to_parameter_msg(),
            Parameter('failure_seed', value=int(failure_seed)).to_parameter_msg()])
        results = self.call(self.set_params, request, timeout).results
        refused = [r.reason for r in results if not r.successful]
        if refused:
            raise RuntimeError(f'sim bridge refused the parameters: {refused}')
        reset = self.call(self.reset_world, Trigger.Request(), timeout)
        if not reset.success:
            raise RuntimeError(f'sim bridge reset refused: {reset.message}')
        self.truth = None  # the latched old truth may come again: wait for the new one
        if not self.spin_until(lambda: self.truth is not None and
                               self.truth.object_id == object_id, timeout):
            raise RuntimeError(f'the sim ground truth did not become {object_id} within '
                               f'{timeout:.0f} s')

    def close(self):
        self.recognize.destroy()
        self.executor.shutdown()
        self.node.destroy_node()


def kill_group(kill):
    """The node names of a `--kill` item ('belief' or 'belief+robot_state')."""
    return kill.split('+') if kill else []


def run_episode(driver, graph, index, object_id, timeout, kill=None):
    """One Recognize goal; with `kill` (a node name, or names joined by '+'), SIGKILL
    those nodes together after the first action. Returns the episode's record (outcome,
    reason, correct, actions, posterior, wall time)."""
    record = {'episode': index, 'object': object_id, 'killed': kill}
    if not wait_until_answering(driver.recognize, driver.spin_until, 120.0):
        record.update(outcome='no server', reason='no Recognize server within 120 s',
                      correct=False)
        return record
    driver.executed.clear()
    started = time.monotonic()
    sent = driver.recognize.send_goal_async(Recognize.Goal())
    if not driver.spin_until(sent.done, 30.0) or not sent.result().accepted:
        record.update(outcome='rejected', reason='goal not accepted', correct=False)
        return record
    result = sent.result().get_result_async()
    killed_at = None
    if kill:
        if not driver.spin_until(lambda: driver.executed or result.done(), timeout):
            record.update(outcome='timeout', reason='no first action', correct=False)
            return record
        running = graph_pids(graph.log_dir)
        pids = {name: running[name] for name in kill_group(kill)}
        killed_at = time.monotonic()
        for pid in (p for group in pids.values() for p in group):
            os.kill(pid, signal.SIGKILL)
        record['killed_pids'] = pids
        record['killed_at'] = killed_at

    def lost():
        # A killed planner takes its goal with it: the result never comes. Its new
        # process (start_graph.sh respawns it) says the old one is gone for good.
        return 'planner' in kill_group(kill) and any(
            p not in pids['planner'] for p in graph_pids(graph.log_dir)['planner'])

    deadline = started + timeout
    driver.spin_until(lambda: result.done() or lost(), max(0.0, deadline - time.monotonic()))
    record['wall_s'] = time.monotonic() - started
    if result.done():
        response = result.result()
        truth = driver.truth.object_id if driver.truth is not None else ''
        record.update(
            outcome={GoalStatus.STATUS_SUCCEEDED: 'succeeded',
                     GoalStatus.STATUS_ABORTED: 'aborted',
                     GoalStatus.STATUS_CANCELED: 'cancelled'}.get(response.status,
                                                                 str(response.status)),
            success=bool(response.result.success), reason=response.result.reason,
            answer=response.result.object_id, ground_truth=truth,
            correct=bool(response.result.success) and response.result.object_id == truth,
            actions=int(response.result.actions_taken),
            posterior=float(response.result.posterior))
    elif lost():
        record.update(outcome='lost', correct=False,
                      reason='the planner died with the goal (start_graph.sh restarted it)')
    else:
        record.update(outcome='timeout', correct=False,
                      reason=f'no result within {timeout:.0f} s')
    return record


def wait_until_back(driver, graph, name, old_pids, killed_at, timeout=180.0):
    """Seconds from the kill until node `name` runs as a new process and is active again
    (the lifecycle manager brings a respawned node up); None if not within `timeout`.
    (Its name alone proves nothing: DDS lists the killed node until its lease ends; a dead
    node answers nothing.)"""
    deadline = time.monotonic() + timeout
    if not driver.spin_until(
            lambda: any(p not in old_pids for p in graph_pids(graph.log_dir)[name]), timeout):
        return None
    client = driver.node.create_client(
        GetState, names.absolute(f'{name}/get_state', driver.namespace))
    try:
        while True:
            state = driver.call(client, GetState.Request(),
                                max(1.0, deadline - time.monotonic())).current_state.label
            if state == 'active':
                return time.monotonic() - killed_at
            if time.monotonic() >= deadline:
                return None
            # Between two questions, take the graph's messages for a moment.
            driver.spin_until(lambda: False, 0.2)
    except RuntimeError:
        return None
    finally:
        driver.node.destroy_client(client)


def summarise(soak, crashes, rss, stopped, leftovers):
    lines = []
    if soak:
        correct = sum(r['correct'] for r in soak)
        walls = sorted(r.get('wall_s', 0.0) for r in soak)
        outcomes = {}
        for r in soak:
            outcomes[r['outcome']] = outcomes.get(r['outcome'], 0) + 1
        lines += [f'episodes: {len(soak)}, correct {correct} ({100.0 * correct / len(soak):.1f} %),'
                  f' outcomes {outcomes}',
                  f'episode wall time: median {statistics.median(walls):.1f} s, max '
                  f'{walls[-1]:.1f} s']
        wrong = [r for r in soak if not r['correct']]
        for r in wrong:
            lines.append(f"  episode {r['episode']}: {r['object']} -> {r.get('answer', '-')} "
                         f"({r['outcome']}: {r.get('reason', '')})")
    if rss:
        base = rss[min(RSS_BASELINE_EPISODE, len(rss)) - 1]
        last = rss[-1]
        lines += ['', '| node | RSS at episode '
                  f'{min(RSS_BASELINE_EPISODE, len(rss))} (MiB) | RSS at episode {len(rss)} '
                  '(MiB) | growth |', '|---|---|---|---|']
        for name in GRAPH_NODES:
            growth = (last[name] / base[name] - 1.0) * 100.0 if base[name] else float('nan')
            lines.append(f'| {name} | {base[name] / 1024:.1f} | {last[name] / 1024:.1f} | '
                         f'{growth:+.1f} % |')
    if crashes:
        lines += ['', '| killed node | episode outcome | reason | seen back (s after the kill) '
                  '| next goal |',
                  '|---|---|---|---|---|']
        for c in crashes:
            back = ', '.join('-' if s is None else f'{s:.1f}' for s in c['back_s'].values())
            after = c.get('next') or {}
            lines.append(f"| {c['killed']} | {c['outcome']}{' (correct)' if c['correct'] else ''}"
                         f" | {c.get('reason', '')} | {back} | {after.get('outcome', '-')}"
                         f"{' (correct)' if after.get('correct') else ''} |")
    lines += ['', f'graph stopped on Ctrl-C: {stopped}; processes left afterwards: '
              f'{len(leftovers)}']
    return '\n'.join(lines)


def crash_ok(crash):
    ended = crash['outcome'] in ('succeeded', 'aborted', 'lost') and (
        crash['correct'] or crash['outcome'] != 'succeeded')
    return ended and all(s is not None for s in crash['back_s'].values()) and bool(
        crash.get('next', {}).get('correct'))


def kill_item(text):
    """A `--kill` item: a node of GRAPH_NODES, or several joined by '+', each once."""
    group = text.split('+')
    unknown = [name for name in group if name not in GRAPH_NODES]
    if unknown or len(set(group)) != len(group):
        raise argparse.ArgumentTypeError(
            f"{text!r}: give graph nodes ({', '.join(GRAPH_NODES)}), several joined by '+', "
            'each once')
    return text


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='soak', description=__doc__.split('\n\n')[0])
    parser.add_argument('--episodes', type=int, default=100, help='soak episodes (0: none)')
    parser.add_argument('--kill', nargs='*', default=[], type=kill_item,
                        metavar='NODE[+NODE]', help='crash test: kill these nodes in turn, '
                        "mid-episode; 'a+b' kills a and b together in one episode "
                        f"(any of {', '.join(GRAPH_NODES)})")
    parser.add_argument('--world', choices=('rules', 'mujoco'), default='rules')
    parser.add_argument('--faults', action='store_true',
                        help='10%% grasp slips and missed pushes, 10%% missed tags, 2 '
                        'distractors, orbit odometry noise (graph_benchmark --faults)')
    parser.add_argument('--speedup', type=float, default=10.0)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--namespace', default='',
                        help='run the graph under this namespace (start_graph.sh --namespace)')
    parser.add_argument('--ready-timeout', type=float, default=900.0,
                        help="seconds to wait for the lifecycle manager's graph ready")
    parser.add_argument('--episode-timeout', type=float, default=600.0,
                        help='wall seconds an episode may take')
    parser.add_argument('--json', help='write every episode record and the RSS series here')
    parser.add_argument('--no-build', action='store_true')
    args = parser.parse_args(argv)
    if args.episodes < 0 or not args.speedup > 0 or not args.episode_timeout > 0:
        parser.error('--episodes must be >= 0, --speedup and --episode-timeout > 0')
    if not args.episodes and not args.kill:
        parser.error('nothing to do: give --episodes N and/or --kill NODE ...')
    return args


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    models = robot_set(seed=args.seed)
    rng = np.random.default_rng(args.seed)
    workdir = pathlib.Path(tempfile.mkdtemp(prefix='abp-soak-'))
    log_dir = workdir / 'logs'
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    # Crash episodes hide the model the graph started with: a respawned sim bridge starts
    # from its command line, and so hides the same cube (at its initial pose).
    start_model = int(rng.integers(models.num_models))
    graph = Graph(args, log_dir, start_model)
    driver = Driver(context, args.namespace)
    soak, crashes, rss = [], [], []
    failed = None
    try:
        if not driver.spin_until(lambda: driver.graph_ready, args.ready_timeout):
            raise RuntimeError(f'the graph was not ready within {args.ready_timeout:.0f} s')
        total = args.episodes + 2 * len(args.kill)
        plan = [None] * args.episodes + [n for name in args.kill for n in (name, None)]
        for index, kill in enumerate(plan):
            model = int(rng.integers(models.num_models)) if index < args.episodes else \
                start_model
            driver.hide(model, models.names[model], failure_seed=args.seed * 1000 + index)
            record = run_episode(driver, graph, index, models.names[model],
                                 args.episode_timeout, kill)
            print(f"[soak] {index + 1}/{total}{' kill ' + kill if kill else ''}: "
                  f"{record['object']} -> {record.get('answer', '-')} {record['outcome']} "
                  f"({record.get('reason', '')}) {record.get('wall_s', 0):.1f} s", flush=True)
            if kill:
                # Seconds from the kill until each killed node was back (None: not back).
                record['back_s'] = {
                    name: wait_until_back(driver, graph, name,
                                          record.get('killed_pids', {}).get(name, []),
                                          record.get('killed_at', time.monotonic()))
                    for name in kill_group(kill)}
                crashes.append(record)
            elif crashes and crashes[-1].get('next') is None and index >= args.episodes:
                crashes[-1]['next'] = record
            else:
                soak.append(record)
                pids = graph_pids(log_dir)
                rss.append({name: rss_kib(pids[name]) for name in GRAPH_NODES})
    except RuntimeError as error:
        failed = str(error)
        print(f'[soak] stopped: {error}\n{graph.tail()}', file=sys.stderr)
    finally:
        driver.close()
        rclpy.try_shutdown(context=context)
        stopped = graph.stop()
        leftovers = leftover_processes(log_dir)
    report = summarise(soak, crashes, rss, stopped, leftovers)
    print(report)
    print(f'(world {args.world}, speed-up {args.speedup:g}, seed {args.seed}, '
          f"{'with' if args.faults else 'without'} faults; logs in {log_dir})")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(
            {'soak': soak, 'crashes': crashes, 'rss_kib': rss, 'stopped': stopped,
             'leftovers': leftovers, 'failed': failed, 'log_dir': str(log_dir)}, indent=1))
    ok = failed is None and stopped and not leftovers and all(map(crash_ok, crashes))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
