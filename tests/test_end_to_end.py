"""End to end over the real graph in simulation, through scripts/start_graph.sh.

The nodes (sim bridge, robot_state, detector, matcher, belief, the skill servers,
planner) talk over DDS; the hidden cube is seeded. Eccentric twins are
visually identical to their uniform sibling, so recognising them proves that the planner
chose the manual action that separates them and that the sim's physics, the skills and
the perception agree. Two graphs:

- `rules` world (contact rules, flat renderer: fast), under a namespace (`--namespace
  robot1`: every node, topic, service and action under /robot1), started once with
  `start_graph.sh --serve`: three goals in turn, a uniform cube and the twins m+z and m+y,
  each hidden by the sim bridge's `model_index` and `reset_world` (abp_bench.soak's
  driver, which the crash test also uses).
- `mujoco` world (physics and MuJoCo camera, start_graph.sh's default), one uniform cube
  through start_graph.sh's own `recognize` client, with `--one-process` (every managed node
  in one graph_container process, issue 39; the rules graph and the crash test run one
  process per node): its trace, its result file, its exit code, every node's parameters
  and that it leaves no process behind.
- the same with the second robot, rover5 (`--robot-profile`: one arm, ORBIT and PUSH only):
  its profile alone changes the robot.

A node killed mid-episode is the crash test's (tests/test_crash_recovery.py: every node,
the belief's episode must still end correct).
"""

import json
import pathlib
import types

import pytest

from abp_belief.cube import MANUAL_ACTIONS
from abp_belief.population import robot_set
from tests.helpers.graph import dds_transports, graph_processes, node_log_tails, run_to_end

REPO = pathlib.Path(__file__).resolve().parent.parent
SEED = 1
# start_graph.sh's own deadline for the Recognize goal, and the driver's per goal; the
# test's (pytest-timeout) is longer, so that a slow episode fails with its trace and its
# graph stopped.
EPISODE_TIMEOUT_S = 480
READY_TIMEOUT_S = 600
NAMESPACE = 'robot1'


def run_episode(tmp_path, object_index, extra=()):
    result_file = tmp_path / f'result-{object_index}.json'
    log_dir = tmp_path / f'logs-{object_index}'
    code, trace, _ = run_to_end(
        [str(REPO / 'scripts' / 'start_graph.sh'), '--seed', str(SEED), '--object',
         str(object_index), '--result-json', str(result_file), '--log-dir', str(log_dir),
         '--timeout', str(EPISODE_TIMEOUT_S), *extra],
        EPISODE_TIMEOUT_S + 60, tmp_path / f'output-{object_index}.txt')
    if code != 0 or not result_file.exists():
        # pytest keeps only the last few tmp dirs: the nodes' logs go into the report.
        trace += node_log_tails(log_dir)
    assert result_file.exists(), trace
    return code, json.loads(result_file.read_text()), trace


def cube_with_mass(models, mass_name):
    """The first model with this mass ('u': a uniform cube, else an eccentric twin)."""
    return next(i for i, name in enumerate(models.names) if name.endswith('/' + mass_name))


@pytest.mark.timeout(READY_TIMEOUT_S + 3 * EPISODE_TIMEOUT_S + 180)
def test_cubes_are_recognised_one_goal_after_another_on_a_namespaced_rules_graph(
        tmp_path, rclpy_context):
    from abp_bench import soak
    models = robot_set(seed=SEED)
    cubes = {mass: cube_with_mass(models, mass) for mass in ('u', 'm+z', 'm+y')}
    log_dir = tmp_path / 'logs'
    graph = soak.Graph(types.SimpleNamespace(
        world='rules', seed=SEED, speedup=10.0, no_build=True, faults=False,
        namespace=NAMESPACE), log_dir, cubes['u'])
    driver = soak.Driver(rclpy_context, NAMESPACE)
    failures = []
    try:
        assert driver.spin_until(lambda: driver.graph_ready, READY_TIMEOUT_S), \
            graph.tail() + node_log_tails(log_dir)
        assert f'sim (rules world) graph under /{NAMESPACE}' in graph.tail(1000), graph.tail()
        # Every node under the namespace, none at the root (the ROS graph says so). The
        # graph's node lists can reach this process after graph_ready: waited for.
        expected = {(name, f'/{NAMESPACE}') for name in soak.GRAPH_NODES}
        driver.spin_until(
            lambda: expected <= set(driver.node.get_node_names_and_namespaces()), 60)
        nodes = driver.node.get_node_names_and_namespaces()
        assert expected <= set(nodes), sorted(nodes)
        assert not {n for n, ns in nodes if ns == '/'} & set(soak.GRAPH_NODES), sorted(nodes)
        # This session's LOCALHOST range: the graph stays on this machine, over UDP on the
        # loopback interface, with no shared memory (start_graph.sh; docs/RECOVERY.md).
        loopback = '0100007F'
        for pid, command in graph_processes(with_pids=True):
            shm, addresses = dds_transports(pid)
            assert not shm and addresses == {loopback}, (command, shm, addresses)
        for episode, (mass, index) in enumerate(cubes.items()):
            driver.hide(index, models.names[index], failure_seed=0)
            record = soak.run_episode(driver, graph, episode, models.names[index],
                                      EPISODE_TIMEOUT_S)
            # The executed actions come on their own topic: wait until all are in.
            driver.spin_until(lambda: len(driver.executed) >= record.get('actions', 0), 10)
            executed = [msg.action for msg in driver.executed]
            print(f'{mass}: {record} executed {executed}')
            if not (record['outcome'] == 'succeeded' and record['correct']
                    and record['answer'] == models.names[index]
                    and record['posterior'] >= 0.95):
                failures.append((mass, record))
            elif len(executed) != record['actions']:
                failures.append((mass, f'{len(executed)} executed actions heard, '
                                 f"{record['actions']} in the result"))
            elif mass != 'u' and not set(MANUAL_ACTIONS) & set(executed):
                # A twin is told apart only by a manual action.
                failures.append((mass, f'no manual action: {executed}'))
    finally:
        driver.close()
        stopped = graph.stop()
    assert not failures, f'{failures}\n{graph.tail(200)}' + node_log_tails(log_dir)
    assert stopped, graph.tail()
    assert not graph_processes(), 'start_graph.sh left processes behind'


@pytest.mark.timeout(EPISODE_TIMEOUT_S + 180)
def test_a_uniform_cube_is_recognised_in_the_mujoco_world_by_a_one_process_graph(tmp_path):
    from abp_common.graph_nodes import GRAPH_NODE_NAMES
    models = robot_set(seed=SEED)
    index = cube_with_mass(models, 'u')
    code, result, trace = run_episode(tmp_path, index, ('--world', 'mujoco', '--one-process',
                                                        '--planner', 'abp'))
    assert code == 0, trace
    assert 'sim (mujoco world)' in trace
    # One process: the container's log has every node's lines, no node has a log of its own;
    # the per-node parameters (the sim bridge's world, the planner's mode) reached them.
    log_dir = tmp_path / f'logs-{index}'
    container_log = (log_dir / 'graph_container.log').read_text()
    for node in GRAPH_NODE_NAMES:
        assert f'[{node}]: active' in container_log, (node, container_log[-3000:])
        assert not (log_dir / f'{node}.log').exists(), node
    assert 'sim_bridge: mujoco world' in container_log, container_log[-3000:]
    assert '(mode abp,' in container_log, container_log[-3000:]
    assert result['ground_truth'] == models.names[index]
    assert result['correct'] and result['object_id'] == models.names[index], trace
    assert result['posterior'] >= 0.95
    executed = [line.split()[2] for line in trace.splitlines() if line.startswith('action ')]
    assert len(executed) == result['actions']
    assert not graph_processes(), 'start_graph.sh left processes behind'


@pytest.mark.timeout(EPISODE_TIMEOUT_S + 180)
def test_the_second_robot_recognises_a_cube_in_the_mujoco_world_from_its_profile_alone(
        tmp_path):
    """rover5 (one arm, ORBIT and PUSH only; abp_description/profiles/rover5.yaml) through
    the same script with only --robot-profile added: its URDF, frames, controllers and
    learned ATG tables reach every node from the profile, and the planner never asks for
    a skill the robot lacks."""
    from abp_bench.episode_trace import model_set_of
    from abp_description.robot_profile import load_profile
    profile_file = REPO / 'abp_description' / 'profiles' / 'rover5.yaml'
    profile = load_profile(profile_file)
    models = model_set_of(profile.models, SEED)
    index = cube_with_mass(models, 'u')
    code, result, trace = run_episode(tmp_path, index, ('--world', 'mujoco', '--one-process',
                                                        '--robot-profile', str(profile_file)))
    assert code == 0, trace
    assert f'robot profile {profile_file}, models {profile.models}' in trace, trace
    assert result['ground_truth'] == models.names[index]
    assert result['correct'] and result['object_id'] == models.names[index], trace
    executed = [line.split()[2] for line in trace.splitlines() if line.startswith('action ')]
    assert executed and len(executed) == result['actions'], trace
    assert all(a.startswith('ORBIT') or a == 'PUSH' for a in executed), executed
    # Every plan leaves LIFT and FLIP out (PUSH too, where the cube is out of its reach).
    infeasible = [line.partition('infeasible: ')[2].rstrip(')').split(', ')
                  for line in trace.splitlines() if line.startswith('plan ')]
    assert infeasible and all({'LIFT', 'FLIP'} <= set(names) for names in infeasible), trace
    assert not graph_processes(), 'start_graph.sh left processes behind'
