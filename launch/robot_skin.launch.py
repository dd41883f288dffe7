"""The whole robot skin: arm, face and elbow patches, each in its own namespace.

Arguments:
  sim      run every patch on the physics simulator; false: on the boards of ports_file [true]
  ports_file  ports YAML (patch namespace -> layer -> serial device) for sim:=false
           [the shipped config/ports.yaml]
  rate_hz  simulator frame rate, Hz [50]
  rviz     also start rviz2 with a configuration generated for the three patches [false]
  params_file  ROS 2 parameters YAML given to every node, e.g. /**/eit_driver: ... [empty]
  <parameter>  any node parameter of docs/nodes.md by its name, e.g. publish_tf:=false;
           set on every node of every patch that has it [not given]

The nodes come from eit_skin.ros.node_graph, the same place `eit-skin run --all` takes them from.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration

from eit_skin.ros.launch_actions import (
    launch_nodes,
    parameter_arguments,
    robot_launch_nodes,
    rviz_actions,
)

ARGUMENTS = [
    ("sim", "true", "simulate every patch (false: the boards of ports_file)"),
    ("ports_file", "", "ports YAML for sim:=false; empty: config/ports.yaml"),
    ("rate_hz", "50.0", "simulator frame rate"),
    ("rviz", "false", "start rviz2"),
    ("params_file", "", "ROS 2 parameters YAML for every node (overrides the arguments)"),
]


def generate_launch_description():
    return LaunchDescription(
        [
            *(DeclareLaunchArgument(n, default_value=d, description=t) for n, d, t in ARGUMENTS),
            *parameter_arguments({name for name, _, _ in ARGUMENTS}),
            OpaqueFunction(
                function=lambda context: launch_nodes(context, robot_launch_nodes(context))
            ),
            OpaqueFunction(
                function=lambda context: rviz_actions(robot_launch_nodes(context)),
                condition=IfCondition(LaunchConfiguration("rviz")),
            ),
        ]
    )
