"""launch_ros actions for node specs (imported by the launch files only, on a ROS install)."""

from __future__ import annotations

from eit_skin.node_graph import NodeSpec


def ros_nodes(specs: list[NodeSpec]) -> list:
    """One ``launch_ros.actions.Node`` per spec (package eit_skin, output to the screen)."""
    from launch_ros.actions import Node

    return [
        Node(
            package="eit_skin",
            executable=spec.executable,
            name=spec.name,
            namespace=spec.namespace,
            parameters=[spec.parameters],
            output="screen",
        )
        for spec in specs
    ]
