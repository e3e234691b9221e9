"""`start_graph.sh --one-process` (issue 39): the graph's managed nodes in one process
(abp_bringup graph_container) on one executor, brought up by the same lifecycle manager
over ROS services, recognise a seeded hidden cube in the rules world; every node's
parameters reach it (the per-node ones through the container's parameters file), and
nothing is left running afterwards. The run ends on its own events (`graph ready`, the
Recognize result); the root conftest gives the session its own ROS domain."""

import json
import pathlib

import pytest

from abp_belief.population import robot_set
from tests.helpers.graph import graph_processes, node_log_tails, run_to_end

REPO = pathlib.Path(__file__).resolve().parent.parent
SEED = 1
EPISODE_TIMEOUT_S = 480
NODES = ('sim_bridge', 'robot_state', 'artag_detector', 'aspect_matcher', 'belief',
         'skill_servers', 'planner')


@pytest.mark.timeout(EPISODE_TIMEOUT_S + 180)
def test_one_process_graph_recognises_the_hidden_cube(tmp_path):
    models = robot_set(seed=SEED)
    index = next(i for i in range(models.num_models) if models.mass[i] == 0)
    result_file, log_dir = tmp_path / 'result.json', tmp_path / 'logs'
    code, trace, _ = run_to_end(
        [str(REPO / 'scripts' / 'start_graph.sh'), '--no-build', '--one-process', '--world',
         'rules', '--seed', str(SEED), '--object', str(index), '--planner', 'abp',
         '--result-json', str(result_file), '--log-dir', str(log_dir),
         '--timeout', str(EPISODE_TIMEOUT_S)],
        EPISODE_TIMEOUT_S + 60, tmp_path / 'output.txt')
    if code != 0 or not result_file.exists():
        trace += node_log_tails(log_dir)
    assert code == 0, trace
    result = json.loads(result_file.read_text())
    assert result['correct'] and result['object_id'] == models.names[index], trace

    # One process: the container's log has every node's lines, no node has its own log.
    container_log = (log_dir / 'graph_container.log').read_text()
    for node in NODES:
        assert f'[{node}]: active' in container_log, (node, container_log[-3000:])
        assert not (log_dir / f'{node}.log').exists(), node
    # The per-node parameters: the sim bridge's world and seed, the planner's mode.
    assert 'sim_bridge: rules world' in container_log, container_log[-3000:]
    assert '(mode abp,' in container_log, container_log[-3000:]
    assert not graph_processes(), 'start_graph.sh left processes behind'
