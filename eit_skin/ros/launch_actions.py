"""launch_ros actions for node specs (imported by the launch files only, on a ROS install)."""

from __future__ import annotations

from eit_skin.ros.node_graph import NODE_ENVIRONMENT, NodeSpec


def ros_nodes(specs: list[NodeSpec], params_file: str = "") -> list:
    """One ``launch_ros.actions.Node`` per spec (package eit_skin, output to the screen).

    ``params_file`` (a ROS 2 parameters YAML; node names as ``/<ns>/<node>`` or wildcards
    ``/**/eit_driver``) is given to every node after the spec's parameters, so it can set
    any node parameter and overrides the launch arguments. Every node gets
    :data:`~eit_skin.ros.node_graph.NODE_ENVIRONMENT` (one BLAS thread), as in
    ``eit-skin run``.
    """
    from launch_ros.actions import Node

    return [
        Node(
            package="eit_skin",
            executable=spec.executable,
            name=spec.name,
            namespace=spec.namespace,
            parameters=[spec.parameters, *([params_file] if params_file else [])],
            additional_env=dict(NODE_ENVIRONMENT),
            output="screen",
        )
        for spec in specs
    ]


def rviz_actions(rviz_config: str) -> list:
    """rviz2 with ``rviz_config``, or, where rviz2 is not installed, one log line saying so.

    A missing rviz2 must not end the launch (which used to exit 1 and leave every skin node
    running as an orphan): the skin runs on without the viewer.
    """
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    from launch.actions import LogInfo
    from launch_ros.actions import Node

    try:
        get_package_prefix("rviz2")
    except PackageNotFoundError:
        return [
            LogInfo(
                msg="rviz:=true but rviz2 is not installed (apt install ros-$ROS_DISTRO-rviz2); "
                "the skin runs without it"
            )
        ]
    return [Node(package="rviz2", executable="rviz2", arguments=["-d", rviz_config])]
