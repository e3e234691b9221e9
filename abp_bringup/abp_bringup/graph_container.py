"""The graph's nodes in one process: `ros2 run abp_bringup graph_container`.

What a component container is to a C++ graph: `--nodes sim_bridge,robot_state,...`
builds each named node class (`NODES`) in this one process and spins them all on one
MultiThreadedExecutor, so the graph imports NumPy, OpenCV, MuJoCo and Pinocchio once
and its nodes talk over one DDS participant. The nodes are the same managed nodes as in
their own processes: started with `autostart:=false` they wait unconfigured, and the
lifecycle manager (its own process) brings them up over their ROS services as always.
Every `--ros-args` argument applies to every node; a parameter for one node only goes in
a parameters file under its name (`/**/planner: ros__parameters: ...`, which
scripts/start_graph.sh --one-process writes).

Threads: the nodes keep their own (the sim bridge's simulation and render threads:
MuJoCo's GL context stays with the render thread); the executor has as many threads as
the nodes would have had in their own processes, so a callback that blocks (the
planner's Recognize loop, a skill waiting for its controller) holds no other node up.
Each node's callbacks keep their callback groups, so a node that is single-threaded in
its own process is still never run on two threads at once.

Crash recovery: a node that dies takes the process, and so every node, with it. Under
scripts/start_graph.sh the container is supervised as one unit (restarted unless it
stopped cleanly, exited 2 on a configuration error, or died 3 times within 10 s), and
the lifecycle manager brings every new instance back to active, as it does a respawned
node. A simulation or render thread that fails ends the container with code 1.
"""

import argparse
import importlib
import sys
from functools import partial

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.utilities import remove_ros_args

from abp_common.lifecycle import BASE_CONFIG_ERRORS
from abp_common.node_runner import (
    CONFIGURATION_ERROR_EXIT_CODE,
    init_rclpy_with_quiet_interrupt,
    retire_ports_of_killed_participants,
)


def _skill_servers():
    from abp_common import names
    from abp_skills.skills_node import SkillsNode
    return partial(SkillsNode, 'skill_servers', names.SKILLS, True)


def _class(module, name):
    return lambda: getattr(importlib.import_module(module), name)


def _config_errors(*spec):
    """Configuration error types, named as (module, attribute), imported when needed."""
    def load():
        errors = []
        for module, name in spec:
            errors.append(getattr(importlib.import_module(module), name))
        return tuple(errors)
    return load


def _stop_sim_bridge(node):
    return node.stop()


def _stop_robot(node):
    try:
        node.stop_motion()
    except Exception:  # noqa: BLE001 -- the context may already be gone
        pass


def _close_camera(node):
    node._close_source()  # the device or file, as the camera's own main() does


MODEL_FILE_ERROR = ('abp_belief.model_file', 'ModelFileError')


class NodeEntry:
    """How to build one of the graph's nodes in this process, and what its own process
    would give it: configuration error types, executor threads, a clean-up at exit."""

    def __init__(self, factory, config_errors=(), threads=1, on_exit=None):
        self.factory, self.config_errors = factory, _config_errors(*config_errors)
        self.threads, self.on_exit = threads, on_exit


# Node name -> entry, the graph's managed nodes (their `main()`s in their packages).
NODES = {
    'sim_bridge': NodeEntry(_class('abp_sim_bridge.sim_bridge_node', 'SimBridgeNode'),
                            threads=8, on_exit=_stop_sim_bridge),
    'robot_state': NodeEntry(_class('abp_description.robot_state_node', 'RobotStateNode')),
    'artag_detector': NodeEntry(
        _class('abp_perception.artag_detector_node', 'ArtagDetectorNode'),
        config_errors=[('builtins', 'FileNotFoundError')]),
    'aspect_matcher': NodeEntry(
        _class('abp_perception.aspect_matcher_node', 'AspectMatcherNode'),
        config_errors=[MODEL_FILE_ERROR]),
    'belief': NodeEntry(_class('abp_belief.belief_node', 'BeliefNode'),
                        config_errors=[MODEL_FILE_ERROR]),
    'skill_servers': NodeEntry(
        _skill_servers, threads=8, on_exit=_stop_robot,
        config_errors=[('builtins', 'TypeError'), ('rclpy.exceptions', 'ParameterException')]),
    'planner': NodeEntry(_class('abp_planner.planner_node', 'PlannerNode'), threads=4,
                         config_errors=[MODEL_FILE_ERROR]),
    # The operator graph (start_graph.sh --operator person): a fixed camera and a person.
    'camera': NodeEntry(
        _class('abp_perception.camera_node', 'CameraNode'), on_exit=_close_camera,
        config_errors=[('abp_perception.frame_source', 'FrameSourceError'),
                       ('abp_perception.camera_calibration_file', 'CalibrationFileError')]),
    # start_graph.sh --operator scripted: the MuJoCo camera and a simulated person.
    'scripted_operator': NodeEntry(
        _class('abp_sim_bridge.scripted_operator_node', 'ScriptedOperatorNode'), threads=2,
        on_exit=lambda node: node.stop()),
    'operator_skills': NodeEntry(
        _class('abp_skills.operator_node', 'OperatorSkillsNode'), threads=4,
        config_errors=[('builtins', 'TypeError'), ('rclpy.exceptions', 'ParameterException')]),
}


def parse(argv):
    parser = argparse.ArgumentParser(
        prog='graph_container', description=__doc__.split('\n\n')[1],
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--nodes', required=True,
                        help=f'comma-separated node names, of: {", ".join(NODES)}')
    args = parser.parse_args(remove_ros_args(argv)[1:])
    wanted = [n for n in args.nodes.split(',') if n]
    unknown = [n for n in wanted if n not in NODES]
    if unknown or not wanted:
        parser.error(f'--nodes: unknown {", ".join(unknown) or "(none given)"}; '
                     f'known: {", ".join(NODES)}')
    return wanted


def main(args=None):
    argv = sys.argv if args is None else args
    wanted = parse(argv)
    retire_ports_of_killed_participants('graph_container')  # a restarted container: run 65
    init_rclpy_with_quiet_interrupt(argv)
    nodes = {}
    try:
        for name in wanted:
            entry = NODES[name]
            errors = entry.config_errors()
            try:
                node = entry.factory()()
                nodes[name] = node
                node.start(errors)
            except (*BASE_CONFIG_ERRORS, *errors) as error:
                print(f'[graph_container] {name}: configuration error: {error}',
                      file=sys.stderr)
                return _shut_down(nodes, CONFIGURATION_ERROR_EXIT_CODE)
    except BaseException:
        _shut_down(nodes, 1)
        raise
    executor = MultiThreadedExecutor(num_threads=sum(NODES[n].threads for n in wanted))
    for node in nodes.values():
        executor.add_node(node)
    failed = []
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():   # Ctrl-C shuts the context down under a running callback
            raise
    finally:
        for name, node in nodes.items():
            if NODES[name].on_exit is not None:
                failed.append(NODES[name].on_exit(node))
        executor.shutdown()
    return _shut_down(nodes, 1 if any(failed) else 0)


def _shut_down(nodes, code):
    for node in nodes.values():
        node.destroy_node()
    rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
