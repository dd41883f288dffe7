"""One skin patch: driver(s) (serial boards or simulator), reconstruction, classifier.

Arguments:
  patch      shipped patch name (arm, face, elbow) or a path to a patch YAML [arm]
  namespace  ROS namespace of the patch [the patch name]
  port       serial device of the board of a one-layer patch, e.g. /dev/eit_skin_face [empty]
  ports      one board per layer: LAYER=DEVICE,..., e.g. pressure=/dev/ttyACM0,stretch=/dev/ttyACM1;
             one eit_driver_<layer> each; every layer of the patch needs one [empty]
  ports_file  the same from a ports YAML (patch namespace -> layer -> device), e.g. the shipped
             config/ports.yaml [empty]
  sim        run the physics simulator instead of boards [true; false when a port is set]
  rate_hz    simulator frame rate, Hz [50]
  rviz       also start rviz2 with a configuration generated for this patch [false]
  params_file  ROS 2 parameters YAML given to every node, e.g. /**/eit_driver: ... [empty]
  <parameter>  any node parameter of docs/nodes.md by its name, e.g. tf_parent_frame:=forearm
             or frame_timeout_s:=2.0; set on every node that has it [not given]

Example: ros2 launch eit_skin skin_patch.launch.py patch:=elbow port:=/dev/eit_skin_elbow
The nodes come from eit_skin.ros.node_graph, the same place `eit-skin run` takes them from.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration

from eit_skin.ros.launch_actions import (
    launch_nodes,
    parameter_arguments,
    patch_launch_nodes,
    rviz_actions,
)

ARGUMENTS = [
    ("patch", "arm", "patch name or YAML path"),
    ("namespace", "", "ROS namespace"),
    ("port", "", "serial device of a one-layer patch; empty = simulator"),
    ("ports", "", "LAYER=DEVICE,... one board per layer"),
    ("ports_file", "", "ports YAML: patch namespace -> layer -> device"),
    ("sim", "", "true/false; default: no port given"),
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
                function=lambda context: launch_nodes(context, patch_launch_nodes(context))
            ),
            OpaqueFunction(
                function=lambda context: rviz_actions(patch_launch_nodes(context)),
                condition=IfCondition(LaunchConfiguration("rviz")),
            ),
        ]
    )
