"""The node graph of one skin patch, shared by the launch files and ``eit-skin run``.

Both ``launch/*.launch.py`` (``ros2 launch`` on a robot) and the bring-up
command build their nodes from :func:`patch_nodes`, so the two cannot drift:
same executables, node names, namespaces and parameters.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

#: Patches of the whole robot, each started in the namespace of its name.
ROBOT_PATCHES: tuple[str, ...] = ("arm", "face", "elbow")

ParameterValue = str | int | float | bool | list[float]

PORTS_FILE = "ports.yaml"
"""The shipped ports file (``config/ports.yaml``): patch namespace -> layer -> device."""

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
    ports: Mapping[str, str] | None = None,
    overrides: Mapping[str, Mapping[str, ParameterValue]] | None = None,
) -> list[NodeSpec]:
    """Driver(s), reconstruction and classifier for one patch.

    One driver per board: ``eit_driver`` for the simulator or a patch on one board, else
    ``eit_driver_<layer>`` per layer, each with its ``layer`` and ``port``. Every layer of
    the patch gets a source, or the graph is refused: a layer without one would publish
    nothing while the others look healthy.

    Args:
        patch: shipped patch name (``arm``, ``face``, ``elbow``) or a path to a patch YAML.
        namespace: ROS namespace of the patch; defaults to the patch file's stem.
        port: serial device of the board of a one-layer patch; empty runs the simulator.
        sim: run the simulator; must be False when ``port`` or ``ports`` is given, and a
            port is required when it is False.
        rate_hz: simulator frame rate, Hz.
        scenario: simulator touch script (name or path); empty = the default script.
        loop: simulator repeats its script forever (False: one pass, then idle).
        ports: layer name -> serial device of its board (one driver each); every layer of
            the patch must have one (:func:`parse_ports`, :func:`read_ports_file`).
        overrides: executable -> parameters set on top of the graph's own (launch
            arguments, :func:`eit_skin.ros.parameters.launch_overrides`).

    Raises:
        ValueError: contradictory arguments, an unknown patch, a layer without a port or a
            port for no layer, naming them.
    """
    from eit_skin.patch.loading import load_patch
    from eit_skin.resources import config_path

    ports = dict(ports or {})
    _check_source(port, ports, sim)
    config = config_path(patch)
    if not config.is_file():
        raise ValueError(
            f"patch {patch!r}: no such patch file, and not a shipped patch "
            f"(valid: {', '.join(ROBOT_PATCHES)}, or a path to a patch YAML)"
        )
    layers = load_patch(config).layer_names
    ports = _layer_ports(patch, layers, port, ports)
    ns = "/" + (namespace or config.stem).strip("/")
    patch_param: dict[str, ParameterValue] = {"patch_config": str(config)}
    overrides = overrides or {}

    def spec(executable: str, name: str, parameters: dict[str, ParameterValue]) -> NodeSpec:
        return NodeSpec(executable, name, ns, {**parameters, **overrides.get(executable, {})})

    if ports and len(ports) > 1:
        drivers = [
            spec(
                "eit_driver",
                f"eit_driver_{layer}",
                # one static transform per patch frame: the first board's driver sends it
                {**patch_param, "layer": layer, "port": ports[layer], "publish_tf": index == 0},
            )
            for index, layer in enumerate(layers)
        ]
    else:
        driver: dict[str, ParameterValue] = {**patch_param, "port": ports.get(layers[0], "")}
        driver["rate_hz"] = float(rate_hz)
        if sim:
            driver.update({"scenario": scenario, "loop": bool(loop)})
        drivers = [spec("eit_driver", "eit_driver", driver)]
    return [
        *drivers,
        spec("eit_reconstruction", "eit_reconstruction", dict(patch_param)),
        spec("eit_classifier", "eit_classifier", dict(patch_param)),
    ]


def _check_source(port: str, ports: dict[str, str], sim: bool) -> None:
    """Refuse a graph with both ``port`` and ``ports``, with a port and ``sim``, or neither."""
    if port and ports:
        raise ValueError(f"port {port!r} given together with ports {ports}; choose one")
    if (port or ports) and sim:
        raise ValueError(f"port(s) {port or ports} given together with sim:=true; choose one")
    if not (port or ports) and not sim:
        raise ValueError("sim:=false needs a serial port (port:=/dev/... or ports:=LAYER=/dev/...)")


def _layer_ports(
    patch: str, layers: tuple[str, ...], port: str, ports: dict[str, str]
) -> dict[str, str]:
    """Layer name -> serial device, from one ``port`` or the ``ports`` map (empty: simulator).

    Raises:
        ValueError: ``port`` for a patch of several layers, a port for no layer or a layer
            without a port.
    """
    if port:
        if len(layers) > 1:
            raise ValueError(
                f"patch {patch!r} has layers {', '.join(layers)}, one board each: give "
                f"ports:={','.join(f'{name}=/dev/...' for name in layers)} instead of port:="
            )
        ports = {layers[0]: port}
    unknown = sorted(set(ports) - set(layers))
    if unknown:
        raise ValueError(f"ports: patch {patch!r} has no layer {unknown} (layers: {layers})")
    missing = [name for name in layers if ports and name not in ports]
    if missing:
        raise ValueError(
            f"ports: no port for layer(s) {', '.join(missing)} of patch {patch!r}: "
            "every layer needs its board"
        )
    return ports


def robot_nodes(
    sim: bool = True,
    rate_hz: float = 50.0,
    scenario: str = "",
    loop: bool = True,
    ports_file: str = "",
    overrides: Mapping[str, Mapping[str, ParameterValue]] | None = None,
) -> list[NodeSpec]:
    """All shipped patches, each in its own namespace.

    Simulated, or with ``sim`` False on the boards of ``ports_file`` (:func:`read_ports_file`;
    empty: the shipped ``config/ports.yaml``).
    """
    nodes: list[NodeSpec] = []
    for name in ROBOT_PATCHES:
        ports = None if sim else read_ports_file(ports_file, name)
        nodes.extend(
            patch_nodes(
                name,
                name,
                sim=sim,
                rate_hz=rate_hz,
                scenario=scenario,
                loop=loop,
                ports=ports,
                overrides=overrides,
            )
        )
    return nodes


def parse_ports(text: str) -> dict[str, str]:
    """``"pressure=/dev/ttyA,stretch=/dev/ttyB"`` -> ``{"pressure": "/dev/ttyA", ...}``.

    Raises:
        ValueError: an entry that is not ``LAYER=DEVICE``, or a layer named twice.
    """
    ports: dict[str, str] = {}
    for entry in (item.strip() for item in text.split(",")):
        if not entry:
            continue
        layer, sep, device = (part.strip() for part in entry.partition("="))
        if not sep or not layer or not device:
            raise ValueError(f"ports: {entry!r} is not LAYER=DEVICE (e.g. pressure=/dev/ttyACM0)")
        if layer in ports:
            raise ValueError(f"ports: layer {layer!r} given twice")
        ports[layer] = device
    return ports


def read_ports_file(path: str, patch: str) -> dict[str, str]:
    """The ports of one patch from a ports file (default: the shipped ``config/ports.yaml``).

    The file maps a patch's namespace (``arm``) to its layers' serial devices
    (``pressure: /dev/eit_skin_arm_pressure``).

    Raises:
        ValueError (a ``ConfigError`` naming the file and key): no such file, not that
        shape, or no entry for ``patch``.
    """
    from eit_skin.patch.yaml_reader import ConfigError, Reader, read_yaml
    from eit_skin.resources import config_path

    source = str(config_path(path or PORTS_FILE))
    r = Reader(source, ConfigError)
    top = r.any_mapping(read_yaml(source, ConfigError), "")
    key = patch.strip("/")
    if key not in top:
        raise r.error(key, f"no ports for patch {key!r} (patches in the file: {', '.join(top)})")
    entries = r.any_mapping(top[key], key)
    return {layer: r.string(entries, layer, key) for layer in entries}
