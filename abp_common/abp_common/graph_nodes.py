"""The graph's long-running managed nodes, in one place: each node's name, the package
and executable that run it, and whether it runs only in simulation. The order is the
bring-up order (dependencies first): the sim bridge's clock and sensors, then the
robot's tf tree (robot_state), perception, the belief, the skills, the planner last.

Python users import it (abp_bringup.lifecycle_manager, abp.launch.py, abp_bench.soak);
scripts/start_graph.sh starts the same nodes with its own per-node arguments, and
tests/test_graph_nodes.py fails when its `start_managed` lines differ from this list.
`python -m abp_common.graph_nodes [--robot]` prints `name package executable` lines.
"""

import argparse
from typing import NamedTuple


class GraphNode(NamedTuple):
    name: str
    package: str
    executable: str
    sim_only: bool = False   # stands in for the robot: not started on the robot


GRAPH = (
    GraphNode('sim_bridge', 'abp_sim_bridge', 'sim_bridge', sim_only=True),
    GraphNode('robot_state', 'abp_description', 'robot_state'),
    GraphNode('artag_detector', 'abp_perception', 'artag_detector'),
    GraphNode('aspect_matcher', 'abp_perception', 'aspect_matcher'),
    GraphNode('belief', 'abp_belief', 'belief'),
    # The four action servers in one process.
    GraphNode('skill_servers', 'abp_skills', 'skill_servers'),
    GraphNode('planner', 'abp_planner', 'planner'),
)
GRAPH_NODE_NAMES = tuple(node.name for node in GRAPH)
ROBOT_NODE_NAMES = tuple(node.name for node in GRAPH if not node.sim_only)


def graph_nodes(sim=True):
    """The nodes started in simulation (`sim`) or on the robot, in bring-up order."""
    return tuple(node for node in GRAPH if sim or not node.sim_only)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m abp_common.graph_nodes',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--robot', action='store_true', help='only the nodes run on the robot')
    args = parser.parse_args(argv)
    for node in graph_nodes(sim=not args.robot):
        print(node.name, node.package, node.executable)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())


__all__ = ['GRAPH', 'GRAPH_NODE_NAMES', 'ROBOT_NODE_NAMES', 'GraphNode', 'graph_nodes']
