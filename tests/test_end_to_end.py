"""End to end over the real graph in simulation, through scripts/start_graph.sh.

Every node runs as its own process over DDS (sim bridge, detector, matcher,
belief, four skill servers, planner) and the `recognize` client drives one
Recognize goal; the hidden cube is seeded. Eccentric twins are visually identical
to their uniform sibling, so recognising them proves that the planner chose the
manual action that separates them and that the sim's physics, the skills and the
perception agree. The uniform cube's episode runs the graph under a namespace
(`--namespace robot1`: every node, topic, service and action under /robot1).
Each case names its world: `rules` (contact rules, flat renderer: fast) for the twins,
`mujoco` (physics and MuJoCo camera, start_graph.sh's default) for one uniform cube.
"""

import json
import os
import pathlib
import signal
import subprocess

import pytest

from abp_belief.population import robot_set
from tests.helpers.graph import graph_processes, node_log_tails, run_to_end, stop_group

REPO = pathlib.Path(__file__).resolve().parent.parent
SEED = 1
# start_graph.sh's own deadline for the Recognize goal; the test's (pytest-timeout) is
# longer, so that a slow episode fails with its trace and its graph stopped.
EPISODE_TIMEOUT_S = 480
MANUAL = {'PUSH', 'LIFT', 'FLIP'}


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


def twin_with_mass(models, mass_name):
    return next(i for i, name in enumerate(models.names) if name.endswith('/' + mass_name))


@pytest.mark.timeout(EPISODE_TIMEOUT_S + 180)
@pytest.mark.parametrize('world, mass, namespace', [
    ('rules', 'u', 'robot1'), ('rules', 'm+z', ''), ('rules', 'm+y', ''), ('mujoco', 'u', '')])
def test_hidden_cube_is_recognised_through_the_whole_graph(tmp_path, world, mass, namespace):
    models = robot_set(seed=SEED)
    if mass == 'u':
        index = next(i for i in range(models.num_models) if models.mass[i] == 0)
    else:
        index = twin_with_mass(models, mass)
    code, result, trace = run_episode(
        tmp_path, index, ('--world', world, *(('--namespace', namespace) if namespace else ())))
    assert code == 0, trace
    assert f'sim ({world} world)' in trace
    if namespace:
        assert f'graph under /{namespace}' in trace
        planner_log = (tmp_path / f'logs-{index}' / 'planner.log').read_text()
        assert f'[{namespace}.planner]' in planner_log
    assert result['ground_truth'] == models.names[index]
    assert result['correct'] and result['object_id'] == models.names[index], trace
    assert result['posterior'] >= 0.95
    executed = [line.split()[2] for line in trace.splitlines() if line.startswith('action ')]
    assert len(executed) == result['actions']
    if mass != 'u':
        # A twin is told apart only by a manual action.
        assert MANUAL & set(executed), trace
    assert not graph_processes(), 'start_graph.sh left processes behind'


@pytest.mark.timeout(EPISODE_TIMEOUT_S + 180)
def test_a_node_killed_mid_episode_is_respawned_and_the_episode_ends_correct(tmp_path):
    models = robot_set(seed=SEED)
    index = next(i for i in range(models.num_models) if models.mass[i] == 0)
    result_file, log_dir = tmp_path / 'result.json', tmp_path / 'logs'
    graph = subprocess.Popen(
        [str(REPO / 'scripts' / 'start_graph.sh'), '--no-build', '--world', 'rules', '--seed',
         str(SEED), '--object', str(index), '--result-json', str(result_file), '--log-dir',
         str(log_dir), '--timeout', str(EPISODE_TIMEOUT_S)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        trace = []
        for line in graph.stdout:  # the event: the first action is done
            trace.append(line)
            if line.startswith('action 1 '):
                break
        belief = [pid for pid, cmdline in graph_processes(with_pids=True)
                  if '/lib/abp_belief/belief ' in cmdline and str(log_dir) in cmdline]
        assert len(belief) == 1, ''.join(trace)
        os.kill(belief[0], signal.SIGKILL)
        trace += graph.stdout.readlines()
        graph.wait(timeout=EPISODE_TIMEOUT_S + 60)
    finally:
        if graph.poll() is None:
            stop_group(graph)
    trace = ''.join(trace)
    assert graph.returncode == 0, trace
    assert 'belief exited with code 137; restarting it (restart 1)' in trace
    planner_log = (log_dir / 'planner.log').read_text()
    assert 're-observing' in planner_log, planner_log
    result = json.loads(result_file.read_text())
    assert result['correct'] and result['object_id'] == models.names[index], trace
    assert not graph_processes(), 'start_graph.sh left processes behind'
