"""Skin patch descriptions: YAML file -> validated :class:`Patch` in SI units.

A patch is one piece of skin on the robot: a ROS ``frame_id``, a 3-D
:mod:`placement <eit_skin.patch.placement>` for visualisation and one or more
stacked **layers**, each its own EIT domain (outline, holes, electrodes,
material, protocol, mesh and solver settings).  The schema is documented in
``docs/patch-schema.md``.

Conventions (metres, patch frame):

* outlines are counter-clockwise; arc-length positions are measured
  counter-clockwise from the outline's first vertex (circle: the point at
  angle 0, ``center + (radius, 0)``; rectangle: the lower-left corner;
  polygon: the first listed point);
* holes are stored clockwise (the sheet is left of every boundary loop);
* electrodes are numbered counter-clockwise in the order of their centres.

Any problem raises :class:`PatchError` ``"<file>: <key.path[3].x>: <reason>"``.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields, is_dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eit_skin.inverse.methods import METHODS
from eit_skin.inverse.priors import PRIOR_KINDS
from eit_skin.patch import geometry
from eit_skin.patch.material import QUANTITIES, Material
from eit_skin.patch.placement import (
    PLACEMENT_TYPES,
    CylinderPlacement,
    HeightmapPlacement,
    Placement,
    PlanePlacement,
)
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

__all__ = [
    "Electrode",
    "Layer",
    "MeshSpec",
    "Patch",
    "PatchError",
    "SolverSpec",
    "load_patch",
    "patch_from_dict",
]

OUTLINE_CIRCLE_SEGMENTS = 128
HOLE_CIRCLE_SEGMENTS = 16
MIN_ELECTRODES = 4


class PatchError(ValueError):
    """A patch file is invalid: ``"<file>: <key path>: <reason>"``."""

    def __init__(self, source: str, key_path: str, reason: str) -> None:
        self.source = source
        self.key_path = key_path or "(root)"
        self.reason = reason
        super().__init__(f"{source}: {self.key_path}: {reason}")


# --------------------------------------------------------------------------- data types


@dataclass(frozen=True, eq=False)
class Electrode:
    """One boundary electrode.

    Attributes:
        start_m, end_m: arc-length positions (m) of its ends along the outline, measured
            counter-clockwise from the outline's start point, in ``[0, perimeter)``;
            ``end_m < start_m`` when the electrode covers the start point.
        width_m: length along the outline, m.
        center: ``[2]`` point of the outline at its middle, m.
        center_m: arc-length position of its middle, m.
    """

    start_m: float
    end_m: float
    width_m: float
    center: np.ndarray
    center_m: float


@dataclass(frozen=True)
class MeshSpec:
    """Mesh sizing of one layer.

    Attributes:
        max_edge_m: global target edge length, m.
        electrode_edge_m: edge length on and next to electrodes, m (<= max_edge_m).
        min_angle_deg: smallest triangle angle Triangle must guarantee, degrees (0, 34].
        inverse_max_edge_m: edge length of the coarse inverse mesh, m, or ``None`` (same mesh).
    """

    max_edge_m: float
    electrode_edge_m: float
    min_angle_deg: float = 30.0
    inverse_max_edge_m: float | None = None

    def __post_init__(self) -> None:
        if not self.max_edge_m > 0:
            raise ValueError(f"max_edge: must be > 0 m, got {self.max_edge_m}")
        if not 0 < self.electrode_edge_m <= self.max_edge_m:
            raise ValueError(
                f"electrode_edge: must be > 0 and <= max_edge ({self.max_edge_m} m), "
                f"got {self.electrode_edge_m}"
            )
        if not 0 < self.min_angle_deg <= 34:
            raise ValueError(
                f"min_angle: must be in (0, 34] degrees (Triangle's guaranteed range), "
                f"got {self.min_angle_deg}"
            )
        if self.inverse_max_edge_m is not None and not self.inverse_max_edge_m > 0:
            raise ValueError(f"inverse_max_edge: must be > 0 m, got {self.inverse_max_edge_m}")


@dataclass(frozen=True)
class SolverSpec:
    """Reconstruction settings of one layer (used by the reconstruction engine).

    Attributes:
        method: ``"one_step"`` (linearised, precomputed matrix with ``prior``), ``"greit"``
            (the trained one-step matrix, no prior) or ``"gauss_newton"`` (iterative, with
            ``prior``); :data:`eit_skin.inverse.methods.METHODS`.
        prior: regularisation ``"laplace"``, ``"tikhonov"`` or ``"noser"``.
        hyperparameter: regularisation weight, or ``None`` to choose it from ``noise_figure``.
        noise_figure: target noise figure for the automatic hyperparameter (> 0).
        max_iterations: Gauss-Newton iterations (>= 1).
        image_pixels: pixels along the long side of the ``H x W`` image grid (>= 8).
        reference_frames: frames averaged into the reference (no-touch) measurement (>= 1).
    """

    method: str = "one_step"
    prior: str = "laplace"
    hyperparameter: float | None = None
    noise_figure: float = 1.0
    max_iterations: int = 5
    image_pixels: int = 64
    reference_frames: int = 20

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method: unknown {self.method!r}; expected one of {METHODS}")
        if self.prior == "greit":
            raise ValueError("prior: 'greit' is a method, not a prior; write method: greit")
        if self.prior not in PRIOR_KINDS:
            raise ValueError(f"prior: unknown {self.prior!r}; expected one of {PRIOR_KINDS}")
        if self.hyperparameter is not None and not self.hyperparameter > 0:
            raise ValueError(f"hyperparameter: must be > 0 or null, got {self.hyperparameter}")
        if not self.noise_figure > 0:
            raise ValueError(f"noise_figure: must be > 0, got {self.noise_figure}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations: must be >= 1, got {self.max_iterations}")
        if self.image_pixels < 8:
            raise ValueError(f"image_pixels: must be >= 8, got {self.image_pixels}")
        if self.reference_frames < 1:
            raise ValueError(f"reference_frames: must be >= 1, got {self.reference_frames}")


@dataclass(frozen=True, eq=False)
class Layer:
    """One sheet of a patch: its own EIT domain.

    Attributes:
        name: layer name, unique in the patch.
        outline_kind: ``"circle"``, ``"rectangle"`` or ``"polygon"`` (as written in the file).
        outline: ``[n, 2]`` CCW polygon, m (circles discretised into regular polygons).
        holes: ``[k_i, 2]`` clockwise polygons, m, strictly inside the outline.
        electrodes: electrodes in counter-clockwise order.
        contact_impedance_ohm_m: 2-D complete-electrode-model contact impedance, ohm*m.
        current_a: injected current amplitude, A.
        protocol: drive/measurement protocol.
        material: sheet material.
        mesh: mesh sizing.
        solver: reconstruction settings.
    """

    name: str
    outline_kind: str
    outline: np.ndarray
    holes: tuple[np.ndarray, ...]
    electrodes: tuple[Electrode, ...]
    contact_impedance_ohm_m: float
    current_a: float
    protocol: ProtocolSpec
    material: Material
    mesh: MeshSpec
    solver: SolverSpec

    @property
    def n_electrodes(self) -> int:
        return len(self.electrodes)

    @property
    def perimeter_m(self) -> float:
        """Outline perimeter, m."""
        return float(geometry.arc_positions(self.outline)[-1])

    @property
    def area_m2(self) -> float:
        """Sheet area without holes, m^2."""
        return geometry.signed_area(self.outline) + sum(geometry.signed_area(h) for h in self.holes)

    @cached_property
    def content_hash(self) -> str:
        """sha256 hex digest of the layer's normalised content (cache key)."""
        return _hash(_canonical(self))


@dataclass(frozen=True, eq=False)
class Patch:
    """A validated skin patch.

    Attributes:
        name: patch name.
        frame_id: ROS frame the sheet coordinates live in.
        layers: stacked sheets, in file order.
        placement: 3-D placement for visualisation.
        source: file the patch was read from (``"<dict>"`` for in-memory data).
    """

    name: str
    frame_id: str
    layers: tuple[Layer, ...]
    placement: Placement
    source: str = "<dict>"

    def layer(self, name: str) -> Layer:
        for layer in self.layers:
            if layer.name == name:
                return layer
        raise KeyError(f"patch {self.name!r} has no layer {name!r}; layers: {self.layer_names}")

    @property
    def layer_names(self) -> tuple[str, ...]:
        return tuple(layer.name for layer in self.layers)

    @cached_property
    def content_hash(self) -> str:
        """sha256 hex digest of the normalised content (not the file text or its path)."""
        content = {
            "name": self.name,
            "frame_id": self.frame_id,
            "layers": [layer.content_hash for layer in self.layers],
            "placement": _canonical(self.placement),
        }
        return _hash(content)


def _canonical(obj: Any) -> Any:
    """JSON-able canonical form: floats as exact ``repr`` strings, arrays as nested lists."""
    if is_dataclass(obj):
        out = {"__type__": type(obj).__name__}
        for f in fields(obj):
            out[f.name] = _canonical(getattr(obj, f.name))
        return out
    if isinstance(obj, np.ndarray):
        return {"shape": list(obj.shape), "values": [repr(float(v)) for v in obj.ravel()]}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, (bool, str)) or obj is None:
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return repr(float(obj))
    raise TypeError(f"cannot hash {type(obj).__name__}")


def _hash(content: Any) -> str:
    text = json.dumps(content, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# --------------------------------------------------------------------------- reading


_MISSING = object()


class _Reader:
    """Typed access to nested YAML data that reports errors with the key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, path: str, reason: str) -> PatchError:
        return PatchError(self.source, path, reason)

    @staticmethod
    def join(path: str, key: str | int) -> str:
        if isinstance(key, int):
            return f"{path}[{key}]"
        return f"{path}.{key}" if path else key

    def mapping(
        self, value: Any, path: str, required: tuple[str, ...] = (), optional: tuple[str, ...] = ()
    ) -> Mapping:
        if not isinstance(value, Mapping):
            raise self.error(path, f"expected a mapping, got {_kind(value)}")
        for key in value:
            if not isinstance(key, str):
                raise self.error(path, f"keys must be strings, got {key!r}")
        for key in required:
            if key not in value:
                raise self.error(self.join(path, key), "missing required key")
        allowed = set(required) | set(optional)
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise self.error(
                self.join(path, unknown[0]), f"unknown key; allowed: {', '.join(sorted(allowed))}"
            )
        return value

    def sequence(self, value: Any, path: str, min_len: int = 0) -> list:
        if not isinstance(value, (list, tuple)):
            raise self.error(path, f"expected a list, got {_kind(value)}")
        if len(value) < min_len:
            raise self.error(path, f"expected at least {min_len} entries, got {len(value)}")
        return list(value)

    def number(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        minimum: float | None = None,
        positive: bool = False,
        allow_none: bool = False,
    ) -> Any:
        where = self.join(path, key)
        if key not in data:
            if default is _MISSING:
                raise self.error(where, "missing required key")
            return default
        value = data[key]
        if value is None and allow_none:
            return None
        number = self.as_float(value, where)
        if positive and not number > 0:
            raise self.error(where, f"must be > 0, got {number:g}")
        if minimum is not None and number < minimum:
            raise self.error(where, f"must be >= {minimum:g}, got {number:g}")
        return number

    def as_float(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(where, f"expected a number, got {_kind(value)}")
        if not math.isfinite(value):
            raise self.error(where, f"expected a finite number, got {value}")
        return float(value)

    def integer(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        minimum: int | None = None,
    ) -> int:
        where = self.join(path, key)
        if key not in data:
            if default is _MISSING:
                raise self.error(where, "missing required key")
            return default
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(where, f"expected an integer, got {_kind(value)}")
        if minimum is not None and value < minimum:
            raise self.error(where, f"must be >= {minimum}, got {value}")
        return int(value)

    def string(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        choices: tuple[str, ...] | None = None,
    ) -> str:
        where = self.join(path, key)
        if key not in data:
            if default is _MISSING:
                raise self.error(where, "missing required key")
            return default
        value = data[key]
        if not isinstance(value, str) or not value:
            raise self.error(where, f"expected a non-empty string, got {_kind(value)}")
        if choices is not None and value not in choices:
            raise self.error(
                where, f"unknown value {value!r}; expected one of {', '.join(choices)}"
            )
        return value

    def vector(self, value: Any, where: str, size: int) -> np.ndarray:
        items = self.sequence(value, where)
        if len(items) != size:
            raise self.error(where, f"expected {size} numbers, got {len(items)}")
        return np.array([self.as_float(v, self.join(where, i)) for i, v in enumerate(items)])

    def points(self, value: Any, where: str, min_len: int) -> np.ndarray:
        items = self.sequence(value, where, min_len=min_len)
        return np.array([self.vector(p, self.join(where, i), 2) for i, p in enumerate(items)])


def _kind(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    for t, name in names.items():
        if type(value) is t:
            return f"{name} ({value!r})"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    return type(value).__name__


class _Loader(yaml.SafeLoader):
    """Safe YAML loader that also reads ``1e-3`` / ``3.0e4`` as floats (YAML 1.2 style)."""


_Loader.yaml_implicit_resolvers = {
    key: list(value) for key, value in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def load_patch(path: str | Path) -> Patch:
    """Read and validate a patch YAML file."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise PatchError(source, "(file)", exc.strerror or str(exc)) from None
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "(yaml)"
        problem = getattr(exc, "problem", None) or str(exc)
        raise PatchError(source, where, f"invalid YAML: {problem}") from None
    return patch_from_dict(data, source=source)


def patch_from_dict(data: Any, source: str = "<dict>") -> Patch:
    """Validate already-parsed patch data (same schema as the YAML file)."""
    r = _Reader(source)
    top = r.mapping(data, "", required=("name", "frame_id", "layers"), optional=("placement",))
    name = r.string(top, "name", "")
    frame_id = r.string(top, "frame_id", "")
    items = r.sequence(top["layers"], "layers", min_len=1)
    layers = []
    for i, item in enumerate(items):
        layer = _layer(r, item, f"layers[{i}]")
        if any(existing.name == layer.name for existing in layers):
            raise r.error(f"layers[{i}].name", f"duplicate layer name {layer.name!r}")
        layers.append(layer)
    placement = _placement(r, top.get("placement", {"type": "plane"}), "placement", layers)
    return Patch(name, frame_id, tuple(layers), placement, source)


def _layer(r: _Reader, data: Any, path: str) -> Layer:
    d = r.mapping(
        data,
        path,
        required=("name", "outline", "electrodes", "material"),
        optional=("holes", "current", "protocol", "mesh", "solver"),
    )
    name = r.string(d, "name", path)
    kind, outline = _outline(r, d["outline"], r.join(path, "outline"))
    electrodes, contact = _electrodes(r, d["electrodes"], r.join(path, "electrodes"), kind, outline)
    holes = _holes(r, d.get("holes", []), r.join(path, "holes"), outline, electrodes)
    current = r.number(d, "current", path, default=1e-3, positive=True)
    material = _material(r, d["material"], r.join(path, "material"))
    protocol = _protocol(r, d.get("protocol", {}), r.join(path, "protocol"), len(electrodes))
    mesh = _mesh_spec(r, d.get("mesh", {}), r.join(path, "mesh"), outline, electrodes)
    solver = _solver_spec(r, d.get("solver", {}), r.join(path, "solver"))
    for array in (outline, *holes):
        array.setflags(write=False)
    return Layer(
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
    )


def _outline(r: _Reader, data: Any, path: str) -> tuple[str, np.ndarray]:
    d = r.mapping(
        data,
        path,
        required=("type",),
        optional=("radius", "center", "segments", "width", "height", "points"),
    )
    kind = r.string(d, "type", path, choices=("circle", "rectangle", "polygon"))
    return kind, _shape(r, d, path, kind, OUTLINE_CIRCLE_SEGMENTS, "outline")


def _shape(r: _Reader, d: Mapping, path: str, kind: str, segments: int, what: str) -> np.ndarray:
    """CCW polygon of a circle / rectangle / polygon shape mapping."""
    allowed = {
        "circle": ("type", "radius", "center", "segments"),
        "rectangle": ("type", "width", "height", "center"),
        "polygon": ("type", "points"),
    }[kind]
    extra = sorted(set(d) - set(allowed))
    if extra:
        raise r.error(r.join(path, extra[0]), f"not a key of a {kind} {what}")
    center = r.vector(d.get("center", [0.0, 0.0]), r.join(path, "center"), 2)
    if kind == "circle":
        radius = r.number(d, "radius", path, positive=True)
        n = r.integer(d, "segments", path, default=segments, minimum=8)
        return geometry.circle_polygon(center, radius, n)
    if kind == "rectangle":
        width = r.number(d, "width", path, positive=True)
        height = r.number(d, "height", path, positive=True)
        return geometry.rectangle_polygon(center, width, height)
    where = r.join(path, "points")
    points = r.points(d.get("points"), where, min_len=3) if "points" in d else None
    if points is None:
        raise r.error(where, "missing required key")
    if geometry.self_intersects(points):
        raise r.error(where, f"{what} polygon intersects itself (or repeats a point)")
    if geometry.signed_area(points) < 0:
        points = np.concatenate([points[:1], points[:0:-1]])  # CCW, same start point
    return points


def _electrodes(
    r: _Reader, data: Any, path: str, outline_kind: str, outline: np.ndarray
) -> tuple[tuple[Electrode, ...], float]:
    d = r.mapping(
        data,
        path,
        required=("width", "contact_impedance"),
        optional=("count", "layout", "start_angle_deg", "start_fraction", "positions", "tolerance"),
    )
    perimeter = float(geometry.arc_positions(outline)[-1])
    width = r.number(d, "width", path, positive=True)
    contact = r.number(d, "contact_impedance", path, positive=True)
    default_layout = "explicit" if "positions" in d else "even"
    layout = r.string(d, "layout", path, default=default_layout, choices=("even", "explicit"))
    if layout == "even":
        if "positions" in d:
            raise r.error(r.join(path, "positions"), "not used with layout: even")
        count = r.integer(d, "count", path)
        if "start_angle_deg" in d and "start_fraction" in d:
            raise r.error(r.join(path, "start_angle_deg"), "give start_angle_deg or start_fraction")
        if "start_angle_deg" in d:
            if outline_kind != "circle":
                raise r.error(r.join(path, "start_angle_deg"), "only for circle outlines")
            start = r.number(d, "start_angle_deg", path) / 360.0
        else:
            start = r.number(d, "start_fraction", path, default=0.0)
        if count < MIN_ELECTRODES:
            raise r.error(
                r.join(path, "count"), f"need at least {MIN_ELECTRODES} electrodes, got {count}"
            )
        centers = np.mod(start + np.arange(count) / count, 1.0) * perimeter
        where = [r.join(path, "count")] * count
    else:
        for key in ("start_angle_deg", "start_fraction"):
            if key in d:
                raise r.error(r.join(path, key), "only used with layout: even")
        ppath = r.join(path, "positions")
        if "positions" not in d:
            raise r.error(ppath, "missing required key")
        items = r.sequence(d["positions"], ppath)
        tolerance = r.number(d, "tolerance", path, default=5e-4, positive=True)
        if len(items) < MIN_ELECTRODES:
            raise r.error(ppath, f"need at least {MIN_ELECTRODES} electrodes, got {len(items)}")
        if "count" in d and r.integer(d, "count", path) != len(items):
            raise r.error(r.join(path, "count"), f"does not match the {len(items)} positions")
        where = [r.join(ppath, i) for i in range(len(items))]
        centers = np.empty(len(items))
        for i, item in enumerate(items):
            if isinstance(item, (list, tuple)):
                point = r.vector(item, where[i], 2)
                s, dist = geometry.project_onto_polygon(point[None], outline)
                if dist[0] > tolerance:
                    raise r.error(
                        where[i],
                        f"point is {dist[0] * 1e3:.3g} mm off the outline "
                        f"(tolerance {tolerance * 1e3:g} mm)",
                    )
                centers[i] = s[0]
            else:
                fraction = r.as_float(item, where[i])
                if not 0.0 <= fraction < 1.0:
                    raise r.error(
                        where[i],
                        f"arc-length fraction {fraction:g} is off the outline (must be in [0, 1))",
                    )
                centers[i] = fraction * perimeter
    n = len(centers)
    gaps = np.mod(np.roll(centers, -1) - centers, perimeter)  # centre k -> centre k+1
    if n and (np.any(gaps <= 0) or abs(gaps.sum() - perimeter) > 1e-9 * perimeter):
        raise r.error(
            where[0] if layout == "even" else r.join(path, "positions"),
            "electrode positions must be distinct and listed counter-clockwise",
        )
    clearance = gaps - width
    if np.any(clearance <= 0):
        k = int(np.argmin(clearance))
        raise r.error(
            r.join(path, "width") if layout == "even" else where[(k + 1) % n],
            f"electrodes {k} and {(k + 1) % n} overlap: their centres are "
            f"{gaps[k] * 1e3:.4g} mm apart along the outline, width is {width * 1e3:.4g} mm",
        )
    points = geometry.point_at_arc(outline, centers)
    electrodes = []
    for k in range(n):
        center = points[k].copy()
        center.setflags(write=False)
        electrodes.append(
            Electrode(
                start_m=float(np.mod(centers[k] - 0.5 * width, perimeter)),
                end_m=float(np.mod(centers[k] + 0.5 * width, perimeter)),
                width_m=width,
                center=center,
                center_m=float(centers[k]),
            )
        )
    return tuple(electrodes), contact


def electrode_points(
    layer_outline: np.ndarray, electrodes: tuple[Electrode, ...], samples: int = 17
) -> np.ndarray:
    """``[n_electrodes * samples, 2]`` points along every electrode (m), for distance checks."""
    if not electrodes:
        return np.zeros((0, 2))
    t = np.linspace(0.0, 1.0, samples)
    s = np.concatenate([e.center_m + (t - 0.5) * e.width_m for e in electrodes])
    return geometry.point_at_arc(layer_outline, s)


def _holes(
    r: _Reader, data: Any, path: str, outline: np.ndarray, electrodes: tuple[Electrode, ...]
) -> tuple[np.ndarray, ...]:
    items = r.sequence(data, path)
    explicit: list[tuple[np.ndarray, str]] = []
    grids: list[tuple[Mapping, str]] = []
    for i, item in enumerate(items):
        where = r.join(path, i)
        d = r.mapping(
            item,
            where,
            required=("type",),
            optional=(
                "radius",
                "center",
                "segments",
                "points",
                "diameter",
                "pitch",
                "pattern",
                "offset",
                "margin",
                "electrode_margin",
            ),
        )
        kind = r.string(d, "type", where, choices=("circle", "polygon", "grid"))
        if kind == "grid":
            grids.append((d, where))
            continue
        hole = _shape(r, d, where, kind, HOLE_CIRCLE_SEGMENTS, "hole")
        inside = geometry.points_in_polygon(hole, outline)
        if not np.all(inside) or geometry.polygons_intersect(hole, outline):
            raise r.error(where, "hole is not strictly inside the sheet outline")
        for other, other_where in explicit:
            if (
                geometry.polygons_intersect(hole, other)
                or geometry.points_in_polygon(hole[:1], other)[0]
                or geometry.points_in_polygon(other[:1], hole)[0]
            ):
                raise r.error(where, f"hole overlaps {other_where}")
        explicit.append((hole, where))
    holes = [h for h, _ in explicit]
    for d, where in grids:
        holes.extend(_grid_holes(r, d, where, outline, electrodes, [h for h, _ in explicit]))
    return tuple(h[::-1].copy() for h in holes)  # clockwise


def _grid_holes(
    r: _Reader,
    d: Mapping,
    path: str,
    outline: np.ndarray,
    electrodes: tuple[Electrode, ...],
    obstacles: list[np.ndarray],
) -> list[np.ndarray]:
    """Circular holes on a lattice, keeping a margin from outline, electrodes and other holes."""
    extra = sorted(
        set(d)
        - {
            "type",
            "diameter",
            "pitch",
            "pattern",
            "offset",
            "margin",
            "electrode_margin",
            "segments",
        }
    )
    if extra:
        raise r.error(r.join(path, extra[0]), "not a key of a grid of holes")
    diameter = r.number(d, "diameter", path, positive=True)
    pitch = r.number(d, "pitch", path, positive=True)
    if pitch <= diameter:
        raise r.error(
            r.join(path, "pitch"),
            f"pitch {pitch:g} m must exceed the hole diameter {diameter:g} m (holes would overlap)",
        )
    pattern = r.string(d, "pattern", path, default="square", choices=("square", "hex"))
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    offset = r.vector(d["offset"], r.join(path, "offset"), 2) if "offset" in d else 0.5 * (lo + hi)
    margin = r.number(d, "margin", path, default=pitch - diameter, minimum=0.0)
    electrode_margin = r.number(
        d, "electrode_margin", path, default=2.0 * (pitch - diameter), minimum=0.0
    )
    segments = r.integer(d, "segments", path, default=HOLE_CIRCLE_SEGMENTS, minimum=6)
    radius = 0.5 * diameter
    centres = geometry.grid_hole_centres(lo, hi, pitch, offset, pattern)
    keep = geometry.points_in_polygon(centres, outline)
    centres = centres[keep]
    a0, a1 = outline, np.roll(outline, -1, axis=0)
    keep = geometry.distance_to_segments(centres, a0, a1) >= radius + margin
    pts = electrode_points(outline, electrodes)
    if len(pts):
        dist_el = np.min(np.linalg.norm(centres[:, None, :] - pts[None], axis=-1), axis=1)
        keep &= dist_el >= radius + electrode_margin
    for hole in obstacles:
        h0, h1 = hole, np.roll(hole, -1, axis=0)
        near = geometry.distance_to_segments(centres, h0, h1) < radius + margin
        keep &= ~near & ~geometry.points_in_polygon(centres, hole)
    centres = centres[keep]
    if len(centres) == 0:
        raise r.error(path, "no hole of the grid fits inside the sheet with the given margins")
    return [geometry.circle_polygon(c, radius, segments) for c in centres]


def _material(r: _Reader, data: Any, path: str) -> Material:
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
        return Material(quantity, conductance, pressure_scale_pa=scale)
    if "pressure_scale" in d:
        raise r.error(r.join(path, "pressure_scale"), "only for quantity: pressure")
    gain = r.number(d, "gauge_factor", path, positive=True)
    return Material(quantity, conductance, gauge_factor=gain)


_PROTOCOL_KEYS = tuple(f.name for f in fields(ProtocolSpec))


def _protocol(r: _Reader, data: Any, path: str, n_electrodes: int) -> ProtocolSpec:
    d = r.mapping(data, path, optional=_PROTOCOL_KEYS)
    kwargs = {}
    for key, value in d.items():
        if key in ("injections", "measurements") and value is not None:
            value = tuple(
                tuple(row) if isinstance(row, (list, tuple)) else row
                for row in r.sequence(value, r.join(path, key))
            )
        kwargs[key] = value
    try:
        spec = ProtocolSpec(**kwargs)
        spec.validate(n_electrodes)
        build_protocol(spec, n_electrodes)
    except ValueError as exc:
        raise _protocol_error(r, path, str(exc)) from None
    return spec


def _protocol_error(r: _Reader, path: str, message: str) -> PatchError:
    """Turn ``"key[3]: reason"`` from ProtocolSpec into a key path under ``path``."""
    head, sep, reason = message.partition(": ")
    key = head.split("[", 1)[0]
    if sep and key in _PROTOCOL_KEYS:
        return r.error(f"{path}.{head}", reason)
    return r.error(path, message)


def _mesh_spec(
    r: _Reader, data: Any, path: str, outline: np.ndarray, electrodes: tuple[Electrode, ...]
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


def _method_and_prior(r: _Reader, d: Mapping, path: str, defaults: SolverSpec) -> tuple[str, str]:
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


def _solver_spec(r: _Reader, data: Any, path: str) -> SolverSpec:
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
            d, "noise_figure", path, default=defaults.noise_figure, positive=True
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
    }
    return SolverSpec(**kwargs)


def _placement(r: _Reader, data: Any, path: str, layers: list[Layer]) -> Placement:
    d = r.mapping(
        data,
        path,
        required=("type",),
        optional=("origin", "rpy", "radius", "axis", "reference", "heights", "bounds"),
    )
    kind = r.string(d, "type", path, choices=PLACEMENT_TYPES)
    allowed = {
        "plane": ("type", "origin", "rpy"),
        "cylinder": ("type", "radius", "axis", "origin", "reference"),
        "heightmap": ("type", "heights", "bounds", "origin", "rpy"),
    }[kind]
    extra = sorted(set(d) - set(allowed))
    if extra:
        raise r.error(r.join(path, extra[0]), f"not a key of a {kind} placement")
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
