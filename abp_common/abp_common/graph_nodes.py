"""The graph's long-running managed nodes, in one place: each node's name, the package
and executable that run it, and the graphs it runs in:

- `sim`: the sim bridge stands in for the robot (scripts/start_graph.sh, `sim:=true`);
- `robot`: the same nodes without the sim bridge (`start_graph.sh --robot`, `sim:=false`);
- `operator`: no robot and no sim, a fixed camera and a person doing the skills
  (`start_graph.sh --operator person`, docs/OPERATOR.md);
- `scripted`: the operator graph with a simulated person and camera in the MuJoCo world
  (`start_graph.sh --operator scripted`, the `scripted_operator` node).

The order is the bring-up order (dependencies first): the sensors (the sim bridge's clock
and sensors, or the camera), the robot's tf tree (robot_state), perception, the belief,
the skills, the planner last. A graph's nodes keep this order.

Each node also belongs to one *part* of the graph, for a split over a network
(`start_graph.sh --part`, docs/OFFBOARD.md): `robot` (what must run on the robot: the sim
bridge standing in for it or its drivers, the camera, perception and the skill servers,
which drive the hardware and see every camera frame) or `workstation` (the belief and the
planner, whose inputs are small messages). Images never cross the link in this split.
With `perception=WORKSTATION_PART` (`start_graph.sh --perception-on workstation`) the
tag detector and the aspect matcher move to the workstation too (the `PERCEPTION` nodes):
the detector then reads JPEG frames (image_transport's compressed transport) across the
link, and the matcher stays beside it, so that only images, camera_info and joint states
cross one way and no detection goes there and back.

Python users import it (abp_bringup.lifecycle_manager, abp.launch.py, abp_bench.soak);
scripts/start_graph.sh starts the same nodes with its own per-node arguments, and
tests/test_graph_nodes.py fails when its `start_managed` lines differ from this list.
`python -m abp_common.graph_nodes [--graph G] [--part P] [--perception P]` prints
`name package executable` lines.
"""

import argparse
from typing import NamedTuple

SIM, ROBOT, OPERATOR, SCRIPTED = 'sim', 'robot', 'operator', 'scripted'
GRAPHS = (SIM, ROBOT, OPERATOR, SCRIPTED)
_ALL = frozenset(GRAPHS)
_WITH_ROBOT = frozenset((SIM, ROBOT))
_WITH_OPERATOR = frozenset((OPERATOR, SCRIPTED))
_SIMULATED = frozenset((SIM, SCRIPTED))
# The parts of a graph split over a network; ALL_PARTS is both (one machine).
ROBOT_PART, WORKSTATION_PART, ALL_PARTS = 'robot', 'workstation', 'all'
PARTS = (ROBOT_PART, WORKSTATION_PART, ALL_PARTS)
# The nodes that can run on either side (`perception`): the detector and its matcher.
PERCEPTION = frozenset(('artag_detector', 'aspect_matcher'))
PERCEPTION_PARTS = (ROBOT_PART, WORKSTATION_PART)


class GraphNode(NamedTuple):
    name: str
    package: str
    executable: str
    graphs: frozenset   # the graphs it runs in (SIM, ROBOT, OPERATOR, SCRIPTED)
    part: str = ROBOT_PART   # where it runs when the graph is split: ROBOT_PART or WORKSTATION_PART

    @property
    def sim_only(self):
        """Stands in for the robot or the world: started in no graph that runs without
        the simulator (the sim bridge, the scripted operator)."""
        return self.graphs <= _SIMULATED


GRAPH = (
    GraphNode('sim_bridge', 'abp_sim_bridge', 'sim_bridge', frozenset((SIM,))),
    GraphNode('camera', 'abp_perception', 'camera', frozenset((OPERATOR,))),
    # The camera and the person of the scripted operator graph, in one node.
    GraphNode('scripted_operator', 'abp_sim_bridge', 'scripted_operator',
              frozenset((SCRIPTED,))),
    GraphNode('robot_state', 'abp_description', 'robot_state', _WITH_ROBOT),
    GraphNode('artag_detector', 'abp_perception', 'artag_detector', _ALL),
    GraphNode('aspect_matcher', 'abp_perception', 'aspect_matcher', _ALL),
    GraphNode('belief', 'abp_belief', 'belief', _ALL, WORKSTATION_PART),
    # The four action servers in one process.
    GraphNode('skill_servers', 'abp_skills', 'skill_servers', _WITH_ROBOT),
    GraphNode('operator_skills', 'abp_skills', 'operator_skills', _WITH_OPERATOR),
    GraphNode('planner', 'abp_planner', 'planner', _ALL, WORKSTATION_PART),
)


def part_of(node, perception=ROBOT_PART):
    """The part `node` runs in when the graph is split, the PERCEPTION nodes in
    `perception` (ROBOT_PART or WORKSTATION_PART)."""
    if perception not in PERCEPTION_PARTS:
        raise ValueError(f'perception must be one of {", ".join(PERCEPTION_PARTS)}, '
                         f'got {perception!r}')
    return perception if node.name in PERCEPTION else node.part


def graph_nodes(graph=SIM, part=ALL_PARTS, perception=ROBOT_PART):
    """The nodes of `graph` (SIM, ROBOT, OPERATOR or SCRIPTED) that run in `part`
    (ROBOT_PART, WORKSTATION_PART or ALL_PARTS), the PERCEPTION nodes in `perception`,
    in bring-up order."""
    if graph not in GRAPHS:
        raise ValueError(f'graph must be one of {", ".join(GRAPHS)}, got {graph!r}')
    if part not in PARTS:
        raise ValueError(f'part must be one of {", ".join(PARTS)}, got {part!r}')
    return tuple(node for node in GRAPH
                 if graph in node.graphs and part in (ALL_PARTS, part_of(node, perception)))


GRAPH_NODE_NAMES = tuple(node.name for node in graph_nodes(SIM))
ROBOT_NODE_NAMES = tuple(node.name for node in graph_nodes(ROBOT))


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m abp_common.graph_nodes',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--graph', choices=GRAPHS, default=SIM, help='which graph (default sim)')
    parser.add_argument('--part', choices=PARTS, default=ALL_PARTS,
                        help='only the nodes of this part of a split graph (default all)')
    parser.add_argument('--perception', choices=PERCEPTION_PARTS, default=ROBOT_PART,
                        help='the part the detector and matcher run in (default robot)')
    args = parser.parse_args(argv)
    for node in graph_nodes(args.graph, args.part, args.perception):
        print(node.name, node.package, node.executable)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())


__all__ = ['ALL_PARTS', 'GRAPH', 'GRAPHS', 'GRAPH_NODE_NAMES', 'OPERATOR', 'PARTS', 'PERCEPTION',
           'PERCEPTION_PARTS', 'ROBOT', 'ROBOT_NODE_NAMES', 'ROBOT_PART', 'SCRIPTED', 'SIM',
           'WORKSTATION_PART', 'GraphNode', 'graph_nodes', 'part_of']
