"""One home for the graph's node list (abp_common.graph_nodes): every other place that
names the graph's nodes agrees with it, in the same bring-up order."""

import re
import subprocess
import sys

import pytest

from abp_common.graph_nodes import (
    ALL_PARTS,
    GRAPH,
    GRAPH_NODE_NAMES,
    GRAPHS,
    OPERATOR,
    ROBOT,
    ROBOT_NODE_NAMES,
    ROBOT_PART,
    SCRIPTED,
    SIM,
    WORKSTATION_PART,
    graph_nodes,
)
from tests.helpers.manifests import REPO

# Where start_graph.sh's operator graph ends and its sim/robot graph begins.
SIM_OR_ROBOT_BLOCK = 'if [ -z "$operator" ]; then'


def test_the_list_is_consistent():
    assert len({node.name for node in GRAPH}) == len(GRAPH)
    # start_graph.sh and the launch file name each node after its executable.
    assert all(node.name == node.executable for node in GRAPH)
    assert all(node.graphs and node.graphs <= set(GRAPHS) for node in GRAPH)
    assert GRAPH_NODE_NAMES == tuple(n.name for n in graph_nodes(SIM))
    assert ROBOT_NODE_NAMES == tuple(n.name for n in graph_nodes(ROBOT))
    # The robot graph is the sim graph without what stands in for the robot.
    assert ROBOT_NODE_NAMES == tuple(n.name for n in graph_nodes(SIM) if not n.sim_only)
    assert [n.name for n in GRAPH if n.sim_only] == ['sim_bridge', 'scripted_operator']
    with pytest.raises(ValueError, match='graph must be one of'):
        graph_nodes('moon')


@pytest.mark.parametrize('graph', GRAPHS)
def test_the_two_parts_split_each_graph(graph):
    """--part robot and --part workstation start every node of the graph once between
    them, in the graph's order; the workstation runs the belief and the planner only (no
    node that drives hardware or reads images)."""
    robot = graph_nodes(graph, ROBOT_PART)
    workstation = graph_nodes(graph, WORKSTATION_PART)
    assert [n.name for n in workstation] == ['belief', 'planner']
    assert set(robot) | set(workstation) == set(graph_nodes(graph, ALL_PARTS))
    assert not set(robot) & set(workstation)
    assert graph_nodes(graph) == graph_nodes(graph, ALL_PARTS)
    with pytest.raises(ValueError, match='part must be one of'):
        graph_nodes(graph, 'moon')


@pytest.mark.parametrize('graph', (SIM, ROBOT))
def test_perception_can_run_on_the_workstation(graph):
    """--perception-on workstation: the detector and matcher join the belief and planner;
    the parts still split the graph, each node once, in its order."""
    robot = graph_nodes(graph, ROBOT_PART, perception=WORKSTATION_PART)
    workstation = graph_nodes(graph, WORKSTATION_PART, perception=WORKSTATION_PART)
    assert [n.name for n in workstation] == ['artag_detector', 'aspect_matcher', 'belief',
                                             'planner']
    assert set(robot) | set(workstation) == set(graph_nodes(graph))
    assert not set(robot) & set(workstation)
    assert graph_nodes(graph, ALL_PARTS, perception=WORKSTATION_PART) == graph_nodes(graph)
    with pytest.raises(ValueError, match='perception must be one of'):
        graph_nodes(graph, ROBOT_PART, perception='moon')
    listed = subprocess.run([sys.executable, '-m', 'abp_common.graph_nodes', '--graph', graph,
                             '--part', 'workstation', '--perception', 'workstation'],
                            capture_output=True, text=True, check=True).stdout.split('\n')
    assert [line.split()[0] for line in listed if line] == [n.name for n in workstation]


def start_managed(text):
    """[(package, executable)] of the start_managed lines of a part of start_graph.sh."""
    return re.findall(r'^\s*(?:\S+=\S+\s+)*start_managed (\w+) (\w+)', text, re.M)


def test_start_graph_starts_the_listed_nodes_in_order():
    script = (REPO / 'scripts' / 'start_graph.sh').read_text()
    assert script.count(SIM_OR_ROBOT_BLOCK) == 1, 'start_graph.sh: the blocks moved'
    operator_part, sim_part = script.split(SIM_OR_ROBOT_BLOCK)
    expect = {graph: [(n.package, n.executable) for n in graph_nodes(graph)]
              for graph in GRAPHS}
    # --robot leaves out the sim-only nodes of the same lines.
    assert start_managed(sim_part) == expect[SIM], \
        'scripts/start_graph.sh: its sim/robot start_managed lines differ from ' \
        'abp_common.graph_nodes'
    # The person's and the scripted operator's graphs share their lines but the first
    # (camera or scripted_operator).
    both = [(n.package, n.executable) for n in GRAPH if n.graphs & {OPERATOR, SCRIPTED}]
    assert start_managed(operator_part) == both, \
        'scripts/start_graph.sh: its operator start_managed lines differ from ' \
        'abp_common.graph_nodes'
    assert expect[OPERATOR] == [e for e in both if e[1] != 'scripted_operator']
    assert expect[SCRIPTED] == [e for e in both if e[1] != 'camera']


def test_the_lifecycle_manager_and_soak_use_the_list():
    from abp_bench.soak import GRAPH_NODES as soak_nodes
    from abp_bringup.lifecycle_manager import MANAGER_SPECS

    node_names = {spec.name: spec for spec in MANAGER_SPECS}['node_names'].default
    assert tuple(node_names) == GRAPH_NODE_NAMES
    assert soak_nodes == {n.name: (n.package, n.executable) for n in graph_nodes(SIM)}


@pytest.mark.parametrize('graph', GRAPHS)
@pytest.mark.parametrize('part', (ROBOT_PART, WORKSTATION_PART, ALL_PARTS))
def test_the_module_prints_the_list(graph, part):
    # start_graph.sh --part reads the part's nodes from this output.
    out = subprocess.run([sys.executable, '-m', 'abp_common.graph_nodes', '--graph', graph,
                          '--part', part], capture_output=True, text=True, check=True).stdout
    assert [tuple(line.split()) for line in out.splitlines()] == \
        [(n.name, n.package, n.executable) for n in graph_nodes(graph, part)]


def test_the_one_process_container_can_build_every_node():
    """graph_container (start_graph.sh --one-process) knows how to build each graph node,
    and each entry names a class its package really has."""
    from abp_bringup.graph_container import NODES
    from abp_common.graph_nodes import GRAPH

    assert sorted(NODES) == sorted(node.name for node in GRAPH)
    for name, entry in NODES.items():
        assert callable(entry.factory()), name
        assert all(isinstance(error, type) for error in entry.config_errors()), name
