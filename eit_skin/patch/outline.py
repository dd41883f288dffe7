"""Reading plane shapes from patch files: sheet outlines and the polygons of holes.

Every shape becomes a counter-clockwise ``[n, 2]`` polygon in metres: a circle is a regular
inscribed polygon starting at angle 0, a rectangle starts at its lower-left corner, a
polygon keeps its first point (clockwise input is reversed).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.yaml_reader import Reader

CIRCLE_SEGMENTS = {"outline": 128, "hole": 16}
"""Default ``segments`` of a circle outline (within 3e-4 radius of the circle) and hole."""

SHAPE_KEYS = {
    "circle": ("radius", "center", "segments"),
    "rectangle": ("width", "height", "center"),
    "polygon": ("points",),
}
"""Keys of each shape ``type`` (besides ``type``)."""


def read_outline(r: Reader, data: Any, path: str) -> tuple[str, np.ndarray]:
    """``(type, [n, 2] CCW polygon, m)`` of a layer's ``outline`` mapping."""
    kind, d = r.variant(data, path, SHAPE_KEYS, "outline")
    return kind, read_shape(r, d, path, kind, "outline")


def read_shape(r: Reader, d: Mapping, path: str, kind: str, what: str) -> np.ndarray:
    """``[n, 2]`` CCW polygon (m) of a checked circle / rectangle / polygon mapping ``d``.

    ``what`` (a key of :data:`CIRCLE_SEGMENTS`) names the shape in errors and sets a
    circle's default polygon size.
    """
    center = r.vector(d.get("center", [0.0, 0.0]), r.join(path, "center"), 2)
    if kind == "circle":
        radius = r.number(d, "radius", path, positive=True)
        n = r.integer(d, "segments", path, default=CIRCLE_SEGMENTS[what], minimum=8)
        return geometry.circle_polygon(center, radius, n)
    if kind == "rectangle":
        width = r.number(d, "width", path, positive=True)
        height = r.number(d, "height", path, positive=True)
        return geometry.rectangle_polygon(center, width, height)
    where = r.join(path, "points")
    if "points" not in d:
        raise r.error(where, "missing required key")
    points = r.points(d["points"], where, min_len=3)
    if geometry.self_intersects(points):
        raise r.error(where, f"{what} polygon intersects itself (or repeats a point)")
    if geometry.signed_area(points) < 0:
        points = np.concatenate([points[:1], points[:0:-1]])  # CCW, same start point
    return points
