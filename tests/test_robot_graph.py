"""The robot graph (`start_graph.sh --robot`: no sim bridge, the robot's drivers stand
outside abp) comes up, one process per node and in one process (`--one-process`).

No robot answers here: the test proves what abp's own part does on a robot before its
first goal: every node of the robot graph configured and active, the lifecycle manager's
graph_ready, no simulated node started. `--robot --one-process` wrote an empty
parameters block for nodes given no `-p` (YAML null), which the parameter parser refused
at start-up: it had never run.
"""

import pathlib

import pytest

from abp_bench import soak
from abp_common.graph_nodes import ROBOT_NODE_NAMES
from tests.helpers.graph import graph_processes

REPO = pathlib.Path(__file__).resolve().parent.parent

READY_TIMEOUT_S = 240
NAMES_TIMEOUT_S = 60


@pytest.mark.timeout(READY_TIMEOUT_S + NAMES_TIMEOUT_S + 120)
@pytest.mark.parametrize('layout', [(), ('--one-process',)], ids=['per-process', 'one-process'])
def test_the_robot_graph_comes_up_without_a_simulator(ros_processes, rclpy_context, tmp_path,
                                                      layout):
    log_dir = tmp_path / 'logs'
    graph = ros_processes.start([str(REPO / 'scripts' / 'start_graph.sh'), '--robot', '--serve',
                                 '--no-build', '--log-dir', str(log_dir), *layout])
    driver = soak.Driver(rclpy_context, '')

    def node_names():
        return {name for name, _ in driver.node.get_node_names_and_namespaces()}

    try:
        ready = driver.spin_until(lambda: driver.graph_ready, READY_TIMEOUT_S)
        # The manager's graph_ready can reach this process before the graph's node names
        # do (each participant announces its nodes on its own; over UDP that took longer
        # than the manager's message in a clean-clone run): wait for them as an event.
        driver.spin_until(lambda: set(ROBOT_NODE_NAMES) <= node_names(), NAMES_TIMEOUT_S)
        nodes = node_names()
    finally:
        driver.close()
    assert ready, ros_processes.output(graph)
    assert graph.poll() is None, ros_processes.output(graph)
    assert set(ROBOT_NODE_NAMES) <= nodes, sorted(nodes)
    assert 'sim_bridge' not in nodes, sorted(nodes)
    ros_processes.stop_all()
    assert not graph_processes(), 'start_graph.sh left processes behind'
