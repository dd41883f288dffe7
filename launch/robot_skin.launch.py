"""The whole robot skin: arm, face and elbow patches, each in its own namespace.

Arguments:
  sim      run every patch on the physics simulator [true]
  rate_hz  simulator frame rate, Hz [50]
  rviz     also start rviz2 with config/skin.rviz [false]
  params_file  ROS 2 parameters YAML given to every node, e.g. /**/eit_driver: ... [empty]

On hardware, start one skin_patch.launch.py per board with its port instead.
The nodes come from eit_skin.ros.node_graph, the same place `eit-skin run --all` takes them from.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration

from eit_skin.ros.launch_actions import ros_nodes, rviz_actions
from eit_skin.ros.node_graph import robot_nodes


def _robot_actions(context):
    sim = LaunchConfiguration("sim").perform(context).strip().lower() in ("1", "true", "yes", "on")
    specs = robot_nodes(sim=sim, rate_hz=float(LaunchConfiguration("rate_hz").perform(context)))
    params_file = LaunchConfiguration("params_file").perform(context)
    if params_file and not os.path.isfile(params_file):
        raise FileNotFoundError(f"params_file {params_file!r}: no such file")
    return ros_nodes(specs, params_file)


def generate_launch_description():
    rviz_config = os.path.join(get_package_share_directory("eit_skin"), "config", "skin.rviz")
    return LaunchDescription(
        [
            DeclareLaunchArgument("sim", default_value="true", description="simulate every patch"),
            DeclareLaunchArgument(
                "rate_hz", default_value="50.0", description="simulator frame rate"
            ),
            DeclareLaunchArgument("rviz", default_value="false", description="start rviz2"),
            DeclareLaunchArgument(
                "params_file",
                default_value="",
                description="ROS 2 parameters YAML for every node (overrides the arguments)",
            ),
            OpaqueFunction(function=_robot_actions),
            OpaqueFunction(
                function=lambda context: rviz_actions(rviz_config),
                condition=IfCondition(LaunchConfiguration("rviz")),
            ),
        ]
    )
