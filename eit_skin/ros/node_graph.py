"""The node graph of one skin patch, shared by the launch files and ``eit-skin run``.

Both ``launch/*.launch.py`` (``ros2 launch`` on a robot) and the bring-up
command build their nodes from :func:`patch_nodes`, so the two cannot drift:
same executables, node names, namespaces and parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Patches of the whole robot, each started in the namespace of its name.
ROBOT_PATCHES: tuple[str, ...] = ("arm", "face", "elbow")

ParameterValue = str | int | float | bool

#: Environment of every node process (bring-up and launch files alike): one BLAS thread.
#: Each frame is one small matrix-vector product; BLAS worker threads only add wake-ups and
#: spinning, and several nodes share few cores (3-10x slower on a 2-core machine).
NODE_ENVIRONMENT: dict[str, str] = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


@dataclass(frozen=True)
class NodeSpec:
    """One node to start: an ``eit_skin`` console script with its ROS identity."""

    executable: str
    name: str
    namespace: str
    parameters: dict[str, ParameterValue] = field(default_factory=dict)


def patch_nodes(
    patch: str,
    namespace: str = "",
    port: str = "",
    sim: bool = True,
    rate_hz: float = 50.0,
    scenario: str = "",
    loop: bool = True,
) -> list[NodeSpec]:
    """Driver, reconstruction and classifier for one patch.

    Args:
        patch: shipped patch name (``arm``, ``face``, ``elbow``) or a path to a patch YAML.
        namespace: ROS namespace of the patch; defaults to the patch file's stem.
        port: serial device of the skin board; empty runs the physics simulator.
        sim: run the simulator; must be False when ``port`` is given, and a port
            is required when it is False.
        rate_hz: simulator frame rate, Hz.
        scenario: simulator touch script (name or path); empty = the default script.
        loop: simulator repeats its script forever (False: one pass, then idle).

    Raises:
        ValueError: contradictory arguments, naming them.
    """
    from eit_skin.resources import config_path

    if port and sim:
        raise ValueError(f"port {port!r} given together with sim:=true; choose one")
    if not port and not sim:
        raise ValueError("sim:=false needs a serial port (port:=/dev/...)")
    config = config_path(patch)
    if not config.is_file():
        raise ValueError(
            f"patch {patch!r}: no such patch file, and not a shipped patch "
            f"(valid: {', '.join(ROBOT_PATCHES)}, or a path to a patch YAML)"
        )
    ns = "/" + (namespace or config.stem).strip("/")
    patch_param: dict[str, ParameterValue] = {"patch_config": str(config)}
    driver: dict[str, ParameterValue] = {**patch_param, "port": port, "rate_hz": float(rate_hz)}
    if sim:
        driver.update({"scenario": scenario, "loop": bool(loop)})
    return [
        NodeSpec("eit_driver", "eit_driver", ns, driver),
        NodeSpec("eit_reconstruction", "eit_reconstruction", ns, dict(patch_param)),
        NodeSpec("eit_classifier", "eit_classifier", ns, dict(patch_param)),
    ]


def robot_nodes(
    sim: bool = True, rate_hz: float = 50.0, scenario: str = "", loop: bool = True
) -> list[NodeSpec]:
    """All shipped patches, each in its own namespace (simulated)."""
    nodes: list[NodeSpec] = []
    for name in ROBOT_PATCHES:
        nodes.extend(
            patch_nodes(name, name, sim=sim, rate_hz=rate_hz, scenario=scenario, loop=loop)
        )
    return nodes
