"""Reading holes from patch files: circles, polygons and lattices of circular holes.

Holes are returned clockwise (the sheet lies left of every boundary loop). An explicit hole
must lie strictly inside the outline and overlap no other; a ``grid`` keeps only the lattice
holes that stay clear of the outline, the electrodes and the explicit holes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.electrodes import electrode_points
from eit_skin.patch.model import Electrode
from eit_skin.patch.outline import CIRCLE_SEGMENTS, SHAPE_KEYS, read_shape
from eit_skin.patch.yaml_reader import Reader

HOLE_KEYS = {
    "circle": SHAPE_KEYS["circle"],
    "polygon": SHAPE_KEYS["polygon"],
    "grid": ("diameter", "pitch", "pattern", "offset", "margin", "electrode_margin", "segments"),
}
"""Keys of each hole ``type`` (besides ``type``)."""


def read_holes(
    r: Reader, data: Any, path: str, outline: np.ndarray, electrodes: tuple[Electrode, ...]
) -> tuple[np.ndarray, ...]:
    """Clockwise ``[k_i, 2]`` hole polygons (m) of a layer's ``holes`` list.

    Args:
        r: reader of the patch file.
        data: the parsed ``holes`` list.
        path: its key path.
        outline: ``[n, 2]`` CCW outline polygon, m.
        electrodes: the layer's electrodes (grids keep a margin from them).
    """
    items = r.sequence(data, path)
    explicit: list[tuple[np.ndarray, str]] = []
    grids: list[tuple[Mapping, str]] = []
    for i, item in enumerate(items):
        where = r.join(path, i)
        kind, d = r.variant(item, where, HOLE_KEYS, "hole")
        if kind == "grid":
            grids.append((d, where))
            continue
        hole = read_shape(r, d, where, kind, "hole")
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
    r: Reader,
    d: Mapping,
    path: str,
    outline: np.ndarray,
    electrodes: tuple[Electrode, ...],
    obstacles: list[np.ndarray],
) -> list[np.ndarray]:
    """Circular holes on a lattice, keeping a margin from outline, electrodes and other holes."""
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
    segments = r.integer(d, "segments", path, default=CIRCLE_SEGMENTS["hole"], minimum=6)
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
