"""Launch the whole abp graph on a robot with launch_ros. launch_ros is not installable
from PyPI, so it never runs here; abp_bringup/test/test_launch_file.py imports it against
stand-ins of launch/launch_ros and checks what it builds (every executable installed,
every parameter declared by its node with a valid value, no respawn loop).
scripts/start_graph.sh is the tested equivalent and starts the same nodes with the same
parameters file.

    ros2 launch abp_bringup abp.launch.py sim:=true world:=mujoco models:=robot planner:=cost \
        seed:=0 namespace:=robot1 tables:=corrected

`world` chooses the sim bridge's world: mujoco (MuJoCo physics and camera) or rules (the
contact rules and the flat renderer; fast). `tables` chooses the hand-written ATG table
(docs/MODEL.md): corrected or paper; empty (the default) means paper in the rules world,
whose physics it is, and corrected otherwise, as start_graph.sh --tables.

The arguments must override config/abp.yaml, and rcl merges parameter sources by node
entry (`/**`, then `/**/planner`, ... in the order they first appear), not by the order
of the files. So every Node is given its `name`: launch_ros then writes its dictionaries
under the node's full name, an entry after all of abp.yaml's, which wins. The model-set
parameters (models, seed, tables) go to every node that way (a node that does not
declare one ignores it); not with `SetParameter`, whose values launch_ros passes before
the parameter files, so abp.yaml's `/**:` would win. `namespace` puts every node (and so
every topic, service and action, all relative) under that namespace.

As in start_graph.sh, every managed node starts with `autostart: false` and the
lifecycle manager (`abp_bringup lifecycle_manager`) configures and activates them in
dependency order, logs `graph ready` once they are all active and their topics matched,
and brings a respawned node back to active. With autostart false a bad parameter makes
configure fail and the node stays up, unconfigured, with the reason in its log: there is
no exit to respawn. A node that dies is respawned after 1 s, at most
RESPAWN_MAX_RETRIES times (launch cannot tell a crash from an exit that a restart cannot
fix, so a crash loop must end). The lifecycle manager itself is not respawned.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from abp_common.graph_nodes import GRAPH_NODE_NAMES, ROBOT_NODE_NAMES, SIM, graph_nodes

RESPAWN_MAX_RETRIES = 3
# The choices of the nodes' own parameters (model_set, planner_mode, world, transition_rules;
# the test checks they match): a wrong value stops `ros2 launch` at once.
MODEL_SETS = ['robot', 'random', 'full', 'visual']
PLANNERS = ['random', 'abp', 'abp2', 'abp3', 'cost']
WORLDS = ['mujoco', 'rules']
TABLES = ['corrected', 'paper']


def generate_launch_description():
    config = os.path.join(get_package_share_directory('abp_bringup'), 'config', 'abp.yaml')
    sim = LaunchConfiguration('sim')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = PythonExpression(["'", sim, "' == 'true'"])
    tables = PythonExpression([
        "'", LaunchConfiguration('tables'), "' or ('paper' if '", sim, "' == 'true' and '",
        LaunchConfiguration('world'), "' == 'rules' else 'corrected')"])

    # The model set, once for the whole graph (as `/**:` in a parameters file).
    model_set = {'model_set': LaunchConfiguration('models'),
                 'seed': LaunchConfiguration('seed'), 'transition_rules': tables}

    def node(package, executable, extra=None, sim_time=True, managed=True, **kw):
        params = [config, model_set]
        if sim_time:
            params.append({'use_sim_time': use_sim_time})
        if extra:
            params.append(extra)
        if managed:
            params.append({'autostart': False})
            kw.update(respawn=True, respawn_delay=1.0, respawn_max_retries=RESPAWN_MAX_RETRIES)
        # Each executable's node has the executable's name.
        return Node(package=package, executable=executable, name=executable,
                    namespace=namespace, output='screen', parameters=params, **kw)

    def manager(node_names, condition):
        return node('abp_bringup', 'lifecycle_manager', {'node_names': node_names},
                    sim_time=False, managed=False, condition=condition)

    # Per node: the parameters and process options beyond the common ones.
    extras = {
        # The sim bridge publishes /clock, so it runs on wall time. The hidden cube is
        # drawn with the same seed, as start_graph.sh --seed.
        'sim_bridge': dict(extra={'world': LaunchConfiguration('world'),
                                  'cube_seed': LaunchConfiguration('seed')},
                           sim_time=False),
        # One BLAS thread: see scripts/start_graph.sh.
        'planner': dict(extra={'planner_mode': LaunchConfiguration('planner')},
                        additional_env={'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1'}),
    }
    # The graph's nodes in bring-up order (abp_common.graph_nodes): robot_state gives
    # /tf, /tf_static and robot_description; skill_servers runs all four action servers.
    # A sim-only node (the sim bridge) starts only with sim:=true.
    nodes = [node(n.package, n.executable, **extras.get(n.name, {}),
                  **({'condition': IfCondition(sim)} if n.sim_only else {}))
             for n in graph_nodes(SIM)]

    return LaunchDescription([
        DeclareLaunchArgument('sim', default_value='true', description='start the sim bridge'),
        DeclareLaunchArgument('world', default_value='mujoco',
                              description='sim world: mujoco or rules', choices=WORLDS),
        DeclareLaunchArgument('models', default_value='robot',
                              description='model set: robot, random, full or visual',
                              choices=MODEL_SETS),
        DeclareLaunchArgument('planner', default_value='cost',
                              description='random, abp, abp2, abp3 or cost', choices=PLANNERS),
        DeclareLaunchArgument('seed', default_value='0',
                              description='model-set seed (and, in sim, of the hidden cube)'),
        DeclareLaunchArgument('tables', default_value='',
                              description='hand-written ATG table: corrected or paper '
                              '(empty: paper in the rules world, else corrected)',
                              choices=[''] + TABLES),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of every node (empty = the root)'),
        *nodes,
        # Brings the nodes up in this order (the sim bridge first, when there is one).
        manager(list(GRAPH_NODE_NAMES), IfCondition(sim)),
        manager(list(ROBOT_NODE_NAMES), UnlessCondition(sim)),
    ])
