"""`graph_profile`: where the simulated graph spends its CPU and wake-ups.

    python -m abp_bench.graph_profile [--world mujoco|rules] [--speedup 10] [--seconds 20]
        [--episode] [--object I] [--json FILE] [--no-topics]
    python -m abp_bench.graph_profile sim-step [--world mujoco] [--ticks 500]

The first form starts the whole graph with `scripts/start_graph.sh --no-build` (idle:
`--serve`, no goal; `--episode`: one recognition runs, and the window ends with it), waits
for `graph ready`, and then over a window of wall time measures:
- per node: CPU (% of one core, all threads, /proc/<pid>/stat) and wake-ups (voluntary
  context switches per second, summed over threads; `proc_stats`);
- per topic: messages and bytes per second of wall time (a raw subscriber to every topic:
  nothing is deserialised, except /clock, whose stamps give the simulated seconds per wall
  second reached), and the image -> belief latency as graph_benchmark measures it;
- the machine's 1-minute load average (the figures are only comparable at a like load).
The probe itself is one more subscriber of every topic: it adds a little to the
publishers' cost, the same before and after a change.

`sim-step` profiles the sim bridge's tick without ROS: the world and camera as the node
builds them (defaults of abp_sim_bridge.config), each tick's physics step, the joint
state and odometry copies, and every `camera_rate` tick a snapshot and a render, timed
apart, then the top cProfile entries of the ticks.

Run it on an isolated domain (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) so
that no other graph's traffic is counted. Figures: docs/SPEED.md.
"""

import argparse
import importlib
import json
import pathlib
import signal
import subprocess
import sys
import tempfile
import threading
import time

from .graph_benchmark import repo_root
from .proc_stats import ProcSample, graph_processes, load_average, rates

READY_LINE = 'graph ready'
START_TIMEOUT_S = 180.0


def message_class(type_name):
    """'pkg/msg/Name' -> the message class (rosidl's Python modules)."""
    package, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


class TopicMeter:
    """Counts every topic's messages and bytes (raw: no deserialisation), /clock's sim
    time, and image -> belief latency (graph_benchmark.LatencyProbe's rule)."""

    def __init__(self, topics=True):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from .graph_benchmark import LatencyProbe
        self.rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('graph_profile', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.topics = topics
        self.counts = {}            # topic -> [messages, bytes]
        self.clock = []             # (wall, sim seconds)
        self._subscribed = set()
        self._counting = False
        self.lock = threading.Lock()
        self.latency = LatencyProbe()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def subscribe_all(self):
        """Subscribe to every topic there is now (call once the graph is ready)."""
        from rclpy.qos import QoSProfile, QoSReliabilityPolicy
        from rclpy.serialization import deserialize_message
        from rosgraph_msgs.msg import Clock
        best_effort = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.BEST_EFFORT)
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._subscribed or not types or topic == '/rosout':
                continue
            if not self.topics and topic != '/clock':
                continue
            try:
                cls = message_class(types[0])
            except (ImportError, AttributeError, ValueError):
                continue
            self._subscribed.add(topic)

            def count(raw, topic=topic):
                if not self._counting:
                    return
                with self.lock:
                    entry = self.counts.setdefault(topic, [0, 0])
                    entry[0] += 1
                    entry[1] += len(raw)
                if topic == '/clock':
                    c = deserialize_message(raw, Clock).clock
                    self.clock.append((time.monotonic(), c.sec + c.nanosec * 1e-9))
            # Best effort: a reliable probe would slow a publisher down; it sees what the
            # graph's own best-effort readers could see (reliable writers match it too).
            self.node.create_subscription(cls, topic, count, best_effort, raw=True)

    def start(self):
        with self.lock:
            self.counts.clear()
            self.clock.clear()
            self.latency.latencies_ms.clear()
            self.latency.observation_latencies_ms.clear()
        self._counting = True

    def stop(self):
        self._counting = False

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
        self.latency.close()

    def sim_rate(self):
        """Simulated seconds per wall second over the window (from /clock)."""
        if len(self.clock) < 2:
            return float('nan')
        (w0, s0), (w1, s1) = self.clock[0], self.clock[-1]
        return (s1 - s0) / (w1 - w0) if w1 > w0 else float('nan')


def start_graph(args, log_dir):
    cmd = [str(repo_root() / 'scripts' / 'start_graph.sh'), '--no-build', '--world',
           args.world, '--speedup', str(args.speedup), '--seed', str(args.seed),
           '--log-dir', str(log_dir), '--no-respawn']
    if args.object is not None:
        cmd += ['--object', str(args.object)]
    if args.params:
        cmd += ['--params', args.params]
    if not args.episode:
        cmd += ['--serve']
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def wait_ready(proc):
    deadline = time.monotonic() + START_TIMEOUT_S
    lines = []
    for line in proc.stdout:
        lines.append(line.rstrip())
        if READY_LINE in line:
            return time.monotonic()
        if time.monotonic() > deadline:
            break
    raise RuntimeError('the graph did not come up:\n' + '\n'.join(lines[-15:]))


def stop(proc):
    try:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        import os
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def measure(args):
    meter = TopicMeter(topics=not args.no_topics)
    with tempfile.TemporaryDirectory(prefix='abp-graph-profile-') as tmp:
        started = time.monotonic()
        try:
            proc = start_graph(args, pathlib.Path(tmp) / 'logs')
        except OSError:
            meter.close()
            raise
        try:
            ready_at = wait_ready(proc)
            # Drain the script's output so that it never blocks on a full pipe.
            threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()
            nodes = graph_processes(proc.pid)
            meter.subscribe_all()
            time.sleep(args.settle)      # matching the probe's subscriptions
            before = {name: ProcSample.take(pid) for name, pid in nodes.items()}
            load_before = load_average()[0]
            meter.start()
            t0 = time.monotonic()
            # Sampled all along: at the end of an episode the nodes exit, and each node's
            # figures are those up to its last sample.
            after = {}
            while time.monotonic() - t0 < args.seconds and proc.poll() is None:
                for name, pid in nodes.items():
                    sample = ProcSample.take(pid)
                    if sample is not None:
                        after[name] = (sample, time.monotonic() - t0)
                time.sleep(0.2)
            wall = time.monotonic() - t0
            meter.stop()
            load_after, cpus = load_average()
        finally:
            stop(proc)
            meter.close()
    per_node = {}
    for name in nodes:
        if before[name] is None or name not in after or after[name][1] <= 0:
            continue
        sample, seconds = after[name]
        cpu, wakeups, preempted = rates(before[name], sample, seconds)
        per_node[name] = {'cpu_percent': cpu, 'wakeups_per_s': wakeups,
                          'preempted_per_s': preempted, 'threads': sample.threads}
    topics = {t: {'hz': n / wall, 'kbytes_per_s': b / wall / 1e3}
              for t, (n, b) in sorted(meter.counts.items())}
    lat = meter.latency.latencies_ms
    return {'world': args.world, 'speedup': args.speedup, 'episode': args.episode,
            'wall_s': wall, 'ready_after_s': ready_at - started, 'sim_per_wall': meter.sim_rate(),
            'load_1min': [load_before, load_after], 'cpus': cpus, 'nodes': per_node,
            'topics': topics, 'image_to_belief_ms': sorted(lat),
            'image_to_observation_ms': sorted(meter.latency.observation_latencies_ms)}


def _median(values):
    import statistics
    return f'{statistics.median(values):.1f}' if values else '-'


def markdown(result):
    r = result
    lines = [f"**{r['world']} world, speed-up {r['speedup']:g}, "
             f"{'one episode' if r['episode'] else 'idle (--serve)'}, "
             f"{r['wall_s']:.1f} s window; load {r['load_1min'][0]:.2f} -> "
             f"{r['load_1min'][1]:.2f} on {r['cpus']} CPUs; sim/wall "
             f"{r['sim_per_wall']:.2f}**", '',
             '| node | CPU % of a core | wake-ups/s | preempted/s | threads |',
             '|---|---|---|---|---|']
    total = wake = 0.0
    for name, n in sorted(r['nodes'].items(), key=lambda kv: -kv[1]['cpu_percent']):
        total += n['cpu_percent']
        wake += n['wakeups_per_s']
        lines.append(f"| {name} | {n['cpu_percent']:.1f} | {n['wakeups_per_s']:.0f} | "
                     f"{n['preempted_per_s']:.0f} | {n['threads']} |")
    lines.append(f'| **all** | **{total:.1f}** | **{wake:.0f}** | | |')
    if r['topics']:
        lines += ['', '| topic | msgs/s (wall) | kB/s |', '|---|---|---|']
        for topic, t in sorted(r['topics'].items(), key=lambda kv: -kv[1]['hz']):
            lines.append(f"| {topic} | {t['hz']:.1f} | {t['kbytes_per_s']:.1f} |")
    lines += ['', f"image -> belief median {_median(r['image_to_belief_ms'])} ms "
              f"({len(r['image_to_belief_ms'])} updates); image -> aspect observation median "
              f"{_median(r['image_to_observation_ms'])} ms "
              f"({len(r['image_to_observation_ms'])} frames)"]
    return '\n'.join(lines)


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='graph_profile',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--world', choices=('mujoco', 'rules'), default='mujoco')
    parser.add_argument('--speedup', type=float, default=10.0)
    parser.add_argument('--seconds', type=float, default=20.0,
                        help='measuring window, wall s (an --episode ends it sooner)')
    parser.add_argument('--settle', type=float, default=2.0,
                        help='wall s between graph ready and the window')
    parser.add_argument('--episode', action='store_true',
                        help='run one recognition (start_graph.sh without --serve)')
    parser.add_argument('--object', type=int, default=None, help='hidden model index')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--params', default='', help='extra parameters YAML for the graph')
    parser.add_argument('--no-topics', action='store_true',
                        help='no per-topic counts (only /clock): the lightest probe')
    parser.add_argument('--json', default='')
    return parser.parse_args(argv)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == 'sim-step':
        from .sim_step_profile import main as sim_step_main
        return sim_step_main(argv[1:])
    args = parse_args(argv)
    result = measure(args)
    print(markdown(result))
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
