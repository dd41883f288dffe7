"""Triangular meshes of skin sheets.

A :class:`Mesh` is the geometry the forward model and the image grid work on:
linear triangles in the patch frame (metres), plus, for every electrode, the
boundary edges it covers (complete electrode model).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from eit_skin.patch import geometry

if TYPE_CHECKING:
    from eit_skin.patch.model import Layer


@dataclass(frozen=True, eq=False)
class Mesh:
    """A 2-D triangle mesh of one sheet.

    Attributes:
        nodes: ``[n_nodes, 2]`` float64 node coordinates, metres, patch frame.
        triangles: ``[n_triangles, 3]`` int64 node indices, counter-clockwise.
        electrode_edges: one ``[k_i, 2]`` int64 array per electrode: the boundary
            edges (node index pairs) under electrode ``i``, electrodes numbered
            counter-clockwise as in the patch config.
    """

    nodes: np.ndarray
    triangles: np.ndarray
    electrode_edges: tuple[np.ndarray, ...]

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def n_electrodes(self) -> int:
        return len(self.electrode_edges)

    @property
    def areas(self) -> np.ndarray:
        """``[n_triangles]`` triangle areas, m^2 (positive for CCW triangles)."""
        p = self.nodes[self.triangles]
        d1 = p[:, 1] - p[:, 0]
        d2 = p[:, 2] - p[:, 0]
        return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])

    @property
    def centroids(self) -> np.ndarray:
        """``[n_triangles, 2]`` triangle centroids, metres."""
        return self.nodes[self.triangles].mean(axis=1)

    @property
    def electrode_lengths(self) -> np.ndarray:
        """``[n_electrodes]`` total length (m) of the boundary edges under each electrode."""
        return np.array(
            [
                float(np.linalg.norm(np.diff(self.nodes[e], axis=1)[:, 0], axis=1).sum())
                for e in self.electrode_edges
            ]
        )

    @property
    def min_angles_deg(self) -> np.ndarray:
        """``[n_triangles]`` smallest interior angle of each triangle, degrees."""
        p = self.nodes[self.triangles]
        a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
        b = np.linalg.norm(p[:, 2] - p[:, 0], axis=1)
        c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
        # smallest angle is opposite the shortest side (law of cosines)
        s = np.sort(np.column_stack([a, b, c]), axis=1)
        cos = (s[:, 1] ** 2 + s[:, 2] ** 2 - s[:, 0] ** 2) / (2 * s[:, 1] * s[:, 2])
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    @property
    def boundary_edges(self) -> np.ndarray:
        """``[b, 2]`` int64 boundary edges (outline and holes), sheet on the left of each."""
        t = self.triangles
        directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        n = self.n_nodes
        forward = directed[:, 0] * n + directed[:, 1]
        backward = directed[:, 1] * n + directed[:, 0]
        return directed[~np.isin(forward, backward)]


def build_mesh(layer: Layer, max_edge_m: float | None = None) -> Mesh:
    """Constrained Delaunay mesh of one layer (Shewchuk's Triangle, quality-bounded).

    The outline is split at every electrode end so that each electrode covers whole
    boundary edges whose lengths add up to its width.  Boundary edges are
    ``layer.mesh.electrode_edge_m`` long on the electrodes and grow linearly
    (slope 1/2) to ``max_edge_m`` away from them; triangles have at most the area of
    an equilateral triangle with edge ``max_edge_m`` and no angle below
    ``layer.mesh.min_angle_deg``.  Holes are left empty.  The result depends only
    on the layer (bit-identical for the same input).

    Args:
        layer: the sheet.
        max_edge_m: global edge length, m; ``None`` uses ``layer.mesh.max_edge_m``
            (the electrode edge length is capped at this value).
    """
    import triangle

    spec = layer.mesh
    h_max = float(spec.max_edge_m if max_edge_m is None else max_edge_m)
    if not h_max > 0:
        raise ValueError(f"max_edge_m must be > 0, got {h_max}")
    h_el = min(spec.electrode_edge_m, h_max)

    outline_pts, markers = _outline_vertices(layer, h_el, h_max)
    loops = [outline_pts]
    loop_markers = [markers]
    hole_points = []
    for hole in layer.holes:
        pts = _subdivide_loop(hole, h_max)
        loops.append(pts)
        loop_markers.append(np.ones(len(pts), dtype=np.int32))
        hole_points.append(geometry.polygon_interior_point(hole))

    vertices = np.concatenate(loops)
    segments = []
    offset = 0
    for pts in loops:
        idx = offset + np.arange(len(pts))
        segments.append(np.column_stack([idx, np.roll(idx, -1)]))
        offset += len(pts)
    data = {
        "vertices": vertices,
        "segments": np.concatenate(segments).astype(np.int32),
        "segment_markers": np.concatenate(loop_markers).astype(np.int32)[:, None],
    }
    if hole_points:
        data["holes"] = np.array(hole_points)
    max_area = np.sqrt(3.0) / 4.0 * h_max * h_max
    digits = max(12, 12 - int(np.floor(np.log10(max_area))))
    opts = f"pq{spec.min_angle_deg:.6f}a{max_area:.{digits}f}Q"
    out = triangle.triangulate(data, opts)

    nodes = np.ascontiguousarray(out["vertices"], dtype=np.float64)
    tris = np.ascontiguousarray(out["triangles"], dtype=np.int64)
    p = nodes[tris]
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
        p[:, 2, 0] - p[:, 0, 0]
    )
    flip = area2 < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    seg = np.asarray(out["segments"], dtype=np.int64)
    seg_marker = np.asarray(out["segment_markers"]).ravel()
    electrode_edges = tuple(
        _ordered_electrode_edges(seg[seg_marker == k + 2], nodes, layer, k)
        for k in range(layer.n_electrodes)
    )
    for array in (nodes, tris, *electrode_edges):
        array.setflags(write=False)
    return Mesh(nodes=nodes, triangles=tris, electrode_edges=electrode_edges)


def _electrode_intervals(layer: Layer) -> np.ndarray:
    """``[n_el, 2]`` arc-length intervals ``[start, start + width]`` (m), start in [0, P)."""
    return np.array([[e.start_m, e.start_m + e.width_m] for e in layer.electrodes])


def _arc_distance_to_electrodes(s: np.ndarray, intervals: np.ndarray, perimeter: float):
    """``[n]`` distance along the outline (m) from positions ``s`` to the nearest electrode."""
    rel = np.mod(s[:, None] - intervals[None, :, 0], perimeter)  # in [0, P)
    width = intervals[None, :, 1] - intervals[None, :, 0]
    after = rel - width  # > 0: past the electrode's end
    before = perimeter - rel  # distance forward to its start
    d = np.where(rel <= width, 0.0, np.minimum(after, before))
    return d.min(axis=1)


def _outline_vertices(layer: Layer, h_el: float, h_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Outline vertices with electrode ends inserted and graded spacing, plus segment markers.

    Marker of the segment from vertex ``i`` to ``i+1``: ``k + 2`` under electrode ``k``,
    else 1.
    """
    outline = layer.outline
    cum = geometry.arc_positions(outline)
    perimeter = float(cum[-1])
    intervals = _electrode_intervals(layer)
    ends = np.mod(intervals.ravel(), perimeter)
    # Snap electrode ends that (nearly) coincide with an outline vertex onto it.
    snap_tol = 1e-9 * perimeter
    diff = np.abs(ends[:, None] - np.append(cum[:-1], perimeter)[None, :])
    near = diff.min(axis=1) <= snap_tol
    ends = np.where(near, np.append(cum[:-1], 0.0)[np.argmin(diff, axis=1)], ends)
    ends = np.mod(ends, perimeter)
    breaks = np.unique(np.concatenate([cum[:-1], ends]))
    piece_start = breaks
    piece_end = np.append(breaks[1:], perimeter)

    def size(s: np.ndarray) -> np.ndarray:
        d = _arc_distance_to_electrodes(s, intervals, perimeter)
        return np.minimum(h_max, h_el + 0.5 * d)

    positions = []
    for a, b in zip(piece_start, piece_end, strict=True):
        # place points so that the local spacing follows size(s): integrate 1/size
        t = np.linspace(a, b, 65)
        density = 1.0 / size(t)
        count = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(t))])
        n = max(1, int(np.ceil(count[-1] - 1e-9)))
        levels = np.arange(n) * (count[-1] / n)
        positions.append(np.interp(levels, count, t))
        positions[-1][0] = a
    s = np.concatenate(positions)
    points = geometry.point_at_arc(outline, s)
    mid = 0.5 * (s + np.append(s[1:], perimeter))
    rel = np.mod(mid[:, None] - intervals[None, :, 0], perimeter)
    under = rel < (intervals[:, 1] - intervals[:, 0])[None, :]
    markers = np.where(under.any(axis=1), np.argmax(under, axis=1) + 2, 1).astype(np.int32)
    return points, markers


def _subdivide_loop(loop: np.ndarray, h: float) -> np.ndarray:
    """Closed polygon with every edge split into equal parts no longer than ``h`` (m)."""
    nxt = np.roll(loop, -1, axis=0)
    length = np.linalg.norm(nxt - loop, axis=1)
    n = np.maximum(1, np.ceil(length / h - 1e-9).astype(int))
    edge = np.repeat(np.arange(len(loop)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    return loop[edge] + t[:, None] * (nxt[edge] - loop[edge])


def _ordered_electrode_edges(
    edges: np.ndarray, nodes: np.ndarray, layer: Layer, k: int
) -> np.ndarray:
    """Electrode ``k``'s boundary edges oriented and ordered counter-clockwise along the outline.

    The outline is counter-clockwise, so an edge has the sheet on its left when it runs
    towards increasing arc length.
    """
    if len(edges) == 0:
        raise ValueError(f"layer {layer.name!r}: electrode {k} has no boundary edge")
    perimeter = layer.perimeter_m
    s, _ = geometry.project_onto_polygon(nodes[edges.ravel()], layer.outline)
    # position relative to the electrode centre, in [-P/2, P/2): no wrap inside the electrode
    rel = np.mod(s - layer.electrodes[k].center_m + 0.5 * perimeter, perimeter) - 0.5 * perimeter
    rel = rel.reshape(-1, 2)
    flip = rel[:, 0] > rel[:, 1]
    edges = np.where(flip[:, None], edges[:, ::-1], edges)
    order = np.argsort(rel.min(axis=1), kind="stable")
    return np.ascontiguousarray(edges[order], dtype=np.int64)
