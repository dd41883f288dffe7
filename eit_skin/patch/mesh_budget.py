"""Mesh budget: refuse a mesh that would take minutes or gigabytes, before building it.

The triangle count of a layer's mesh (:func:`eit_skin.fem.mesh.build_mesh`) is estimated
from the sheet area and ``max_edge`` plus the refinement along boundary pieces finer than
``max_edge`` (electrodes at ``electrode_edge``, short outline and hole edges)::

    N ~ FILL * area / (sqrt(3)/4 h^2)
        + BOUNDARY_FILL * sum_pieces length * (1/s - 1/h)
        + GRADING_FILL * n_electrodes * ln(h / electrode_edge)

and the cost of meshing plus the first forward assembly (forward model, voltages, Jacobian
``[M, N]`` and its relative copy) from per-triangle costs measured by
``bench/studies/bench_mesh_budget.py`` (docs/patch-schema.md, *Mesh budget*)::

    peak memory ~ N * (BYTES_PER_TRIANGLE + BYTES_PER_TRIANGLE_AND_MEASUREMENT * M)
    CPU time    ~ N * (SECONDS_PER_TRIANGLE + SECONDS_PER_TRIANGLE_AND_MEASUREMENT * M)
                  * (N / TRIANGLES_REFERENCE) ** TIME_EXPONENT

A layer whose forward mesh (``max_edge``) or inverse mesh (``inverse_max_edge``) exceeds
the peak-memory or CPU-time limit is refused by the patch loader with the estimate and the
edge length that would fit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from eit_skin.patch.protocol import build_protocol

if TYPE_CHECKING:
    from eit_skin.patch.model import Layer

FILL = 1.58
"""Triangles per equilateral triangle of edge ``max_edge`` in the interior (Triangle, q30)."""
BOUNDARY_FILL = 6.0
"""Extra triangles per unit of ``length * (1/s - 1/h)`` along boundary pieces of spacing s < h."""
GRADING_FILL = 24.0
"""Extra triangles per electrode per ``ln(max_edge / electrode_edge)`` (graded outline)."""

BYTES_PER_TRIANGLE = 1600.0
"""Peak memory of meshing + forward assembly per triangle, apart from the M x N arrays, bytes."""
BYTES_PER_TRIANGLE_AND_MEASUREMENT = 24.0
"""Peak memory per triangle and measurement: three float64 ``[M, N]`` arrays alive at once."""
SECONDS_PER_TRIANGLE = 25e-6
"""CPU time per triangle of meshing + forward assembly at :data:`TRIANGLES_REFERENCE`, s."""
SECONDS_PER_TRIANGLE_AND_MEASUREMENT = 70e-9
"""CPU time per triangle and measurement (Jacobian rows) at :data:`TRIANGLES_REFERENCE`, s."""
TRIANGLES_REFERENCE = 100_000
TIME_EXPONENT = 0.3
"""The time per triangle grows as ``N ** TIME_EXPONENT`` (sparse factorisation fill-in)."""

MAX_PEAK_BYTES = 2 * 2**30
"""Largest estimated peak memory of one mesh (2 GiB)."""
MAX_SECONDS = 60.0
"""Largest estimated CPU time of one mesh, s."""


@dataclass(frozen=True)
class MeshCost:
    """Estimated size and cost of one mesh.

    Attributes:
        triangles: estimated triangle count.
        peak_bytes: estimated peak memory of meshing + forward assembly, bytes.
        seconds: estimated CPU time of meshing + forward assembly, s.
    """

    triangles: int
    peak_bytes: float
    seconds: float

    @property
    def fits(self) -> bool:
        return self.peak_bytes <= MAX_PEAK_BYTES and self.seconds <= MAX_SECONDS

    def describe(self) -> str:
        return (
            f"~{self.triangles:.3g} triangles, ~{self.peak_bytes / 2**30:.3g} GiB and "
            f"~{_duration(self.seconds)} to mesh and assemble the forward model"
        )


def estimate_triangles(layer: Layer, max_edge_m: float, electrode_edge_m: float) -> float:
    """Estimated triangle count of ``build_mesh`` at these edge lengths (m)."""
    h = float(max_edge_m)
    h_el = min(float(electrode_edge_m), h)
    fine = 0.0  # sum of length * (1/s - 1/h) over boundary pieces finer than h
    for loop in (layer.outline, *layer.holes):
        edges = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
        fine += float(np.sum(edges * (1.0 / np.minimum(edges, h) - 1.0 / h)))
    widths = np.array([e.width_m for e in layer.electrodes])
    fine += float(np.sum(widths)) * (1.0 / h_el - 1.0 / h)
    interior = layer.area_m2 / (math.sqrt(3.0) / 4.0 * h * h)
    grading = len(widths) * math.log(h / h_el)
    return FILL * interior + BOUNDARY_FILL * fine + GRADING_FILL * grading


def estimate_cost(triangles: float, n_measurements: int) -> MeshCost:
    """Peak memory and CPU time of meshing + forward assembly of ``triangles`` triangles."""
    n = max(float(triangles), 1.0)
    peak = n * (BYTES_PER_TRIANGLE + BYTES_PER_TRIANGLE_AND_MEASUREMENT * n_measurements)
    per_triangle = SECONDS_PER_TRIANGLE + SECONDS_PER_TRIANGLE_AND_MEASUREMENT * n_measurements
    seconds = n * per_triangle * (n / TRIANGLES_REFERENCE) ** TIME_EXPONENT
    return MeshCost(round(n), peak, seconds)


def estimate_layer(layer: Layer, max_edge_m: float | None = None) -> MeshCost:
    """Cost of the layer's mesh at ``max_edge_m`` (default ``layer.mesh.max_edge_m``)."""
    h = layer.mesh.max_edge_m if max_edge_m is None else max_edge_m
    n = estimate_triangles(layer, h, layer.mesh.electrode_edge_m)
    return estimate_cost(n, _n_measurements(layer))


def budget_problem(layer: Layer) -> tuple[str, str] | None:
    """``(mesh key, reason)`` if a mesh of the layer is over budget, else ``None``.

    Checks the forward mesh (``max_edge``) and the inverse mesh (``inverse_max_edge``);
    the reason gives the estimate, the limits and the edge length that would fit.
    """
    spec = layer.mesh
    edges = [("max_edge", spec.max_edge_m)]
    if spec.inverse_max_edge_m is not None:
        edges.append(("inverse_max_edge", spec.inverse_max_edge_m))
    for key, h in edges:
        problem = _over_budget(layer, key, h)
        if problem is not None:
            return problem
    return None


def _over_budget(layer: Layer, key: str, h: float) -> tuple[str, str] | None:
    m = _n_measurements(layer)
    h_el = layer.mesh.electrode_edge_m

    def fits(h_try: float, h_el_try: float) -> bool:
        return estimate_cost(estimate_triangles(layer, h_try, h_el_try), m).fits

    cost = estimate_cost(estimate_triangles(layer, h, h_el), m)
    if cost.fits:
        return None
    limit = f"the limit is {MAX_PEAK_BYTES / 2**30:g} GiB and {_duration(MAX_SECONDS)}"
    extent = float(np.ptp(layer.outline, axis=0).max())
    if fits(max(extent, h), h_el):  # a coarser mesh fits
        h_fit = _round_up(_smallest_fitting(lambda x: fits(x, h_el), h))
        return key, f"{cost.describe()}; {limit}: {key} >= {h_fit:.2g} m would fit"
    h_el_fit = _round_up(_smallest_fitting(lambda x: fits(max(h, x), x), h_el))
    return "electrode_edge", (
        f"{cost.describe()} (with {key} {h:g} m); {limit}: electrode_edge >= "
        f"{h_el_fit:.2g} m would fit"
    )


def _n_measurements(layer: Layer) -> int:
    return build_protocol(layer.protocol, layer.n_electrodes).n_measurements


def _smallest_fitting(fits: Callable[[float], bool], too_small: float) -> float:
    """Smallest length (within 1 %) above ``too_small`` for which ``fits`` holds (monotonic)."""
    lo, hi = too_small, too_small
    while not fits(hi):
        lo, hi = hi, hi * 2.0
    while hi > lo * 1.01:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def _round_up(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    step = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.ceil(x / step * (1 - 1e-12)) * step


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.2g} s"
    if seconds < 7200:
        return f"{seconds / 60:.2g} min"
    return f"{seconds / 3600:.2g} h"
