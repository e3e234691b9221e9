"""`link_benchmark`: the graph split over a rate-limited link between two network
namespaces of this machine (docs/OFFBOARD.md): episodes, link drops, bytes per topic.

    sudo python -m abp_bench.link_benchmark [--episodes 10] [--drops 5] [--past-timeout 5]
        [--no-multicast [--discovery static-peers|server]] [--loopback]
        [--perception-on robot|workstation] [--jpeg-quality Q] [--world rules] [--seed S]
        [--rate-mbit 20] [--queue-ms 20] [--link-down-s 10] [--node-return-timeout 8]
        [--json FILE] [--no-build]

`start_graph.sh --part robot` runs in one namespace and `--part workstation --serve` in
the other, joined by a veth pair (abp_bench.netns_link: `tbf` at --rate-mbit with
--queue-ms of queue), Fast DDS over UDP only. A driver in the workstation's namespace
hides a random cube of the robot set in the sim before each goal and sends it:

- `--episodes` clean episodes;
- `--drops` episodes with the link down for --link-down-s while the first skill runs (the
  planner must pause, naming what it lost, and the episode end correct);
- `--past-timeout` episodes with the link down until the goal ends: it must abort naming
  the lost nodes (the planner's node_return_timeout is --node-return-timeout), and the
  next goal, sent once the manager says the graph is whole again, must succeed.

Meters beside each part (abp_bench.link_meter) count the serialized bytes of every topic
that crosses the link, and the veth's counters give the total on the wire. With
`--loopback` both parts run in the same namespace (over its loopback, same transports):
the baseline for the latency from image (its camera_info, published with it) to the
belief that includes it. `--no-multicast`: multicast off on the link, discovery through
ROS_STATIC_PEERS (`--discovery static-peers`, the default) or a Fast DDS discovery server
on the robot's host (`--discovery server`: `start_graph.sh --discovery-server`; the meters
run as its super clients, SUPER_CLIENT_PROFILE, to see every topic).
`--perception-on workstation`: the detector and matcher run on the workstation and read
JPEG frames (`--jpeg-quality`) across the link. Needs root. Exit code 0 when every
episode met its expectation.
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

from .graph_benchmark import repo_root, terminate_with_parent
from .netns_link import ROBOT, WORKSTATION, TwoHostLink, link_environment, unavailable

READY_TIMEOUT_S = 600.0
EPISODE_TIMEOUT_S = 600.0
DISCOVERY_SERVER_PORT = 11811
# A participant that sees every topic through the discovery server (id 0), as ros2cli's
# daemon must; the lease of fastdds_link.xml, as every process of the split graph.
SUPER_CLIENT_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <participant profile_name="abp_link_super_client" is_default_profile="true">
      <rtps>
        <builtin>
          <discovery_config>
            <discoveryProtocol>SUPER_CLIENT</discoveryProtocol>
            <discoveryServersList>
              <RemoteServer prefix="44.53.00.5f.45.50.52.4f.53.49.4d.41">
                <metatrafficUnicastLocatorList>
                  <locator><udpv4><address>{address}</address><port>{port}</port></udpv4></locator>
                </metatrafficUnicastLocatorList>
              </RemoteServer>
            </discoveryServersList>
            <leaseDuration><sec>5</sec></leaseDuration>
            <leaseAnnouncement><sec>1</sec></leaseAnnouncement>
          </discovery_config>
        </builtin>
      </rtps>
    </participant>
  </profiles>
</dds>
"""


class Process:
    """A child process in its own session, its output kept by a reader thread."""

    def __init__(self, argv, env):
        self.lines = []
        self._cond = threading.Condition()
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env, start_new_session=True,
                                     preexec_fn=terminate_with_parent)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip('\n'))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def wait_line(self, text, timeout):
        deadline = time.monotonic() + timeout
        with self._cond:
            while not any(text in line for line in self.lines):
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self._cond.wait(0.2)):
                    raise RuntimeError(f'no "{text}" within {timeout:.0f} s:\n' +
                                       '\n'.join(self.lines[-30:]))
                self._cond.wait(min(left, 1.0))

    def stop(self, grace=20.0):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


def median_ms(values):
    return round(1000.0 * statistics.median(values), 2) if values else None


def latencies(robot_report, workstation_report):
    """Seconds from each image's camera_info (robot side) to the first belief with its
    stamp (workstation side)."""
    images = next(iter(robot_report['stamps'].values()), {})
    beliefs = next(iter(workstation_report['stamps'].values()), {})
    return sorted(beliefs[s] - images[s] for s in beliefs if s in images)


def topic_table(reports):
    """Rows (topic, direction, messages/s, bytes/s) of the topics that crossed the link."""
    rows = []
    for report in reports:
        window = max(report['ended'] - report['started'], 1e-9)
        for topic, entry in sorted(report['topics'].items()):
            if entry['crosses']:
                rows.append({'topic': topic, 'type': entry['type'],
                             'from': report['side'],
                             'to': ', '.join(entry['remote_subscribers']),
                             'messages_per_s': round(entry['messages'] / window, 2),
                             'bytes_per_s': round(entry['bytes'] / window, 1)})
    return sorted(rows, key=lambda r: -r['bytes_per_s'])


def orchestrate(args):
    reason = unavailable()
    if reason:
        print(f'link_benchmark: {reason}', file=sys.stderr)
        return 2
    work = pathlib.Path(args.log_dir or tempfile.mkdtemp(prefix='link-benchmark-'))
    work.mkdir(parents=True, exist_ok=True)
    if not args.no_build:
        subprocess.run([str(repo_root() / 'scripts' / 'bootstrap.sh')], check=True)
    params = work / 'planner.yaml'
    params.write_text('/**/planner:\n  ros__parameters:\n'
                      f'    node_return_timeout: {args.node_return_timeout}\n')
    processes = []
    with TwoHostLink(rate_mbit=args.rate_mbit, queue_ms=args.queue_ms) as link:
        ws_side = ROBOT if args.loopback else WORKSTATION
        if args.no_multicast:
            link.set_multicast(False)
        try:
            env = {**os.environ, **link_environment(), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
            env.pop('ROS_STATIC_PEERS', None)
            graph = ['--world', args.world, '--seed', str(args.seed), '--no-build',
                     '--params', str(params), '--speedup', str(args.speedup),
                     '--perception-on', args.perception_on]
            if args.jpeg_quality is not None:
                graph += ['--jpeg-quality', str(args.jpeg_quality)]
            server = f'{link.address[ROBOT]}:{DISCOVERY_SERVER_PORT}'
            if args.discovery == 'server':
                graph += ['--discovery-server', server]
            envs, meter_envs = {}, {}
            for part, side in ((ROBOT, ROBOT), (WORKSTATION, ws_side)):
                envs[part] = dict(env)
                if args.no_multicast and not args.loopback and args.discovery == 'static-peers':
                    envs[part]['ROS_STATIC_PEERS'] = link.address[
                        WORKSTATION if part == ROBOT else ROBOT]
                meter_envs[part] = dict(envs[part])
                if args.discovery == 'server':
                    # start_graph.sh sets ROS_DISCOVERY_SERVER for the graph; the driver
                    # is a client like the nodes, the meters super clients.
                    envs[part]['ROS_DISCOVERY_SERVER'] = server
                    profile = work / 'super_client.xml'
                    profile.write_text(SUPER_CLIENT_PROFILE.format(
                        address=link.address[ROBOT], port=DISCOVERY_SERVER_PORT))
                    meter_envs[part]['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)
                extra = ['--serve'] if part == WORKSTATION else []
                processes.append(Process(link.command(side, [
                    repo_root() / 'scripts' / 'start_graph.sh', '--part', part, *graph,
                    *extra, '--log-dir', work / f'logs-{part}']), envs[part]))
            robot_part, ws_part = processes
            robot_part.wait_line('robot part up', READY_TIMEOUT_S)
            ws_part.wait_line('graph up: serving', READY_TIMEOUT_S)
            before = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
            meters = {}
            for part, side in ((ROBOT, ROBOT), (WORKSTATION, ws_side)):
                meters[part] = Process(link.command(side, [
                    sys.executable, '-m', 'abp_bench.link_meter', '--side', part,
                    '--perception', args.perception_on, '--out',
                    work / f'meter-{part}.json']), meter_envs[part])
                processes.append(meters[part])
                meters[part].wait_line('metering', 60)
            started = time.time()
            driver = Process(link.command(ws_side, [
                sys.executable, '-m', 'abp_bench.link_driver', '--episodes', args.episodes,
                '--drops', args.drops, '--past-timeout', args.past_timeout, '--seed',
                args.seed, '--link-down-s', args.link_down_s, '--link-suffix',
                link.interface[ROBOT][len('abpr'):], '--planner-log',
                work / 'logs-workstation' / 'planner.log', '--json', work / 'episodes.json']),
                envs[WORKSTATION])
            processes.append(driver)
            driver.proc.wait()
            elapsed = time.time() - started
            for meter in meters.values():
                meter.stop()
            after = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
        finally:
            for process in reversed(processes):
                process.stop()
        print('\n'.join(driver.lines[-5:]))
        for part, meter in meters.items():
            if not (work / f'meter-{part}.json').exists():
                print(f'the {part} meter wrote no report:\n' + '\n'.join(meter.lines[-20:]))
        episodes = json.loads((work / 'episodes.json').read_text())
        reports = {part: json.loads((work / f'meter-{part}.json').read_text())
                   if (work / f'meter-{part}.json').exists() else
                   {'side': part, 'started': 0.0, 'ended': 1.0, 'topics': {}, 'stamps': {}}
                   for part in (ROBOT, WORKSTATION)}
    wire = {f'{a}_to_{b}': (after[b]['rx_bytes'] - before[b]['rx_bytes']) / elapsed
            for a, b in ((ROBOT, WORKSTATION), (WORKSTATION, ROBOT))}
    lat = latencies(reports[ROBOT], reports[WORKSTATION])
    summary = {
        'rate_mbit': args.rate_mbit, 'queue_ms': args.queue_ms, 'loopback': args.loopback,
        'multicast': not args.no_multicast, 'world': args.world, 'seed': args.seed,
        'discovery': ('multicast' if not args.no_multicast else args.discovery),
        'perception_on': args.perception_on, 'jpeg_quality': args.jpeg_quality,
        'seconds': round(elapsed, 1),
        'wire_bytes_per_s': {k: round(v, 1) for k, v in wire.items()},
        'wire_mbit_per_s': round(sum(wire.values()) * 8 / 1e6, 3),
        'topics': topic_table(reports.values()),
        'image_to_belief_ms': {'median': median_ms(lat), 'count': len(lat),
                               'p90': round(1000 * lat[int(0.9 * (len(lat) - 1))], 2)
                               if lat else None},
        'episodes': episodes['episodes'], 'passed': episodes['passed'],
        'logs': str(work)}
    text = json.dumps(summary, indent=2)
    print(text)
    if args.json:
        pathlib.Path(args.json).write_text(text)
    return 0 if episodes['passed'] else 1


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m abp_bench.link_benchmark',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--episodes', type=int, default=10, help='clean episodes (10)')
    parser.add_argument('--drops', type=int, default=5,
                        help='episodes with a link drop of --link-down-s mid-episode (5)')
    parser.add_argument('--past-timeout', type=int, default=5,
                        help='episodes with the link down past node_return_timeout, each '
                             'followed by a goal that must succeed (5)')
    parser.add_argument('--link-down-s', type=float, default=10.0)
    parser.add_argument('--node-return-timeout', type=float, default=8.0,
                        help="the planner's node_return_timeout, s (8)")
    parser.add_argument('--no-multicast', action='store_true',
                        help='multicast off on the link; discovery by ROS_STATIC_PEERS')
    parser.add_argument('--discovery', choices=('static-peers', 'server'),
                        default='static-peers',
                        help='with --no-multicast: ROS_STATIC_PEERS, or a Fast DDS discovery '
                             'server on the robot host (default static-peers)')
    parser.add_argument('--loopback', action='store_true',
                        help='both parts in one namespace: the latency baseline')
    parser.add_argument('--perception-on', choices=('robot', 'workstation'), default='robot',
                        help='where the detector and matcher run: workstation = JPEG frames '
                             'across the link (default robot)')
    parser.add_argument('--jpeg-quality', type=int, choices=range(1, 101), metavar='1-100',
                        help="with --perception-on workstation: the sim's JPEG quality (90)")
    parser.add_argument('--world', choices=('rules', 'mujoco'), default='rules')
    parser.add_argument('--speedup', type=float, default=10.0)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--rate-mbit', type=float, default=20.0)
    parser.add_argument('--queue-ms', type=float, default=20.0)
    parser.add_argument('--log-dir', help='where logs and reports go (default: a temp dir)')
    parser.add_argument('--json', help='write the summary here')
    parser.add_argument('--no-build', action='store_true')
    args = parser.parse_args(argv)
    if args.discovery == 'server' and (args.loopback or not args.no_multicast):
        parser.error('--discovery server goes with --no-multicast, across the link')
    if args.jpeg_quality is not None and args.perception_on != 'workstation':
        parser.error('--jpeg-quality goes with --perception-on workstation')
    if args.loopback:
        args.drops = args.past_timeout = 0   # no link to drop
    return orchestrate(args)


if __name__ == '__main__':
    sys.exit(main())
