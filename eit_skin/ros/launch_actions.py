"""launch_ros actions for node specs (imported by the launch files only, on a ROS install)."""

from __future__ import annotations

from eit_skin.ros.node_graph import NODE_ENVIRONMENT, NodeSpec


def ros_nodes(specs: list[NodeSpec]) -> list:
    """One ``launch_ros.actions.Node`` per spec (package eit_skin, output to the screen).

    Every node gets :data:`~eit_skin.ros.node_graph.NODE_ENVIRONMENT` (one BLAS thread), as in
    ``eit-skin run``.
    """
    from launch_ros.actions import Node

    return [
        Node(
            package="eit_skin",
            executable=spec.executable,
            name=spec.name,
            namespace=spec.namespace,
            parameters=[spec.parameters],
            additional_env=dict(NODE_ENVIRONMENT),
            output="screen",
        )
        for spec in specs
    ]
