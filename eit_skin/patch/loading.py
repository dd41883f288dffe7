"""Patch files -> validated :class:`~eit_skin.patch.model.Patch` (schema: docs/patch-schema.md).

:func:`load_patch` reads a YAML file with the package's one YAML reader
(:mod:`eit_skin.patch.yaml_reader`: YAML 1.2 numbers, duplicate keys refused);
:func:`patch_from_dict` validates already-parsed data. Outlines, electrodes and holes have
their own modules; the small sections (material, protocol, mesh, solver, placement) are
read here. A layer whose mesh would be too big to build is refused with an estimate
(:mod:`eit_skin.patch.mesh_budget`). Any problem raises
:class:`~eit_skin.patch.model.PatchError` ``"<file>: <key.path[3].x>: <reason>"``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.device import (
    DEFAULT_PROFILE,
    PROFILES,
    DeviceSpec,
    device_from_mapping,
    device_problem,
)
from eit_skin.patch.electrodes import read_electrodes
from eit_skin.patch.holes import read_holes
from eit_skin.patch.material import QUANTITIES, RESPONSES, Material
from eit_skin.patch.mesh_budget import budget_problem
from eit_skin.patch.model import (
    CHANNEL_WEIGHTS,
    METHODS,
    PRIOR_KINDS,
    AccuracyTarget,
    Electrode,
    Layer,
    MeshSpec,
    Mount,
    Patch,
    PatchError,
    SolverSpec,
    tank_refusal,
)
from eit_skin.patch.outline import read_outline
from eit_skin.patch.placement import (
    CylinderPlacement,
    HeightmapPlacement,
    Placement,
    PlanePlacement,
)
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from eit_skin.patch.yaml_reader import Reader, read_yaml

__all__ = ["load_patch", "patch_from_dict"]

LAYER_KEYS = (
    "name",
    "outline",
    "electrodes",
    "material",
    "holes",
    "current",
    "full_scale_v",
    "depth",
    "protocol",
    "mesh",
    "solver",
    "device",
)
"""Keys of a layer (the first four are required)."""

PLACEMENT_KEYS = {
    "plane": ("origin", "rpy"),
    "cylinder": ("radius", "axis", "origin", "reference"),
    "heightmap": ("heights", "bounds", "origin", "rpy"),
}
"""Keys of each placement ``type`` (besides ``type``)."""

_PROTOCOL_KEYS = tuple(f.name for f in fields(ProtocolSpec))


def load_patch(path: str | Path) -> Patch:
    """Read and validate a patch YAML file.

    Raises:
        PatchError: the file is not a valid patch, naming the file and the key.

    >>> from eit_skin.resources import config_path
    >>> patch = load_patch(config_path("face"))  # a shipped patch; any YAML path works
    >>> [(layer.name, layer.n_electrodes, layer.material.quantity) for layer in patch.layers]
    [('pressure', 16, 'pressure')]
    """
    return patch_from_dict(read_yaml(path, PatchError), source=str(path))


def patch_from_dict(data: Any, source: str = "<dict>", *, check_budget: bool = True) -> Patch:
    """Validate already-parsed patch data (same schema as the YAML file).

    ``check_budget=False`` skips the mesh size limit (only for measuring it, bench/).
    """
    r = Reader(source, PatchError)
    top = r.mapping(
        data, "", required=("name", "frame_id", "layers"), optional=("placement", "mount")
    )
    name = r.string(top, "name", "")
    frame_id = r.string(top, "frame_id", "")
    items = r.sequence(top["layers"], "layers", min_len=1)
    layers = []
    for i, item in enumerate(items):
        layer = _layer(r, item, f"layers[{i}]", check_budget)
        if any(existing.name == layer.name for existing in layers):
            raise r.error(f"layers[{i}].name", f"duplicate layer name {layer.name!r}")
        layers.append(layer)
    placement = _placement(r, top.get("placement", {"type": "plane"}), "placement", layers)
    mount = _mount(r, top["mount"], "mount", frame_id) if "mount" in top else Mount()
    return Patch(name, frame_id, tuple(layers), placement, source, mount)


def _mount(r: Reader, data: Any, path: str, frame_id: str) -> Mount:
    """``mount: {parent_frame, xyz (m), rpy (rad)}``: the patch frame's pose on the robot."""
    d = r.mapping(data, path, required=("parent_frame",), optional=("xyz", "rpy"))
    parent = r.string(d, "parent_frame", path)
    if parent == frame_id:
        raise r.error(r.join(path, "parent_frame"), f"is the patch's own frame_id {frame_id!r}")
    xyz = r.vector(d.get("xyz", [0, 0, 0]), r.join(path, "xyz"), 3)
    rpy = r.vector(d.get("rpy", [0, 0, 0]), r.join(path, "rpy"), 3)
    return Mount(parent, tuple(float(v) for v in xyz), tuple(float(v) for v in rpy))


def _layer(r: Reader, data: Any, path: str, check_budget: bool) -> Layer:
    d = r.mapping(data, path, required=LAYER_KEYS[:4], optional=LAYER_KEYS[4:])
    name = r.string(d, "name", path)
    kind, outline = read_outline(r, d["outline"], r.join(path, "outline"))
    electrodes, contact = read_electrodes(
        r, d["electrodes"], r.join(path, "electrodes"), kind, outline
    )
    holes = read_holes(r, d.get("holes", []), r.join(path, "holes"), outline, electrodes)
    current = r.number(d, "current", path, default=1e-3, positive=True)
    full_scale = r.number(d, "full_scale_v", path, default=None, positive=True, allow_none=True)
    material = _material(r, d["material"], r.join(path, "material"))
    protocol = _protocol(r, d.get("protocol", {}), r.join(path, "protocol"), len(electrodes))
    mesh = _mesh_spec(r, d.get("mesh", {}), r.join(path, "mesh"), outline, electrodes)
    solver = _solver_spec(r, d.get("solver", {}), r.join(path, "solver"))
    device = _device(r, d.get("device", {}), path, protocol, len(electrodes), current)
    depth = _depth(r, d, path, electrodes, material)
    if solver.accuracy_target is not None:
        _refuse_chosen_keys(r, d, path)
    for array in (outline, *holes):
        array.setflags(write=False)
    layer = Layer(
        name=name,
        outline_kind=kind,
        outline=outline,
        holes=holes,
        electrodes=electrodes,
        contact_impedance_ohm_m=contact,
        current_a=current,
        protocol=protocol,
        material=material,
        mesh=mesh,
        solver=solver,
        device=device,
        full_scale_v=full_scale,
        depth_m=depth,
    )
    if check_budget:
        problem = budget_problem(layer)
        if problem is not None:
            key, reason = problem
            raise r.error(r.join(r.join(path, "mesh"), key), reason)
    return layer


def _depth(r: Reader, d: dict, path: str, electrodes, material: Material) -> float | None:
    """``depth`` (m): a tank's; refused where the model cannot honour it."""
    depth = r.number(d, "depth", path, default=None, positive=True, allow_none=True)
    if depth is None:
        return None
    where = r.join(path, "depth")
    refusal = tank_refusal(material, electrodes)
    if refusal is not None:
        raise r.error(where, refusal)
    height = electrodes[0].width_m
    if depth < height:
        raise r.error(where, f"{depth} m is less than the electrodes' height {height} m")
    return float(depth)


def _material(r: Reader, data: Any, path: str) -> Material:
    d = r.mapping(
        data,
        path,
        required=("quantity",),
        optional=(
            "sheet_conductance",
            "volume_resistivity",
            "thickness",
            "pressure_scale",
            "gauge_factor",
            "response",
        ),
    )
    quantity = r.string(d, "quantity", path, choices=QUANTITIES)
    if "sheet_conductance" in d:
        for key in ("volume_resistivity", "thickness"):
            if key in d:
                raise r.error(
                    r.join(path, key),
                    "give sheet_conductance or volume_resistivity + thickness, not both",
                )
        conductance = r.number(d, "sheet_conductance", path)
        if conductance <= 0:
            raise r.error(
                r.join(path, "sheet_conductance"), f"conductance must be > 0 S, got {conductance:g}"
            )
    elif "volume_resistivity" in d:
        rho = r.number(d, "volume_resistivity", path)
        if rho <= 0:
            raise r.error(
                r.join(path, "volume_resistivity"), f"resistivity must be > 0 ohm*m, got {rho:g}"
            )
        thickness = r.number(d, "thickness", path, positive=True)
        conductance = thickness / rho
    else:
        raise r.error(
            r.join(path, "sheet_conductance"),
            "missing required key (or volume_resistivity + thickness)",
        )
    if quantity == "pressure":
        if "gauge_factor" in d:
            raise r.error(r.join(path, "gauge_factor"), "only for quantity: stretch")
        scale = r.number(d, "pressure_scale", path, positive=True)
        response = r.string(d, "response", path, default=RESPONSES[0], choices=RESPONSES)
        return Material(quantity, conductance, pressure_scale_pa=scale, response=response)
    for key in ("pressure_scale", "response"):
        if key in d:
            raise r.error(r.join(path, key), "only for quantity: pressure")
    gain = r.number(d, "gauge_factor", path, positive=True)
    return Material(quantity, conductance, gauge_factor=gain)


def _protocol(r: Reader, data: Any, path: str, n_electrodes: int) -> ProtocolSpec:
    d = r.mapping(data, path, optional=_PROTOCOL_KEYS)
    kwargs = {}
    for key, value in d.items():
        if key in ("injections", "measurements", "currents") and value is not None:
            value = tuple(
                tuple(row) if isinstance(row, (list, tuple)) else row
                for row in r.sequence(value, r.join(path, key))
            )
        elif key == "electrode_order" and value is not None:
            value = tuple(r.sequence(value, r.join(path, key)))
        kwargs[key] = value
    try:
        spec = ProtocolSpec(**kwargs)
        spec.validate(n_electrodes)
        build_protocol(spec, n_electrodes)
    except ValueError as exc:
        raise _protocol_error(r, path, str(exc)) from None
    return spec


def _device(
    r: Reader, data: Any, layer_path: str, spec: ProtocolSpec, n_electrodes: int, current: float
) -> DeviceSpec:
    """``device: {profile, <the profile's options>}`` (eit_skin.patch.device)."""
    path = r.join(layer_path, "device")
    d = r.any_mapping(data, path)
    profile = r.string(d, "profile", path, default=DEFAULT_PROFILE, choices=tuple(PROFILES))
    names = tuple(option.name for option in PROFILES[profile])
    r.mapping(d, path, optional=("profile", *names), what=f"{profile} device")
    device = device_from_mapping(d, path, r.error)
    problem = device_problem(device, spec, build_protocol(spec, n_electrodes), current)
    if problem is not None:
        key, reason = problem
        raise r.error(r.join(layer_path, key), reason)
    return device


def _protocol_error(r: Reader, path: str, message: str) -> PatchError:
    """Turn ``"key[3]: reason"`` from ProtocolSpec into a key path under ``path``."""
    head, sep, reason = message.partition(": ")
    key = head.split("[", 1)[0]
    if sep and key in _PROTOCOL_KEYS:
        return r.error(f"{path}.{head}", reason)
    return r.error(path, message)


def _mesh_spec(
    r: Reader, data: Any, path: str, outline: np.ndarray, electrodes: tuple[Electrode, ...]
) -> MeshSpec:
    d = r.mapping(
        data, path, optional=("max_edge", "electrode_edge", "min_angle", "inverse_max_edge")
    )
    perimeter = float(geometry.arc_positions(outline)[-1])
    max_edge = r.number(d, "max_edge", path, default=perimeter / 100.0, positive=True)
    width = min(e.width_m for e in electrodes)
    electrode_edge = r.number(
        d, "electrode_edge", path, default=min(max_edge, width / 4.0), positive=True
    )
    min_angle = r.number(d, "min_angle", path, default=30.0)
    inverse = r.number(d, "inverse_max_edge", path, default=None, positive=True, allow_none=True)
    try:
        return MeshSpec(max_edge, electrode_edge, min_angle, inverse)
    except ValueError as exc:
        key, _, reason = str(exc).partition(": ")
        raise r.error(r.join(path, key), reason) from None


def _method_and_prior(r: Reader, d: Mapping, path: str, defaults: SolverSpec) -> tuple[str, str]:
    """``solver.method`` and ``solver.prior``; the old spelling ``prior: greit`` means method greit.

    Files written before GREIT became a method (``method: one_step, prior: greit``) keep
    working and load as ``method: greit`` (same content hash as the new spelling).
    """
    method = r.string(d, "method", path, default=defaults.method, choices=METHODS)
    if d.get("prior") != "greit":
        return method, r.string(d, "prior", path, default=defaults.prior, choices=PRIOR_KINDS)
    if method not in ("one_step", "greit"):
        raise r.error(
            r.join(path, "prior"),
            f"'greit' is a one-step method and cannot be the prior of method {method!r}; "
            f"choose one of {', '.join(PRIOR_KINDS)}",
        )
    return "greit", defaults.prior


#: What ``solver.accuracy_target`` chooses: ``(section, key)`` pairs a layer with a target may
#: not give (both would be one decision made twice). ``mesh.min_angle`` (quality) stays free.
CHOSEN_BY_TARGET = (
    ("mesh", "max_edge"),
    ("mesh", "electrode_edge"),
    ("mesh", "inverse_max_edge"),
    ("solver", "image_pixels"),
    ("solver", "max_iterations"),
)


def _refuse_chosen_keys(r: Reader, d: Mapping, path: str) -> None:
    """A layer with ``solver.accuracy_target`` gives no mesh size, pixel or iteration count."""
    for section, key in CHOSEN_BY_TARGET:
        given = d.get(section)
        if isinstance(given, Mapping) and key in given:
            raise r.error(
                r.join(r.join(path, section), key),
                f"{path}.solver.accuracy_target chooses it; give {section}.{key} or the "
                "accuracy target, not both",
            )


def _accuracy_target(r: Reader, data: Any, path: str) -> AccuracyTarget:
    d = r.mapping(
        data,
        path,
        required=("position_error_percent",),
        optional=("amplitude_error_percent",),
    )
    position = r.number(d, "position_error_percent", path, positive=True)
    amplitude = r.number(
        d, "amplitude_error_percent", path, default=None, positive=True, allow_none=True
    )
    return AccuracyTarget(position, amplitude, source=r.source, key=path)


def _solver_spec(r: Reader, data: Any, path: str) -> SolverSpec:
    d = r.mapping(data, path, optional=tuple(f.name for f in fields(SolverSpec)))
    defaults = SolverSpec()
    method, prior = _method_and_prior(r, d, path, defaults)
    kwargs = {
        "method": method,
        "prior": prior,
        "hyperparameter": r.number(
            d, "hyperparameter", path, default=None, positive=True, allow_none=True
        ),
        "noise_figure": r.number(
            d, "noise_figure", path, default=None, positive=True, allow_none=True
        ),
        "max_iterations": r.integer(
            d, "max_iterations", path, default=defaults.max_iterations, minimum=1
        ),
        "image_pixels": r.integer(
            d, "image_pixels", path, default=defaults.image_pixels, minimum=8
        ),
        "reference_frames": r.integer(
            d, "reference_frames", path, default=defaults.reference_frames, minimum=1
        ),
        "channel_weights": r.string(
            d,
            "channel_weights",
            path,
            default=defaults.channel_weights,
            choices=CHANNEL_WEIGHTS,
        ),
        "accuracy_target": None
        if d.get("accuracy_target") is None
        else _accuracy_target(r, d["accuracy_target"], r.join(path, "accuracy_target")),
    }
    return SolverSpec(**kwargs)


def _placement(r: Reader, data: Any, path: str, layers: list[Layer]) -> Placement:
    kind, d = r.variant(data, path, PLACEMENT_KEYS, "placement")
    origin = r.vector(d.get("origin", [0, 0, 0]), r.join(path, "origin"), 3)
    try:
        if kind == "plane":
            rpy = r.vector(d.get("rpy", [0, 0, 0]), r.join(path, "rpy"), 3)
            return PlanePlacement(origin=origin, rpy=rpy)
        if kind == "cylinder":
            radius = r.number(d, "radius", path, positive=True)
            axis = r.vector(d.get("axis", [1, 0, 0]), r.join(path, "axis"), 3)
            reference = (
                r.vector(d["reference"], r.join(path, "reference"), 3) if "reference" in d else None
            )
            return CylinderPlacement(radius=radius, axis=axis, origin=origin, reference=reference)
        rpy = r.vector(d.get("rpy", [0, 0, 0]), r.join(path, "rpy"), 3)
        hpath = r.join(path, "heights")
        if "heights" not in d:
            raise r.error(hpath, "missing required key")
        rows = r.sequence(d["heights"], hpath, min_len=2)
        grid = []
        for i, row in enumerate(rows):
            values = r.sequence(row, r.join(hpath, i), min_len=2)
            grid.append([r.as_float(v, r.join(r.join(hpath, i), j)) for j, v in enumerate(values)])
        if len({len(row) for row in grid}) != 1:
            raise r.error(hpath, "rows must all have the same length")
        if "bounds" in d:
            bounds = r.vector(d["bounds"], r.join(path, "bounds"), 4)
        else:
            allpts = np.concatenate([layer.outline for layer in layers])
            lo, hi = allpts.min(axis=0), allpts.max(axis=0)
            bounds = np.array([lo[0], hi[0], lo[1], hi[1]])
        return HeightmapPlacement(heights=np.array(grid), bounds=bounds, origin=origin, rpy=rpy)
    except ValueError as exc:
        if isinstance(exc, PatchError):
            raise
        raise r.error(path, str(exc)) from None
