"""Where a flat sheet sits on the robot, for visualisation.

A placement maps sheet coordinates ``(x, y)`` (metres, patch frame of the flat
sheet) to 3-D points (metres) in the patch's ROS frame (``frame_id``):

* :class:`PlanePlacement`: a rigid transform (origin, roll-pitch-yaw).
* :class:`CylinderPlacement`: the sheet wrapped without stretch around a
  cylinder; sheet ``x`` runs around the circumference (counter-clockwise about
  ``axis``), sheet ``y`` along ``axis``, the sheet normal points outwards.
* :class:`HeightmapPlacement`: ``z`` from a bilinear height grid over the
  sheet's bounding box (the face), then a rigid transform.

:meth:`Placement.normals` gives the surface's outward unit normal there: the direction of
``dp/dx x dp/dy``, the flat sheet's ``+z`` carried along (a plane's ``R @ z``, a cylinder's
radial direction, a height map's ``(-dh/dx, -dh/dy, 1)`` rotated). A contact found at sheet
point ``(x, y)`` touches the robot at ``to_3d`` with that normal (``Contact.position`` and
``Contact.normal`` of the messages).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def rotation_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """``[3, 3]`` rotation matrix from roll, pitch, yaw (rad), ROS convention ``Rz @ Ry @ Rx``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _vector(value: np.ndarray | tuple, size: int, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be {size} finite numbers")
    v.setflags(write=False)
    return v


@dataclass(frozen=True, eq=False)
class Placement:
    """Base class: ``to_3d`` maps ``[n, 2]`` sheet points (m) to ``[n, 3]`` points (m)."""

    kind: str = field(init=False, default="")

    def to_3d(self, points_xy: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def normals(self, points_xy: np.ndarray) -> np.ndarray:
        """``[n, 3]`` outward unit normals of the placed surface at ``[n, 2]`` sheet points."""
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class PlanePlacement(Placement):
    """Flat sheet: ``p = origin + R(rpy) @ [x, y, 0]``."""

    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "plane")
        object.__setattr__(self, "origin", _vector(self.origin, 3, "origin"))
        object.__setattr__(self, "rpy", _vector(self.rpy, 3, "rpy"))

    def to_3d(self, points_xy: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        local = np.column_stack([pts, np.zeros(len(pts))])
        return self.origin + local @ rotation_from_rpy(self.rpy).T

    def normals(self, points_xy: np.ndarray) -> np.ndarray:
        n = len(np.asarray(points_xy, float).reshape(-1, 2))
        return np.tile(rotation_from_rpy(self.rpy)[:, 2], (n, 1))

    def describe(self) -> str:
        return f"plane at {self.origin.tolist()} m, rpy {self.rpy.tolist()} rad"


@dataclass(frozen=True, eq=False)
class CylinderPlacement(Placement):
    """Sheet wrapped around a cylinder.

    Attributes:
        radius: cylinder radius at the sheet, m (> 0).
        axis: ``[3]`` axis direction (normalised on construction).
        origin: ``[3]`` point on the axis where the sheet's ``y = 0`` lies, m.
        reference: ``[3]`` direction from the axis to the sheet point ``x = 0``; made
            perpendicular to ``axis``.  Default: the frame axis least aligned with ``axis``.
    """

    radius: float = 0.05
    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reference: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "cylinder")
        if not np.isfinite(self.radius) or self.radius <= 0:
            raise ValueError(f"radius must be > 0 m, got {self.radius}")
        axis = _vector(self.axis, 3, "axis").copy()
        norm = np.linalg.norm(axis)
        if norm == 0:
            raise ValueError("axis must not be zero")
        axis /= norm
        if self.reference is None:
            ref = np.eye(3)[int(np.argmin(np.abs(axis)))]
        else:
            ref = _vector(self.reference, 3, "reference").copy()
        ref = ref - np.dot(ref, axis) * axis
        if np.linalg.norm(ref) < 1e-9:
            raise ValueError("reference must not be parallel to axis")
        ref /= np.linalg.norm(ref)
        for name, value in (("axis", axis), ("reference", ref)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "origin", _vector(self.origin, 3, "origin"))

    def to_3d(self, points_xy: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        theta = pts[:, 0] / self.radius
        tangent = np.cross(self.axis, self.reference)
        radial = np.cos(theta)[:, None] * self.reference + np.sin(theta)[:, None] * tangent
        return self.origin + pts[:, 1:2] * self.axis + self.radius * radial

    def normals(self, points_xy: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        theta = pts[:, 0] / self.radius
        tangent = np.cross(self.axis, self.reference)
        return np.cos(theta)[:, None] * self.reference + np.sin(theta)[:, None] * tangent

    def describe(self) -> str:
        return f"cylinder r={self.radius:g} m, axis {np.round(self.axis, 6).tolist()}"


@dataclass(frozen=True, eq=False)
class HeightmapPlacement(Placement):
    """Sheet draped over a height grid.

    Attributes:
        heights: ``[rows, cols]`` z values, m; row ``i`` at ``y = y_min + i*dy``, column
            ``j`` at ``x = x_min + j*dx`` (at least 2 x 2).
        bounds: ``[x_min, x_max, y_min, y_max]`` covered by the grid, m (points outside
            are clamped to the edge values).
        origin, rpy: rigid transform applied after lifting, as for a plane.
    """

    heights: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    bounds: np.ndarray = field(default_factory=lambda: np.array([-1.0, 1.0, -1.0, 1.0]))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "heightmap")
        h = np.asarray(self.heights, dtype=float)
        if h.ndim != 2 or h.shape[0] < 2 or h.shape[1] < 2 or not np.all(np.isfinite(h)):
            raise ValueError("heights must be a grid of at least 2 x 2 finite numbers (m)")
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)
        b = _vector(self.bounds, 4, "bounds")
        if not (b[1] > b[0] and b[3] > b[2]):
            raise ValueError("bounds must be [x_min, x_max, y_min, y_max] with max > min")
        object.__setattr__(self, "bounds", b)
        object.__setattr__(self, "origin", _vector(self.origin, 3, "origin"))
        object.__setattr__(self, "rpy", _vector(self.rpy, 3, "rpy"))

    def _cells(self, points_xy: np.ndarray):
        """Grid cell ``(i, j)``, fractions ``(fu, fv)`` and whether inside ``(in_u, in_v)``."""
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        rows, cols = self.heights.shape
        x_min, x_max, y_min, y_max = self.bounds
        u_raw = (pts[:, 0] - x_min) / (x_max - x_min) * (cols - 1)
        v_raw = (pts[:, 1] - y_min) / (y_max - y_min) * (rows - 1)
        u, v = np.clip(u_raw, 0, cols - 1), np.clip(v_raw, 0, rows - 1)
        j = np.minimum(np.floor(u).astype(int), cols - 2)
        i = np.minimum(np.floor(v).astype(int), rows - 2)
        return i, j, u - j, v - i, u == u_raw, v == v_raw

    def height(self, points_xy: np.ndarray) -> np.ndarray:
        """``[n]`` bilinear height (m) at sheet points ``[n, 2]``."""
        i, j, fu, fv, _, _ = self._cells(points_xy)
        h = self.heights
        return (
            h[i, j] * (1 - fu) * (1 - fv)
            + h[i, j + 1] * fu * (1 - fv)
            + h[i + 1, j] * (1 - fu) * fv
            + h[i + 1, j + 1] * fu * fv
        )

    def normals(self, points_xy: np.ndarray) -> np.ndarray:
        """``[n, 3]`` outward unit normals of the bilinear surface at ``[n, 2]`` sheet points.

        Beyond the bounds, where the edge value is held, the slope across the edge is 0; on
        a cell edge, the slope of the cell above it.
        """
        i, j, fu, fv, in_u, in_v = self._cells(points_xy)
        h = self.heights
        rows, cols = h.shape
        x_min, x_max, y_min, y_max = self.bounds
        dh_du = (h[i, j + 1] - h[i, j]) * (1 - fv) + (h[i + 1, j + 1] - h[i + 1, j]) * fv
        dh_dv = (h[i + 1, j] - h[i, j]) * (1 - fu) + (h[i + 1, j + 1] - h[i, j + 1]) * fu
        dh_dx = np.where(in_u, dh_du * (cols - 1) / (x_max - x_min), 0.0)
        dh_dy = np.where(in_v, dh_dv * (rows - 1) / (y_max - y_min), 0.0)
        local = np.column_stack([-dh_dx, -dh_dy, np.ones(len(dh_dx))])
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        return local @ rotation_from_rpy(self.rpy).T

    def to_3d(self, points_xy: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        local = np.column_stack([pts, self.height(pts)])
        return self.origin + local @ rotation_from_rpy(self.rpy).T

    def describe(self) -> str:
        rows, cols = self.heights.shape
        return f"heightmap {rows}x{cols}, z {self.heights.min():g}..{self.heights.max():g} m"
