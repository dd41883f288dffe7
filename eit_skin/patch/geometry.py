"""Plane geometry of skin sheets: polygons, arc length along an outline, holes.

Everything is in metres in the patch frame.  Polygons are ``[n, 2]`` float64
arrays of vertices without the closing repeat.  Outlines are counter-clockwise
(the sheet lies to the left when walking the boundary), holes clockwise, so
that the sheet is on the left of every boundary loop.

Arc-length positions along an outline are measured counter-clockwise from its
first vertex; the perimeter is the length of the closed polygon.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "arc_positions",
    "circle_polygon",
    "distance_to_segments",
    "grid_hole_centres",
    "point_at_arc",
    "points_in_polygon",
    "polygon_interior_point",
    "polygons_intersect",
    "project_onto_polygon",
    "rectangle_polygon",
    "self_intersects",
    "signed_area",
]


def circle_polygon(center: np.ndarray, radius: float, n_segments: int) -> np.ndarray:
    """``[n_segments, 2]`` CCW regular polygon inscribed in a circle.

    Vertex ``i`` sits at angle ``2*pi*i/n_segments`` from the +x axis, so the
    outline starts at ``center + (radius, 0)``.
    """
    angle = 2.0 * np.pi * np.arange(n_segments) / n_segments
    return np.asarray(center, float) + radius * np.column_stack([np.cos(angle), np.sin(angle)])


def rectangle_polygon(center: np.ndarray, width: float, height: float) -> np.ndarray:
    """``[4, 2]`` CCW rectangle starting at its lower-left corner (width along x)."""
    hw, hh = 0.5 * width, 0.5 * height
    corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
    return np.asarray(center, float) + corners


def signed_area(polygon: np.ndarray) -> float:
    """Signed area of a closed polygon, m^2 (positive when counter-clockwise)."""
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edges(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return polygon, np.roll(polygon, -1, axis=0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _segments_cross(
    p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray, eps: float
) -> np.ndarray:
    """``[n, m]`` True where segment ``p0[i]-p1[i]`` meets segment ``q0[j]-q1[j]``.

    Touching (within ``eps`` in the orientation tests) counts as meeting.
    """
    p0, p1 = p0[:, None, :], p1[:, None, :]
    q0, q1 = q0[None, :, :], q1[None, :, :]
    d1 = _cross(p1 - p0, q0 - p0)
    d2 = _cross(p1 - p0, q1 - p0)
    d3 = _cross(q1 - q0, p0 - q0)
    d4 = _cross(q1 - q0, p1 - q0)
    proper = (d1 * d2 < -eps) & (d3 * d4 < -eps)

    # Collinear or touching cases: an end point lies on the other segment.
    def on_segment(a0: np.ndarray, a1: np.ndarray, d: np.ndarray, pt: np.ndarray) -> np.ndarray:
        lo = np.minimum(a0, a1) - eps
        hi = np.maximum(a0, a1) + eps
        inside = np.all((pt >= lo) & (pt <= hi), axis=-1)
        return (np.abs(d) <= eps) & inside

    touch = (
        on_segment(p0, p1, d1, q0)
        | on_segment(p0, p1, d2, q1)
        | on_segment(q0, q1, d3, p0)
        | on_segment(q0, q1, d4, p1)
    )
    return proper | touch


def self_intersects(polygon: np.ndarray) -> bool:
    """True if a closed polygon's edges cross or touch other than at shared corners."""
    n = polygon.shape[0]
    if n < 3:
        return True
    a0, a1 = _edges(polygon)
    scale = float(np.max(np.ptp(polygon, axis=0))) or 1.0
    eps = 1e-12 * scale * scale
    hit = _segments_cross(a0, a1, a0, a1, eps)
    i, j = np.triu_indices(n, k=1)
    adjacent = (j == i + 1) | ((i == 0) & (j == n - 1))
    if np.any(hit[i[~adjacent], j[~adjacent]]):
        return True
    # Adjacent edges only share their corner unless they fold back onto each other.
    e = a1 - a0
    e_next = np.roll(e, -1, axis=0)
    folded = (np.abs(_cross(e, e_next)) <= eps) & (np.sum(e * e_next, axis=1) < 0)
    degenerate = np.linalg.norm(e, axis=1) <= 1e-12 * scale
    return bool(np.any(folded) or np.any(degenerate))


def polygons_intersect(a: np.ndarray, b: np.ndarray) -> bool:
    """True if the boundaries of two closed polygons cross or touch."""
    scale = float(max(np.max(np.ptp(a, axis=0)), np.max(np.ptp(b, axis=0)))) or 1.0
    a0, a1 = _edges(a)
    b0, b1 = _edges(b)
    return bool(np.any(_segments_cross(a0, a1, b0, b1, 1e-12 * scale * scale)))


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """``[n]`` bool, True for points strictly inside a closed polygon (even-odd rule)."""
    pts = np.asarray(points, float).reshape(-1, 2)
    v0, v1 = _edges(polygon)
    x, y = pts[:, 0][:, None], pts[:, 1][:, None]
    y0, y1 = v0[:, 1][None, :], v1[:, 1][None, :]
    x0, x1 = v0[:, 0][None, :], v1[:, 0][None, :]
    straddle = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    crossings = np.sum(straddle & (x < x_cross), axis=1)
    return (crossings % 2) == 1


def distance_to_segments(points: np.ndarray, seg0: np.ndarray, seg1: np.ndarray) -> np.ndarray:
    """``[n]`` shortest distance (m) from each point to a set of segments ``seg0[k]-seg1[k]``."""
    pts = np.asarray(points, float).reshape(-1, 2)[:, None, :]
    d = (seg1 - seg0)[None, :, :]
    length2 = np.sum(d * d, axis=-1)
    t = np.sum((pts - seg0[None]) * d, axis=-1) / np.where(length2 > 0, length2, 1.0)
    t = np.clip(t, 0.0, 1.0)
    nearest = seg0[None] + t[..., None] * d
    return np.min(np.linalg.norm(pts - nearest, axis=-1), axis=1)


def arc_positions(polygon: np.ndarray) -> np.ndarray:
    """``[n + 1]`` arc length (m) of each vertex from vertex 0; the last entry is the perimeter."""
    a0, a1 = _edges(polygon)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(a1 - a0, axis=1))])


def point_at_arc(polygon: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``[..., 2]`` points at arc-length positions ``s`` (m, taken modulo the perimeter)."""
    cum = arc_positions(polygon)
    s = np.mod(np.asarray(s, float), cum[-1])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, polygon.shape[0] - 1)
    a0, a1 = _edges(polygon)
    length = cum[k + 1] - cum[k]
    t = (s - cum[k]) / np.where(length > 0, length, 1.0)
    return a0[k] + t[..., None] * (a1[k] - a0[k])


def project_onto_polygon(points: np.ndarray, polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest boundary point of each point.

    Returns:
        ``(s, distance)``: ``[n]`` arc-length position (m) of the nearest point on
        the closed polygon and ``[n]`` distance to it (m).
    """
    pts = np.asarray(points, float).reshape(-1, 2)[:, None, :]
    a0, a1 = _edges(polygon)
    d = (a1 - a0)[None]
    length2 = np.sum(d * d, axis=-1)
    t = np.clip(np.sum((pts - a0[None]) * d, axis=-1) / length2, 0.0, 1.0)
    dist = np.linalg.norm(pts - (a0[None] + t[..., None] * d), axis=-1)
    k = np.argmin(dist, axis=1)
    rows = np.arange(pts.shape[0])
    cum = arc_positions(polygon)
    s = cum[k] + t[rows, k] * np.sqrt(length2[0, k])
    return np.mod(s, cum[-1]), dist[rows, k]


def polygon_interior_point(polygon: np.ndarray) -> np.ndarray:
    """``[2]`` a point strictly inside a simple polygon (used to mark holes for the mesher)."""
    centroid = polygon.mean(axis=0)
    if points_in_polygon(centroid[None], polygon)[0]:
        return centroid
    # Midpoint of the widest interior span of a horizontal line through the vertex band.
    ys = np.sort(np.unique(polygon[:, 1]))
    y = 0.5 * (ys[:-1] + ys[1:])[np.argmax(np.diff(ys))]
    a0, a1 = _edges(polygon)
    straddle = (a0[:, 1] > y) != (a1[:, 1] > y)
    xs = a0[straddle, 0] + (y - a0[straddle, 1]) * (a1[straddle, 0] - a0[straddle, 0]) / (
        a1[straddle, 1] - a0[straddle, 1]
    )
    xs = np.sort(xs)
    spans = xs[1::2] - xs[0::2]
    k = int(np.argmax(spans))
    return np.array([0.5 * (xs[2 * k] + xs[2 * k + 1]), y])


def grid_hole_centres(
    bbox_min: np.ndarray, bbox_max: np.ndarray, pitch: float, offset: np.ndarray, pattern: str
) -> np.ndarray:
    """``[n, 2]`` centres of a hole lattice covering a bounding box.

    Args:
        bbox_min: ``[2]`` lower-left corner of the box to cover, m.
        bbox_max: ``[2]`` upper-right corner, m.
        pitch: centre-to-centre spacing, m.
        offset: ``[2]`` one lattice point, m.
        pattern: ``"square"`` or ``"hex"`` (rows ``pitch*sqrt(3)/2`` apart, every other row
            shifted by half a pitch).
    """
    dy = pitch * (np.sqrt(3.0) / 2.0 if pattern == "hex" else 1.0)
    j = np.arange(
        np.floor((bbox_min[1] - offset[1]) / dy), np.ceil((bbox_max[1] - offset[1]) / dy) + 1
    )
    i = np.arange(
        np.floor((bbox_min[0] - offset[0]) / pitch) - 1,
        np.ceil((bbox_max[0] - offset[0]) / pitch) + 2,
    )
    ii, jj = np.meshgrid(i, j)
    shift = 0.5 * (np.mod(jj, 2) == 1) if pattern == "hex" else 0.0
    x = offset[0] + (ii + shift) * pitch
    y = offset[1] + jj * dy
    return np.column_stack([x.ravel(), y.ravel()])
