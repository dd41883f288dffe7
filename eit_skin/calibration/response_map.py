"""Press position by matching the pattern to a learnt response map (position -> pattern).

The inverse kernel ridge (:class:`~eit_skin.calibration.kernel_ridge.KernelRidge`, pattern ->
position) interpolates in the pattern space, whose dimension (8-64 components) a few dozen
presses cover thinly. The **response map** learns the other direction, press centre ``[2]`` m
-> the pattern's leading principal components ``[K]``, a kernel ridge on the sheet's two
dimensions that few presses already cover. A frame is located by comparing its pattern with
the map's prediction on a grid over the training presses' region (:func:`press_region_grid`):
the posterior mean of the grid points under a Gaussian misfit whose variance is the map's own
leave-one-out residual (no temperature tuned to a data set; the grid step is a fixed fraction
of the presses' extent).

Leave-one-out in closed form, as for the inverse model: removing press ``i`` moves the map's
prediction at ``x`` by ``B(x, i) a_i / A_ii`` (``A`` the inverse regularised kernel matrix,
``a = A y``, ``B = k(x) A``), so every press is located by a map that never saw it.
:func:`fit_position` keeps the map only when it is
:func:`~eit_skin.calibration.kernel_ridge.clearly_better` than the inverse model
(bench/standing/press_calibration.md, "The response map").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from eit_skin.calibration.kernel_ridge import (
    COMPONENT_COUNTS,
    KernelRidge,
    clearly_better,
    nearest_other,
    nearest_share,
    squared_distances,
)
from eit_skin.calibration.stored_fields import StoredFields, stored_dataclass

GRID_STEPS = 64
"""Grid steps across the larger side of the training presses' bounding box."""


def press_region_grid(xy: np.ndarray, steps: int = GRID_STEPS) -> np.ndarray:
    """``[G, 2]`` candidate press centres m: a square grid over the presses ``xy`` [N, 2].

    The points inside the presses' convex hull or within ``reach`` of a press, ``reach`` the
    largest distance of a press to its nearest other one (so every press's neighbourhood is
    covered, also beyond the hull of a few presses; presses on one line have no hull); the
    step is the larger side of the presses' bounding box over ``steps``.
    """
    reach = float(nearest_other(squared_distances(xy, xy)).max())
    low, high = xy.min(axis=0), xy.max(axis=0)
    step = float((high - low).max()) / steps
    axes = [
        np.arange(a - reach, b + reach + step / 2, step) for a, b in zip(low, high, strict=True)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    near = squared_distances(grid, xy).min(axis=1) <= reach * reach
    try:
        return grid[near | (Delaunay(xy).find_simplex(grid) >= 0)]
    except QhullError:  # collinear presses: their neighbourhoods only
        return grid[near]


def posterior_mean(misfit: np.ndarray, variance: float, grid: np.ndarray) -> np.ndarray:
    """``[T, 2]`` mean of ``grid`` [G, 2] weighted by ``exp(-misfit / (2 variance))`` [T, G]."""
    log_w = -0.5 * misfit / variance
    w = np.exp(log_w - log_w.max(axis=1, keepdims=True))
    return (w @ grid) / w.sum(axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class ResponseMap:
    """Position model: pattern ``[T, M]`` -> press centre by a learnt response map.

    Attributes:
        centre: ``[M]`` mean training pattern.
        projection: ``[M, K]`` leading principal directions of the training patterns.
        grid: ``[G, 2]`` candidate press centres, m.
        grid_responses: ``[G, K]`` the map's projected pattern at each grid point.
        variance: misfit variance per component (the map's leave-one-out residual).
        responses: ``[N, K]`` projected training patterns (for the confidence).
        spacing: ``[N]`` sorted distances of each training response to its nearest other one.
        loo_error: mean leave-one-out position error, m.
        loo_errors: ``[N]`` those errors per press (only after :func:`fit_response_map`).
    """

    centre: np.ndarray
    projection: np.ndarray
    grid: np.ndarray
    grid_responses: np.ndarray
    variance: float
    responses: np.ndarray
    spacing: np.ndarray
    loo_error: float
    loo_errors: np.ndarray | None = None

    def predict(self, pattern: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``[T, 2]`` press centres m, ``[T]`` confidence in [0, 1]) of ``pattern`` [T, M]."""
        z = (np.asarray(pattern, float) - self.centre) @ self.projection
        xy = posterior_mean(squared_distances(z, self.grid_responses), self.variance, self.grid)
        nearest = squared_distances(z, self.responses).min(axis=1)
        return xy, nearest_share(np.sqrt(nearest), self.spacing)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return stored_dataclass(prefix, self, skip=("loo_errors",))

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> ResponseMap:
        return StoredFields(arrays, prefix).dataclass(cls, skip=("loo_errors",))


def fit_response_map(
    pattern: np.ndarray, xy: np.ndarray, projection: np.ndarray, grid: np.ndarray
) -> ResponseMap:
    """The map of ``pattern`` [N, M] on ``projection`` [M, K] over ``grid`` [G, 2], with LOO."""
    centre = pattern.mean(axis=0)
    z = (pattern - centre) @ projection
    fwd = KernelRidge.fit(xy, z)
    inverse = np.linalg.inv(
        np.exp(-fwd.gamma * squared_distances(xy, xy)) + fwd.ridge * np.eye(len(xy))
    )
    influence = np.exp(-fwd.gamma * squared_distances(grid, xy)) @ inverse  # B [G, N]
    shift = fwd.weights / np.diag(inverse)[:, None]  # [N, K]: y_i - LOO prediction
    variance = float(np.mean(shift * shift))
    responses = fwd.predict(grid)[0]  # [G, K]
    # |z_i - (r_g - B_gi s_i)|^2 for every press i and grid point g, without an [N, G, K] array
    misfit = (
        squared_distances(z, responses)
        + 2.0 * influence.T * ((z * shift).sum(axis=1)[:, None] - shift @ responses.T)
        + influence.T**2 * (shift * shift).sum(axis=1)[:, None]
    )
    errors = np.linalg.norm(posterior_mean(misfit, variance, grid) - xy, axis=1)
    spacing = np.sort(nearest_other(squared_distances(z, z)))
    return ResponseMap(
        centre, projection, grid, responses, variance, z, spacing, float(errors.mean()), errors
    )


def fit_position(
    pattern: np.ndarray, xy: np.ndarray, components: tuple[int, ...] = COMPONENT_COUNTS
) -> KernelRidge | ResponseMap:
    """Position model of patterns ``[N, M]`` and press centres ``[N, 2]`` m.

    The inverse kernel ridge (projection chosen by leave-one-out) unless a response map on one
    of ``components`` leading principal components is clearly better by leave-one-out.
    """
    inverse = KernelRidge.fit(pattern, xy, components=components)
    grid = press_region_grid(xy)
    directions = np.linalg.svd(pattern - pattern.mean(axis=0), full_matrices=False)[2].T
    best: KernelRidge | ResponseMap = inverse
    for k in sorted(c for c in components if c < min(directions.shape[1], pattern.shape[1])):
        candidate = fit_response_map(pattern, xy, directions[:, :k], grid)
        if candidate.loo_error < best.loo_error:
            best = candidate
    if best is inverse or not clearly_better(inverse.loo_errors, best.loo_errors):
        return inverse
    return best
