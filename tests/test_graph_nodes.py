"""One home for the graph's node list (abp_common.graph_nodes): every other place that
names the graph's nodes agrees with it, in the same bring-up order."""

import re
import subprocess
import sys

from abp_common.graph_nodes import GRAPH, GRAPH_NODE_NAMES, ROBOT_NODE_NAMES, graph_nodes
from tests.helpers.manifests import REPO


def test_the_list_is_consistent():
    assert len(set(GRAPH_NODE_NAMES)) == len(GRAPH)
    # start_graph.sh and the launch file name each node after its executable.
    assert all(node.name == node.executable for node in GRAPH)
    assert ROBOT_NODE_NAMES == tuple(n.name for n in graph_nodes(sim=False))
    assert 'sim_bridge' not in ROBOT_NODE_NAMES and 'sim_bridge' in GRAPH_NODE_NAMES
    # Sim-only nodes come first: on the robot, the others keep their relative order.
    sim_only = [node.sim_only for node in GRAPH]
    assert sim_only == sorted(sim_only, reverse=True)


def test_start_graph_starts_the_listed_nodes_in_order():
    script = (REPO / 'scripts' / 'start_graph.sh').read_text()
    started = re.findall(r'^\s*(?:\S+=\S+\s+)*start_managed (\w+) (\w+)', script, re.M)
    assert started == [(node.package, node.executable) for node in GRAPH], \
        'scripts/start_graph.sh: its start_managed lines differ from abp_common.graph_nodes'


def test_the_lifecycle_manager_and_soak_use_the_list():
    from abp_bench.soak import GRAPH_NODES as soak_nodes
    from abp_bringup.lifecycle_manager import MANAGER_SPECS

    node_names = {spec.name: spec for spec in MANAGER_SPECS}['node_names'].default
    assert tuple(node_names) == GRAPH_NODE_NAMES
    assert soak_nodes == {n.name: (n.package, n.executable) for n in GRAPH}


def test_the_module_prints_the_list():
    for flag, nodes in (([], graph_nodes(sim=True)), (['--robot'], graph_nodes(sim=False))):
        out = subprocess.run([sys.executable, '-m', 'abp_common.graph_nodes', *flag],
                             capture_output=True, text=True, check=True).stdout
        assert [tuple(line.split()) for line in out.splitlines()] == \
            [(n.name, n.package, n.executable) for n in nodes]
