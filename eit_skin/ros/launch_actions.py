"""launch_ros actions for node specs (imported by the launch files only, on a ROS install).

The launch files stay declarations: the arguments every node parameter gets
(:func:`parameter_arguments`), the nodes of the patch(es) from
:mod:`eit_skin.ros.node_graph` (:func:`patch_launch_nodes`, :func:`robot_launch_nodes`) and
rviz2 with a configuration generated for them (:func:`rviz_actions`).
"""

from __future__ import annotations

import os

from eit_skin.ros.node_graph import (
    NODE_ENVIRONMENT,
    NodeSpec,
    parse_ports,
    patch_nodes,
    read_ports_file,
    robot_nodes,
)
from eit_skin.ros.parameters import NODE_PARAMETERS, launch_arguments, launch_overrides


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


def parameter_arguments(declared: set[str]) -> list:
    """A ``DeclareLaunchArgument`` (default empty: not given) per node parameter.

    ``declared``: arguments the launch file declares itself (e.g. ``rate_hz``), left out.
    """
    from launch.actions import DeclareLaunchArgument

    return [
        DeclareLaunchArgument(name, default_value="", description=description)
        for name, description in launch_arguments().items()
        if name not in declared
    ]


def _text(context, name: str) -> str:
    from launch.substitutions import LaunchConfiguration

    return LaunchConfiguration(name).perform(context)


def _overrides(context) -> dict[str, dict[str, object]]:
    """Executable -> the node parameters given as launch arguments (typed).

    Every name of :func:`~eit_skin.ros.parameters.launch_arguments` is declared, by
    :func:`parameter_arguments` or by the launch file itself (``rate_hz``).
    """
    texts = {name: _text(context, name) for name in launch_arguments()}
    return {executable: launch_overrides(executable, texts) for executable in NODE_PARAMETERS}


def _truthy(text: str) -> bool:
    return text.strip().lower() in ("1", "true", "yes", "on")


def patch_launch_nodes(context) -> list[NodeSpec]:
    """The nodes of skin_patch.launch.py from its arguments (see its docstring)."""
    port, ports_text, ports_file = (_text(context, n) for n in ("port", "ports", "ports_file"))
    patch, namespace = _text(context, "patch"), _text(context, "namespace")
    if ports_text and ports_file:
        raise ValueError("ports:= and ports_file:= given; choose one")
    ports = parse_ports(ports_text)
    if ports_file:
        from eit_skin.resources import config_path

        ports = read_ports_file(ports_file, namespace or config_path(patch).stem)
    sim_text = _text(context, "sim")
    sim = _truthy(sim_text) if sim_text else not (port or ports)
    return patch_nodes(
        patch,
        namespace=namespace,
        port=port,
        sim=sim,
        rate_hz=float(_text(context, "rate_hz")),
        ports=ports,
        overrides=_overrides(context),
    )


def robot_launch_nodes(context) -> list[NodeSpec]:
    """The nodes of robot_skin.launch.py from its arguments (see its docstring)."""
    return robot_nodes(
        sim=_truthy(_text(context, "sim")),
        rate_hz=float(_text(context, "rate_hz")),
        ports_file=_text(context, "ports_file"),
        overrides=_overrides(context),
    )


def launch_nodes(context, specs: list[NodeSpec]) -> list:
    """The ``Node`` actions of ``specs`` with the ``params_file`` argument, checked to exist."""
    params_file = _text(context, "params_file")
    if params_file and not os.path.isfile(params_file):
        raise FileNotFoundError(f"params_file {params_file!r}: no such file")
    return ros_nodes(specs, params_file)


def rviz_actions(specs: list[NodeSpec]) -> list:
    """rviz2 showing the patches of ``specs``; where rviz2 is not installed, a log line.

    The configuration (:mod:`eit_skin.ros.rviz_config`) names the topics of each launched
    patch in its namespace, written to a fresh temporary folder. A missing rviz2 must not
    end the launch (which used to exit 1 and leave every skin node running as an orphan):
    the skin runs on without the viewer.
    """
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    from launch.actions import LogInfo
    from launch_ros.actions import Node

    from eit_skin.patch.loading import load_patch
    from eit_skin.ros.rviz_config import write_rviz_config

    try:
        get_package_prefix("rviz2")
    except PackageNotFoundError:
        return [
            LogInfo(
                msg="rviz:=true but rviz2 is not installed (apt install ros-$ROS_DISTRO-rviz2); "
                "the skin runs without it"
            )
        ]
    patches = [
        (load_patch(str(spec.parameters["patch_config"])), spec.namespace)
        for spec in specs
        if spec.executable == "eit_reconstruction"
    ]
    config = write_rviz_config(patches)
    return [
        LogInfo(msg=f"rviz2 configuration for this launch: {config}"),
        Node(package="rviz2", executable="rviz2", arguments=["-d", str(config)]),
    ]
