"""Where a flat sheet sits on the robot, for visualisation.

A placement maps sheet coordinates ``(x, y)`` (metres, patch frame of the flat
sheet) to 3-D points (metres) in the patch's ROS frame (``frame_id``):

* :class:`PlanePlacement`: a rigid transform (origin, roll-pitch-yaw).
* :class:`CylinderPlacement`: the sheet wrapped without stretch around a
  cylinder; sheet ``x`` runs around the circumference (counter-clockwise about
  ``axis``), sheet ``y`` along ``axis``, the sheet normal points outwards.
* :class:`HeightmapPlacement`: ``z`` from a bilinear height grid over the
  sheet's bounding box (the face), then a rigid transform.
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

    def height(self, points_xy: np.ndarray) -> np.ndarray:
        """``[n]`` bilinear height (m) at sheet points ``[n, 2]``."""
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        rows, cols = self.heights.shape
        x_min, x_max, y_min, y_max = self.bounds
        u = np.clip((pts[:, 0] - x_min) / (x_max - x_min) * (cols - 1), 0, cols - 1)
        v = np.clip((pts[:, 1] - y_min) / (y_max - y_min) * (rows - 1), 0, rows - 1)
        j = np.minimum(np.floor(u).astype(int), cols - 2)
        i = np.minimum(np.floor(v).astype(int), rows - 2)
        fu, fv = u - j, v - i
        h = self.heights
        return (
            h[i, j] * (1 - fu) * (1 - fv)
            + h[i, j + 1] * fu * (1 - fv)
            + h[i + 1, j] * (1 - fu) * fv
            + h[i + 1, j + 1] * fu * fv
        )

    def to_3d(self, points_xy: np.ndarray) -> np.ndarray:
        pts = np.asarray(points_xy, float).reshape(-1, 2)
        local = np.column_stack([pts, self.height(pts)])
        return self.origin + local @ rotation_from_rpy(self.rpy).T

    def describe(self) -> str:
        rows, cols = self.heights.shape
        return f"heightmap {rows}x{cols}, z {self.heights.min():g}..{self.heights.max():g} m"
