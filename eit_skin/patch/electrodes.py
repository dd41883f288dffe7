"""Reading electrodes from patch files: even or explicit layouts along the outline.

Electrodes are numbered counter-clockwise in the order of their centres; positions are
arc lengths (m) measured counter-clockwise from the outline's first vertex. Refused: fewer
than :data:`MIN_ELECTRODES`, positions off the outline, not distinct or not listed
counter-clockwise, and neighbours (the last and the first included) that overlap.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.model import Electrode
from eit_skin.patch.yaml_reader import Reader

MIN_ELECTRODES = 4

ELECTRODE_KEYS = (
    "width",
    "contact_impedance",
    "count",
    "layout",
    "start_angle_deg",
    "start_fraction",
    "positions",
    "tolerance",
)
"""Keys of a layer's ``electrodes`` mapping (the first two are required)."""


def _contact_impedance(r: Reader, d: dict, path: str) -> float | tuple[float, ...]:
    """One contact impedance (ohm*m) or one per electrode (a list, config numbering)."""
    value = d["contact_impedance"]
    if not isinstance(value, (list, tuple)):
        return r.number(d, "contact_impedance", path, positive=True)
    key = r.join(path, "contact_impedance")
    values = []
    for i, item in enumerate(r.sequence(value, key, min_len=1)):
        number = r.as_float(item, r.join(key, i))
        if not number > 0:
            raise r.error(r.join(key, i), f"must be > 0 ohm*m, got {number:g}")
        values.append(number)
    return tuple(values)


def read_electrodes(
    r: Reader, data: Any, path: str, outline_kind: str, outline: np.ndarray
) -> tuple[tuple[Electrode, ...], float]:
    """``(electrodes in CCW order, contact impedance ohm*m)`` of an ``electrodes`` mapping.

    The contact impedance is a float, or a tuple of one per electrode (config numbering).

    Args:
        r: reader of the patch file.
        data: the parsed ``electrodes`` mapping.
        path: its key path.
        outline_kind: the outline's ``type`` (``start_angle_deg`` needs a circle).
        outline: ``[n, 2]`` CCW outline polygon, m.
    """
    d = r.mapping(data, path, required=ELECTRODE_KEYS[:2], optional=ELECTRODE_KEYS[2:])
    perimeter = float(geometry.arc_positions(outline)[-1])
    width = r.number(d, "width", path, positive=True)
    contact = _contact_impedance(r, d, path)
    default_layout = "explicit" if "positions" in d else "even"
    layout = r.string(d, "layout", path, default=default_layout, choices=("even", "explicit"))
    if layout == "even":
        centers, where = _even_centres(r, d, path, outline_kind, perimeter)
    else:
        centers, where = _explicit_centres(r, d, path, outline)
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
    electrodes = _electrodes(outline, centers, width, perimeter)
    if isinstance(contact, tuple) and len(contact) != len(electrodes):
        raise r.error(
            r.join(path, "contact_impedance"),
            f"{len(contact)} values for {len(electrodes)} electrodes (one per electrode, "
            "in config numbering, or a single number)",
        )
    return tuple(electrodes), contact


def _even_centres(
    r: Reader, d: dict, path: str, outline_kind: str, perimeter: float
) -> tuple[np.ndarray, list[str]]:
    """``layout: even``: ``(centres [count] arc length m, key path of each)``."""
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
    return centers, [r.join(path, "count")] * count


def _explicit_centres(
    r: Reader, d: dict, path: str, outline: np.ndarray
) -> tuple[np.ndarray, list[str]]:
    """``layout: explicit``: ``(centres [n] arc length m, key path of each position)``."""
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
    perimeter = float(geometry.arc_positions(outline)[-1])
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
    return centers, where


def _electrodes(
    outline: np.ndarray, centers: np.ndarray, width: float, perimeter: float
) -> list[Electrode]:
    """Electrodes of ``width`` m centred at arc lengths ``centers`` ``[n]`` m on ``outline``."""
    points = geometry.point_at_arc(outline, centers)
    electrodes = []
    for k in range(len(centers)):
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
    return electrodes


def electrode_points(
    layer_outline: np.ndarray, electrodes: tuple[Electrode, ...], samples: int = 17
) -> np.ndarray:
    """``[n_electrodes * samples, 2]`` points along every electrode (m), for distance checks."""
    if not electrodes:
        return np.zeros((0, 2))
    t = np.linspace(0.0, 1.0, samples)
    s = np.concatenate([e.center_m + (t - 0.5) * e.width_m for e in electrodes])
    return geometry.point_at_arc(layer_outline, s)
