"""One skin patch: driver (serial board or simulator), reconstruction, classifier.

Arguments:
  patch      shipped patch name (arm, face, elbow) or a path to a patch YAML [arm]
  namespace  ROS namespace of the patch [the patch name]
  port       serial device of the skin board, e.g. /dev/eit_skin_arm [empty]
  sim        run the physics simulator instead of a board [true; false when port is set]
  rate_hz    simulator frame rate, Hz [50]
  rviz       also start rviz2 with config/skin.rviz [false]
  params_file  ROS 2 parameters YAML given to every node, e.g. /**/eit_driver: ... [empty]

Example: ros2 launch eit_skin skin_patch.launch.py patch:=elbow port:=/dev/eit_skin_elbow
The nodes come from eit_skin.ros.node_graph, the same place `eit-skin run` takes them from.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration

from eit_skin.ros.launch_actions import ros_nodes, rviz_actions
from eit_skin.ros.node_graph import patch_nodes


def _truthy(text: str) -> bool:
    return text.strip().lower() in ("1", "true", "yes", "on")


def _patch_actions(context):
    port = LaunchConfiguration("port").perform(context)
    sim_text = LaunchConfiguration("sim").perform(context)
    sim = _truthy(sim_text) if sim_text else not port
    specs = patch_nodes(
        LaunchConfiguration("patch").perform(context),
        namespace=LaunchConfiguration("namespace").perform(context),
        port=port,
        sim=sim,
        rate_hz=float(LaunchConfiguration("rate_hz").perform(context)),
    )
    params_file = LaunchConfiguration("params_file").perform(context)
    if params_file and not os.path.isfile(params_file):
        raise FileNotFoundError(f"params_file {params_file!r}: no such file")
    return ros_nodes(specs, params_file)


def generate_launch_description():
    rviz_config = os.path.join(get_package_share_directory("eit_skin"), "config", "skin.rviz")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "patch", default_value="arm", description="patch name or YAML path"
            ),
            DeclareLaunchArgument("namespace", default_value="", description="ROS namespace"),
            DeclareLaunchArgument(
                "port", default_value="", description="serial device; empty = simulator"
            ),
            DeclareLaunchArgument(
                "sim", default_value="", description="true/false; default: no port given"
            ),
            DeclareLaunchArgument(
                "rate_hz", default_value="50.0", description="simulator frame rate"
            ),
            DeclareLaunchArgument("rviz", default_value="false", description="start rviz2"),
            DeclareLaunchArgument(
                "params_file",
                default_value="",
                description="ROS 2 parameters YAML for every node (overrides the arguments)",
            ),
            OpaqueFunction(function=_patch_actions),
            OpaqueFunction(
                function=lambda context: rviz_actions(rviz_config),
                condition=IfCondition(LaunchConfiguration("rviz")),
            ),
        ]
    )
