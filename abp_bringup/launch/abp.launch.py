"""Launch the whole abp graph on a robot with launch_ros (untested here: launch_ros
is not installable from PyPI; scripts/start_graph.sh is the tested equivalent and
starts the same nodes with the same parameters file).

    ros2 launch abp_bringup abp.launch.py sim:=true models:=robot planner:=abp seed:=0
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("abp_bringup"), "config", "abp.yaml")
    sim = LaunchConfiguration("sim")
    use_sim_time = PythonExpression(["'", sim, "' == 'true'"])
    model_params = {
        "model_set": LaunchConfiguration("models"),
        "seed": LaunchConfiguration("seed"),
    }

    def node(package, executable, extra=None):
        return Node(package=package, executable=executable, output="screen",
                    parameters=[config, {"use_sim_time": use_sim_time}, extra or {}])

    return LaunchDescription([
        DeclareLaunchArgument("sim", default_value="true", description="start the sim bridge"),
        DeclareLaunchArgument("models", default_value="robot",
                              description="model set: robot, random, full or visual"),
        DeclareLaunchArgument("planner", default_value="abp",
                              description="random, abp, abp2, abp3 or cost"),
        DeclareLaunchArgument("seed", default_value="0", description="model-set seed"),
        Node(package="abp_sim_bridge", executable="sim_bridge", output="screen",
             parameters=[config, model_params], condition=IfCondition(sim)),
        node("abp_perception", "artag_detector"),
        node("abp_perception", "aspect_matcher", model_params),
        node("abp_belief", "belief", model_params),
        node("abp_skills", "skill_servers"),  # all four action servers, one process
        node("abp_planner", "planner",
             {**model_params, "planner_mode": LaunchConfiguration("planner")}),
    ])
