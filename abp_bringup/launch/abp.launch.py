"""Launch the whole abp graph on a robot with launch_ros (untested here: launch_ros
is not installable from PyPI; scripts/start_graph.sh is the tested equivalent and
starts the same nodes with the same parameters file).

    ros2 launch abp_bringup abp.launch.py sim:=true world:=mujoco models:=robot planner:=cost \
        seed:=0 namespace:=robot1 tables:=corrected

`world` chooses the sim bridge's world: mujoco (MuJoCo physics and camera) or rules (the
contact rules and the flat renderer; fast). `tables` chooses the hand-written ATG table
(docs/MODEL.md): corrected or paper; empty (the default) means paper in the rules world,
whose physics it is, and corrected otherwise, as start_graph.sh --tables.

The model-set parameters are set once for every node (`SetParameter`, the launch form
of the `/**:` section in config/abp.yaml); `namespace` puts every node (and so every
topic, service and action, all relative) under that namespace.

As in start_graph.sh, every managed node starts with `autostart: false` (respawned after
1 s when it dies) and the lifecycle manager (`abp_bringup lifecycle_manager`) configures
and activates them in dependency order, logs `graph ready` once they are all active and
their topics matched, and brings a respawned node back to active.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node, SetParameter


def generate_launch_description():
    config = os.path.join(get_package_share_directory('abp_bringup'), 'config', 'abp.yaml')
    sim = LaunchConfiguration('sim')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = PythonExpression(["'", sim, "' == 'true'"])
    tables = PythonExpression([
        "'", LaunchConfiguration('tables'), "' or ('paper' if '", sim, "' == 'true' and '",
        LaunchConfiguration('world'), "' == 'rules' else 'corrected')"])

    def node(package, executable, extra=None, sim_time=True, managed=True, **kw):
        params = [config, {'use_sim_time': use_sim_time} if sim_time else {}, extra or {}]
        if managed:
            params.append({'autostart': False})
            kw.update(respawn=True, respawn_delay=1.0)
        return Node(package=package, executable=executable, namespace=namespace,
                    output='screen', parameters=params, **kw)

    def manager(node_names, condition):
        return node('abp_bringup', 'lifecycle_manager', {'node_names': node_names},
                    sim_time=False, managed=False, condition=condition)

    graph = ['artag_detector', 'aspect_matcher', 'belief', 'skill_servers', 'planner']

    return LaunchDescription([
        DeclareLaunchArgument('sim', default_value='true', description='start the sim bridge'),
        DeclareLaunchArgument('world', default_value='mujoco',
                              description='sim world: mujoco or rules',
                              choices=['mujoco', 'rules']),
        DeclareLaunchArgument('models', default_value='robot',
                              description='model set: robot, random, full or visual'),
        DeclareLaunchArgument('planner', default_value='cost',
                              description='random, abp, abp2, abp3 or cost'),
        DeclareLaunchArgument('seed', default_value='0', description='model-set seed'),
        DeclareLaunchArgument('tables', default_value='',
                              description='hand-written ATG table: corrected or paper '
                              '(empty: paper in the rules world, else corrected)',
                              choices=['', 'corrected', 'paper']),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of every node (empty = the root)'),
        # The model set, once for the whole graph (as `/**:` in a parameters file).
        SetParameter(name='model_set', value=LaunchConfiguration('models')),
        SetParameter(name='seed', value=LaunchConfiguration('seed')),
        SetParameter(name='transition_rules', value=tables),
        # The sim bridge publishes /clock, so it runs on wall time.
        node('abp_sim_bridge', 'sim_bridge', {'world': LaunchConfiguration('world')},
             sim_time=False, condition=IfCondition(sim)),
        node('abp_perception', 'artag_detector'),
        node('abp_perception', 'aspect_matcher'),
        node('abp_belief', 'belief'),
        node('abp_skills', 'skill_servers'),  # all four action servers, one process
        # One BLAS thread: see scripts/start_graph.sh.
        node('abp_planner', 'planner', {'planner_mode': LaunchConfiguration('planner')},
             additional_env={'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1'}),
        # Brings the nodes up in this order (the sim bridge first, when there is one).
        manager(['sim_bridge'] + graph, IfCondition(sim)),
        manager(graph, UnlessCondition(sim)),
    ])
