"""How long the graph takes to come up, and where the time goes (issue 39).

    python -m abp_bench.startup_benchmark --runs 5 --world rules [--one-process]

Each run starts `scripts/start_graph.sh --serve --no-build` (the bootstrap is done), times
the script's `graph ready` line from the moment it was started, then stops the graph
with SIGTERM. From the logs of the run it breaks the time down per node: `up` when the
process had imported its modules and built its node (its `waiting for a lifecycle
manager` line), `configured` and `activated` when the lifecycle manager logged them
(in --one-process mode every node is up when the container is). Prints one line per run
and the medians; --idle S also measures the idle graph's CPU; --json writes every figure.
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .graph_benchmark import repo_root, stop_graph, terminate_with_parent

READY = '[start_graph] graph ready'
# A ROS 2 log line: [LEVEL] [seconds.nanoseconds] [logger]: message
LOG_LINE = re.compile(r'\[(?:INFO|WARN|ERROR)\] \[(\d+\.\d+)\] \[([^\]]+)\]: (.*)')
MANAGER_STEP = re.compile(r'^(\w+): (configured|activated)$')


def session_cpu_s(session):
    """CPU seconds (user + system) used so far by the live processes of a session."""
    total = 0
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue   # gone meanwhile
        if int(fields[3]) == session:   # field 6 of stat: the session id
            total += int(fields[11]) + int(fields[12])   # utime, stime (clock ticks)
    return total / os.sysconf('SC_CLK_TCK')


def run_once(world, one_process, log_dir, timeout, idle_s=0.0):
    command = [str(repo_root() / 'scripts' / 'start_graph.sh'), '--serve', '--no-build',
               '--world', world, '--log-dir', str(log_dir)]
    if one_process:
        command.append('--one-process')
    started = time.time()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True,
                            preexec_fn=terminate_with_parent)
    ready_s, output = None, []
    deadline = time.monotonic() + timeout
    try:
        for line in proc.stdout:
            output.append(line)
            if READY in line:
                ready_s = time.time() - started
                break
            if time.monotonic() > deadline:
                break
        idle = None
        if ready_s is not None and idle_s > 0:
            # The idle graph (no goal): its processes' CPU over idle_s s of wall time,
            # after as long again to settle.
            time.sleep(idle_s)
            cpu, wall = session_cpu_s(proc.pid), time.monotonic()
            time.sleep(idle_s)
            idle = (session_cpu_s(proc.pid) - cpu) / (time.monotonic() - wall)
    finally:
        stop_graph(proc)
    if ready_s is None:
        raise RuntimeError('no graph ready:\n' + ''.join(output[-30:]))
    return {'ready_s': ready_s, 'idle_cores': idle, 'nodes': breakdown(log_dir, started)}


def breakdown(log_dir, started):
    """{node: {'up': s, 'configured': s, 'activated': s}} in seconds after the start."""
    nodes = {}
    for log in Path(log_dir).glob('*.log'):
        for line in log.read_text(errors='replace').splitlines():
            match = LOG_LINE.search(line)
            if not match:
                continue
            stamp, logger, message = float(match[1]), match[2], match[3]
            if 'waiting for a lifecycle manager' in message:
                nodes.setdefault(logger, {}).setdefault('up', stamp - started)
            step = MANAGER_STEP.match(message)
            if logger == 'lifecycle_manager' and step:
                nodes.setdefault(step[1], {}).setdefault(step[2], stamp - started)
    return nodes


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--world', choices=('rules', 'mujoco'), default='rules')
    parser.add_argument('--one-process', action='store_true')
    parser.add_argument('--timeout', type=float, default=300.0)
    parser.add_argument('--idle', type=float, default=0.0, metavar='S',
                        help='after graph ready, wait S s, then measure the CPU of the idle '
                        'graph (every process of the run) over S s')
    parser.add_argument('--json', help='write every run here')
    args = parser.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory(prefix='startup-') as tmp:
        for i in range(args.runs):
            run = run_once(args.world, args.one_process, Path(tmp) / f'run{i}', args.timeout,
                           args.idle)
            runs.append(run)
            steps = ', '.join(f'{n} {v.get("up", float("nan")):.1f}/'
                              f'{v.get("configured", float("nan")):.1f}/'
                              f'{v.get("activated", float("nan")):.1f}'
                              for n, v in sorted(run['nodes'].items()))
            idle = ('' if run['idle_cores'] is None else
                    f', idle {100 * run["idle_cores"]:.0f} % of a core')
            print(f'run {i}: graph ready {run["ready_s"]:.2f} s{idle}  '
                  f'(up/configured/activated: {steps})', flush=True)
    median = statistics.median(r['ready_s'] for r in runs)
    print(f'{args.world} world{" one process" if args.one_process else ""}: graph ready '
          f'median {median:.2f} s over {len(runs)} runs '
          f'(min {min(r["ready_s"] for r in runs):.2f}, '
          f'max {max(r["ready_s"] for r in runs):.2f})')
    idle = [r['idle_cores'] for r in runs if r['idle_cores'] is not None]
    if idle:
        print(f'idle graph: median {100 * statistics.median(idle):.0f} % of one core')
    if args.json:
        Path(args.json).write_text(json.dumps({'world': args.world,
                                               'one_process': args.one_process,
                                               'median_ready_s': median, 'runs': runs},
                                              indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
