"""The graph split over a network link between two "hosts" on this machine
(docs/OFFBOARD.md): `start_graph.sh --part robot` in one network namespace (sim bridge,
robot_state, perception, skills) and `--part workstation --serve` in another (lifecycle
manager, belief, planner), joined by a veth pair limited to 20 Mbit/s with 20 ms of queue
(abp_bench.netns_link). Fast DDS runs over UDP only (the namespaces share /dev/shm, where
its shared-memory transport would carry the data past the link) and discovers over the
veth, so every message between the parts crosses the link: the interface byte counters
show it. The workstation's lifecycle manager brings the robot's nodes up over the link.

- With multicast discovery (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET): the link goes down for
  10 s while the first skill runs; the planner pauses naming what it lost, resumes when
  it is back, and the episode ends correct.
- Without multicast (off on the link; ROS_STATIC_PEERS names the other host): the link
  goes down past the planner's node_return_timeout; the goal aborts cleanly naming the
  lost nodes, and once the link is back the next goal succeeds, with no node restarted.
- Without multicast and without static peers: discovery through a Fast DDS discovery
  server that the robot part starts on its host (`start_graph.sh --discovery-server`,
  ROS_DISCOVERY_SERVER in every process); an episode ends correct.
- Perception on the workstation (`--perception-on workstation`): the detector there reads
  the sim's JPEG frames across the link (camera/image_raw/compressed), never the raw
  ones; an episode ends correct.

Rules world (fast), a uniform cube. Needs root and iproute2: skipped otherwise. The
namespaces (random names) are removed, and every process in them killed, whatever the
outcome. The 10-episode and 5x link-down figures are abp_bench.link_benchmark's.
"""

import json
import os
import pathlib
import subprocess
import sys

import pytest

from abp_belief.population import robot_set
from abp_bench.netns_link import (
    ROBOT,
    WORKSTATION,
    TwoHostLink,
    link_environment,
    unavailable,
)
from tests.helpers.graph import graph_processes, node_log_tails, stop_group

REPO = pathlib.Path(__file__).resolve().parents[2]
START_GRAPH = REPO / 'scripts' / 'start_graph.sh'
RECOGNIZE = REPO / 'install' / 'abp_bringup' / 'lib' / 'abp_bringup' / 'recognize'
SEED = 1
READY_TIMEOUT_S = 420
EPISODE_TIMEOUT_S = 300
LINK_DOWN_S = 10.0   # the fault injected: a fixed outage is the point
# Short enough that the abort comes soon after the lease (5 s, fastdds_link.xml) ends.
NODE_RETURN_TIMEOUT_S = 8.0


@pytest.fixture
def link():
    reason = unavailable()
    if reason:
        pytest.skip(f'two hosts on one machine need network namespaces: {reason}')
    two_hosts = TwoHostLink(rate_mbit=20, queue_ms=20)
    try:
        two_hosts.create()
        yield two_hosts
    finally:
        two_hosts.remove()   # kills every process left inside, deletes the namespaces


def uniform_cube():
    models = robot_set(seed=SEED)
    return next((i, name) for i, name in enumerate(models.names) if name.endswith('/u'))


class SplitGraph:
    """The two parts of one graph, each in its namespace, and goals sent from the
    workstation's namespace."""

    def __init__(self, ros_processes, link, tmp_path, static_peers, params=None,
                 discovery_server=None, graph_options=()):
        self.processes, self.link, self.tmp_path = ros_processes, link, tmp_path
        self.index, self.object_id = uniform_cube()
        # UDP only, and one participant lease for every process on both sides.
        self.env = {**os.environ, **link_environment(),
                    'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
        self.env.pop('ROS_STATIC_PEERS', None)
        graph = ['--world', 'rules', '--seed', SEED, '--object', self.index, '--no-build']
        if params:
            graph += ['--params', params]
        graph += list(graph_options)
        if discovery_server:
            graph += ['--discovery-server', discovery_server]
            # The goals' clients are the server's clients too (start_graph.sh sets it
            # for the graph's nodes).
            self.env['ROS_DISCOVERY_SERVER'] = discovery_server
        self.log_dir = {side: tmp_path / f'logs-{side}' for side in (ROBOT, WORKSTATION)}
        self.parts = {}
        for side, extra in ((ROBOT, ()), (WORKSTATION, ('--serve',))):
            env = dict(self.env)
            if static_peers:
                other = WORKSTATION if side == ROBOT else ROBOT
                env['ROS_STATIC_PEERS'] = link.address[other]
            self.parts[side] = ros_processes.start(link.command(side, [
                START_GRAPH, '--part', side, *graph, *extra,
                '--log-dir', self.log_dir[side]]), env=env)
            if side == WORKSTATION:
                self.env = env   # the goals' clients run beside the workstation part
        ros_processes.wait_for_line(self.parts[ROBOT], 'robot part up', READY_TIMEOUT_S)
        ros_processes.wait_for_line(self.parts[WORKSTATION], 'graph up: serving',
                                    READY_TIMEOUT_S)

    def goal(self, name):
        """Start one Recognize goal from the workstation's namespace: (process, result file)."""
        result = self.tmp_path / f'result-{name}.json'
        proc = self.processes.start(self.link.command(WORKSTATION, [
            RECOGNIZE, '--timeout', EPISODE_TIMEOUT_S, '--result-json', result]), env=self.env)
        return proc, result

    def finish(self, proc, result):
        self.processes.wait_for_line(proc, 'result:', EPISODE_TIMEOUT_S + 30)
        proc.wait(timeout=30)
        assert result.exists(), self.logs()
        return json.loads(result.read_text())

    def wait_ready(self):
        """The lifecycle manager's graph_ready, heard in the workstation's namespace."""
        waiter = self.processes.start(self.link.command(WORKSTATION, [
            sys.executable, '-m', 'abp_bench.link_wait', '--timeout', READY_TIMEOUT_S]),
            env=self.env)
        self.processes.wait_for_line(waiter, 'graph ready', READY_TIMEOUT_S + 10)

    def stop(self):
        """Ctrl-C to each part, the workstation first (its lifecycle manager still reaches
        the robot's nodes while it shuts down), each given time to stop its nodes: a part
        killed before its trap ran would leave its nodes running."""
        for side in (WORKSTATION, ROBOT):
            stop_group(self.parts[side], int_grace=60.0, term_grace=20.0)

    def log(self, side, node):
        return (self.log_dir[side] / f'{node}.log').read_text(errors='replace')

    def logs(self):
        return ''.join(node_log_tails(d, 40) for d in self.log_dir.values())


def assert_the_traffic_crossed_the_link(link, before):
    """Both directions carried the graph's messages (not only discovery): the robot's
    observations and clock one way, goals and beliefs' effects the other."""
    after = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
    received = {side: after[side]['rx_bytes'] - before[side]['rx_bytes'] for side in after}
    # (What was sent while the link was down is lost: received, not sent, is the proof.)
    assert received[WORKSTATION] > 100_000 and received[ROBOT] > 10_000, received
    return {ROBOT: received[WORKSTATION], WORKSTATION: received[ROBOT]}


def assert_fast_dds_uses_the_link_not_shared_memory(link):
    """Fast DDS bound its sockets to the link's address in each namespace (its unicast
    locators), and no process maps a Fast DDS shared-memory segment (the namespaces share
    /dev/shm: its transport or data sharing would carry the data past the link)."""
    for side in (ROBOT, WORKSTATION):
        local = {line.split()[3].rsplit(':', 1)[0] for line in link.sockets(side)
                 if 'users:' in line}
        assert link.address[side] in local, (side, local)
        assert local <= {'0.0.0.0', '*', '127.0.0.1', link.address[side], '239.255.0.1'}, local
        fast_dds = {f for f in link.shared_memory_files(side)
                    if 'fastrtps' in f or 'fast_datasharing' in f}
        assert not fast_dds, (side, fast_dds)


@pytest.mark.timeout(READY_TIMEOUT_S + 2 * EPISODE_TIMEOUT_S + 120)
def test_an_episode_survives_a_10_s_link_drop_with_multicast_discovery(
        ros_processes, link, tmp_path):
    assert link.multicast_reaches(ROBOT) and link.multicast_reaches(WORKSTATION)
    graph = SplitGraph(ros_processes, link, tmp_path, static_peers=False)
    before = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
    proc, result_file = graph.goal('drop')
    # The first skill is on its way: drop the link under it.
    ros_processes.wait_for_line(proc, 'plan ', EPISODE_TIMEOUT_S)
    link.set_up(False)
    try:
        # The outage (a fixed time is the fault); the goal cannot end without the robot.
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=LINK_DOWN_S)
    finally:
        link.set_up(True)
    result = graph.finish(proc, result_file)
    planner_log = graph.log(WORKSTATION, 'planner')
    assert result['correct'] and result['object_id'] == graph.object_id, \
        (result, graph.logs())
    # The planner paused naming what it lost, and went on when it was back. What it
    # finds lost depends on what it was doing when the link fell: waiting for an
    # action's evidence, it misses the observations and the skill servers (each lease
    # ends on its own schedule); sending a skill goal, it finds the skill servers gone
    # and they may be back before it looks at the observations.
    lines = planner_log.splitlines()
    paused = [line for line in lines if 'episode paused:' in line]
    back = [line for line in lines if 'back: re-observing' in line]
    assert paused and back, planner_log[-4000:]
    lost = [what for what in ('skill server', 'aspect observations') if what in paused[0]]
    assert lost and all(what in back[0] for what in lost), planner_log[-4000:]
    sent = assert_the_traffic_crossed_the_link(link, before)
    assert_fast_dds_uses_the_link_not_shared_memory(link)
    print(f'two hosts, multicast: {result}; bytes robot->workstation '
          f'{sent[ROBOT]}, workstation->robot {sent[WORKSTATION]}')
    # No node restarted: each robot-side node's log shows one start.
    for node in ('sim_bridge', 'skill_servers', 'aspect_matcher'):
        assert 'restarting it' not in graph.log(ROBOT, node), node
    graph.stop()
    ros_processes.stop_all()
    assert not graph_processes(), 'the graph left processes behind'


@pytest.mark.timeout(READY_TIMEOUT_S + 3 * EPISODE_TIMEOUT_S + 120)
def test_a_link_down_past_the_timeout_aborts_cleanly_without_multicast(
        ros_processes, link, tmp_path):
    params = tmp_path / 'planner.yaml'
    params.write_text('/**/planner:\n  ros__parameters:\n'
                      f'    node_return_timeout: {NODE_RETURN_TIMEOUT_S}\n')
    link.set_multicast(False)
    # Discovery can go by the static peers only: no multicast leaves either host.
    assert not any(link.multicast_reaches(side) for side in (ROBOT, WORKSTATION))
    graph = SplitGraph(ros_processes, link, tmp_path, static_peers=True, params=params)
    before = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
    proc, result_file = graph.goal('abort')
    ros_processes.wait_for_line(proc, 'plan ', EPISODE_TIMEOUT_S)
    link.set_up(False)
    try:
        # The event: the goal's end, an abort (the link stays down until then).
        result = graph.finish(proc, result_file)
    finally:
        link.set_up(True)
    assert result['status'] == 'aborted', result
    assert 'not back within' in result['reason'], result
    assert 'skill server' in result['reason'] and 'aspect observations' in result['reason'], \
        result
    # The next goal, once the graph is whole again, succeeds.
    graph.wait_ready()
    proc, result_file = graph.goal('after')
    result = graph.finish(proc, result_file)
    assert result['correct'] and result['object_id'] == graph.object_id, \
        (result, graph.logs())
    assert_the_traffic_crossed_the_link(link, before)
    assert_fast_dds_uses_the_link_not_shared_memory(link)
    for node in ('sim_bridge', 'skill_servers', 'aspect_matcher', 'belief', 'planner'):
        side = WORKSTATION if node in ('belief', 'planner') else ROBOT
        assert 'restarting it' not in graph.log(side, node), node
    graph.stop()
    ros_processes.stop_all()
    assert not graph_processes(), 'the graph left processes behind'


@pytest.mark.timeout(READY_TIMEOUT_S + EPISODE_TIMEOUT_S + 120)
def test_discovery_through_a_discovery_server_without_multicast(ros_processes, link, tmp_path):
    link.set_multicast(False)
    assert not any(link.multicast_reaches(side) for side in (ROBOT, WORKSTATION))
    server = f'{link.address[ROBOT]}:11811'
    graph = SplitGraph(ros_processes, link, tmp_path, static_peers=False,
                       discovery_server=server)
    assert 'ROS_STATIC_PEERS' not in graph.env
    # The robot part owns the server's address: it started the server there, and only it.
    robot_log = (graph.log_dir[ROBOT] / 'discovery_server.log')
    assert robot_log.exists(), graph.logs()
    assert not (graph.log_dir[WORKSTATION] / 'discovery_server.log').exists()
    # (Fast DDS binds its unicast port on every address, filtering by interface.)
    def server_sockets(side):
        return [line for line in link.sockets(side)
                if ':11811 ' in line and 'fast-discovery' in line]
    assert server_sockets(ROBOT) and not server_sockets(WORKSTATION), link.sockets(ROBOT)
    before = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
    proc, result_file = graph.goal('server')
    result = graph.finish(proc, result_file)
    assert result['correct'] and result['object_id'] == graph.object_id, \
        (result, graph.logs())
    assert_the_traffic_crossed_the_link(link, before)
    assert_fast_dds_uses_the_link_not_shared_memory(link)
    graph.stop()
    ros_processes.stop_all()
    assert not graph_processes(), 'the graph left processes behind'
    assert not graph_processes(markers=(b'fast-discovery-server',)), \
        'the discovery server outlived the robot part'


@pytest.mark.timeout(READY_TIMEOUT_S + EPISODE_TIMEOUT_S + 120)
def test_perception_on_the_workstation_reads_jpeg_across_the_link(ros_processes, link,
                                                                  tmp_path):
    graph = SplitGraph(ros_processes, link, tmp_path, static_peers=False,
                       graph_options=['--perception-on', 'workstation', '--jpeg-quality', '90'])
    assert (graph.log_dir[WORKSTATION] / 'artag_detector.log').exists()
    assert not (graph.log_dir[ROBOT] / 'artag_detector.log').exists()
    before = {side: link.counters(side) for side in (ROBOT, WORKSTATION)}
    proc, result_file = graph.goal('jpeg')
    result = graph.finish(proc, result_file)
    assert result['correct'] and result['object_id'] == graph.object_id, \
        (result, graph.logs())
    detector_log = graph.log(WORKSTATION, 'artag_detector')
    assert 'in compressed images on /camera/image_raw/compressed' in detector_log
    assert 'rejected input on /camera/image_raw/compressed (decode' not in detector_log
    # The detector runs only on the workstation and the images come only from the robot:
    # a correct episode (its observations) means the JPEG frames crossed the link.
    assert_the_traffic_crossed_the_link(link, before)
    assert_fast_dds_uses_the_link_not_shared_memory(link)
    graph.stop()
    ros_processes.stop_all()
    assert not graph_processes(), 'the graph left processes behind'
