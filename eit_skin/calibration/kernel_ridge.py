"""RBF kernel ridge regression with leave-one-out hyperparameters (a GP's posterior mean).

Used by the press localiser (:mod:`eit_skin.calibration.localiser`) and its physics prior
(:mod:`eit_skin.calibration.physics_prior`). Hyperparameters are chosen inside every fit by a
scale-free rule: the inputs may be projected on their leading principal components (a count
of :data:`COMPONENT_COUNTS` or all of them; the press localiser's position model), the length
scale is a factor of the median pairwise distance of the (projected) training inputs, the
ridge is relative to the kernel's unit diagonal, and the choice with the least closed-form
leave-one-out error wins. The projection drops the directions in which the training presses
hardly vary, mostly noise (issue 37, item 4: bench/standing/press_calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from eit_skin.calibration.stored_fields import StoredFields, stored_fields

LENGTH_SCALE_FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
"""Kernel length scales tried, as factors of the median pairwise feature distance."""

RIDGE_GRID = tuple(10.0 ** np.arange(-6, 1))
"""Ridge values tried, relative to the kernel's unit diagonal (dimensionless)."""

COMPONENT_COUNTS = (8, 16, 32, 64)
"""Leading principal components of the training inputs tried (those below the input dimension
and the training count), besides all inputs unprojected."""


def clearly_better(base: np.ndarray, candidate: np.ndarray) -> bool:
    """Whether ``candidate``'s leave-one-out errors ``[N]`` beat ``base``'s beyond noise.

    The mean paired gain must exceed one standard error of the paired differences: a choice
    among several fits by leave-one-out is otherwise decided by selection noise.
    """
    gained = np.asarray(base) - np.asarray(candidate)
    return bool(gained.mean() > gained.std(ddof=1) / np.sqrt(gained.size))


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[A, B]`` squared Euclidean distances between the rows of ``a`` [A, D] and ``b`` [B, D]."""
    d = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2.0 * a @ b.T
    return np.maximum(d, 0.0)


def nearest_other(d2: np.ndarray) -> np.ndarray:
    """``[N]`` distance of each point to its nearest other one, from squared distances [N, N]."""
    return np.sqrt(np.where(np.eye(len(d2), dtype=bool), np.inf, d2).min(axis=1))


def nearest_share(nearest: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """``[T]`` confidence: share of the sorted training ``spacing`` [N] >= ``nearest`` [T].

    ``nearest``: each query's distance to its nearest training input; ``spacing``: each
    training input's distance to its nearest other one (the localiser's confidence rule).
    """
    farther = spacing.size - np.searchsorted(spacing, nearest, side="left")
    return farther / spacing.size


@dataclass(frozen=True, eq=False)
class KernelRidge:
    """RBF kernel ridge regression (GP posterior mean) with leave-one-out hyperparameters.

    Attributes:
        inputs: ``[N, D0]`` training features (before any projection).
        gamma: kernel ``exp(-gamma |x - x'|^2)``, 1 / feature unit^2.
        ridge: ridge relative to the unit kernel diagonal.
        weights: ``[N, K]`` dual weights.
        offset: ``[K]`` mean of the training targets (the prediction far from all data).
        spacing: ``[N]`` sorted distances of each training input to its nearest other one.
        loo_error: mean Euclidean leave-one-out error of the chosen pair, target units.
        loo_errors: ``[N]`` those errors per training input (only after :meth:`fit`, not
            stored in files).
        projection: ``[D0, D]`` principal directions the raw inputs ``[., D0]`` are projected
            on (after removing ``centre``), or None: inputs used as they are.
        centre: ``[D0]`` mean of the raw training inputs, or None.
    """

    inputs: np.ndarray
    gamma: float
    ridge: float
    weights: np.ndarray
    offset: np.ndarray
    spacing: np.ndarray
    loo_error: float
    loo_errors: np.ndarray | None = None
    projection: np.ndarray | None = None
    centre: np.ndarray | None = None

    def __post_init__(self) -> None:
        projected = self.inputs
        if self.projection is not None:
            projected = (self.inputs - self.centre) @ self.projection
        object.__setattr__(self, "_kernel_inputs", projected)  # what the kernel compares

    @classmethod
    def fit(
        cls,
        inputs: np.ndarray,
        targets: np.ndarray,
        factors: tuple[float, ...] = LENGTH_SCALE_FACTORS,
        ridges: tuple[float, ...] = RIDGE_GRID,
        components: tuple[int, ...] = (),
    ) -> KernelRidge:
        """Fit ``targets`` [N, K] on ``inputs`` [N, D]; components, factor and ridge by LOO.

        ``components``: counts of leading principal components tried besides all inputs (the
        press localiser's position model: :data:`COMPONENT_COUNTS`; default none); the best
        projection is kept only if it is :func:`clearly_better` than all inputs.
        """
        raw = np.asarray(inputs, float)
        y = np.asarray(targets, float).reshape(len(raw), -1)
        plain = cls._fit_projected(raw, y, factors, ridges)
        centre = raw.mean(axis=0)
        directions = np.linalg.svd(raw - centre, full_matrices=False)[2].T  # [D, min(N, D)]
        best, projection = plain, None
        for k in sorted(c for c in components if c < min(directions.shape[1], raw.shape[1])):
            model = cls._fit_projected((raw - centre) @ directions[:, :k], y, factors, ridges)
            if model.loo_error < best.loo_error:
                best, projection = model, directions[:, :k]
        if projection is None or not clearly_better(plain.loo_errors, best.loo_errors):
            return plain  # a projection must beat all inputs beyond selection noise
        return replace(best, inputs=raw, projection=projection, centre=centre)

    @classmethod
    def _fit_projected(cls, x, y, factors, ridges) -> KernelRidge:
        """The (factor, ridge) pair by LOO on inputs ``x`` [N, D] as they are.

        One eigendecomposition per length scale gives the exact leave-one-out residuals
        ``(y - H y) / (1 - diag H)`` of every ridge at once.
        """
        offset = y.mean(axis=0)
        yc = y - offset
        d2 = squared_distances(x, x)
        median = float(np.median(d2[np.triu_indices(len(x), 1)]))
        if not median > 0:
            raise ValueError("all training features are identical: nothing to learn from")
        best = (np.inf, 1.0, 1.0, np.zeros(len(x)))
        for factor in factors:
            gamma = 1.0 / (2.0 * factor * factor * median)
            s, U = np.linalg.eigh(np.exp(-gamma * d2))
            s = np.maximum(s, 0.0)
            Uy = U.T @ yc
            U2 = U * U
            for ridge in ridges:
                g = s / (s + ridge)
                residual = (yc - U @ (g[:, None] * Uy)) / (1.0 - U2 @ g)[:, None]
                errors = np.linalg.norm(residual, axis=1)
                if errors.mean() < best[0]:
                    best = (float(errors.mean()), gamma, ridge, errors)
        error, gamma, ridge, errors = best
        weights = np.linalg.solve(np.exp(-gamma * d2) + ridge * np.eye(len(x)), yc)
        spacing = np.sort(nearest_other(d2))
        return cls(x, gamma, ridge, weights, offset, spacing, error, errors)

    def predict(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``[T, K]`` prediction, ``[T]`` confidence in [0, 1]) for ``queries`` [T, D]."""
        if self.projection is not None:
            queries = (np.asarray(queries, float) - self.centre) @ self.projection
        d2 = squared_distances(queries, self._kernel_inputs)
        confidence = nearest_share(np.sqrt(d2.min(axis=1)), self.spacing)
        return np.exp(-self.gamma * d2) @ self.weights + self.offset, confidence

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        projected = {}
        if self.projection is not None:
            projected = {"projection": self.projection, "centre": self.centre}
        return stored_fields(
            prefix,
            **projected,
            inputs=self.inputs,
            gamma=np.float64(self.gamma),
            ridge=np.float64(self.ridge),
            weights=self.weights,
            offset=self.offset,
            spacing=self.spacing,
            loo_error=np.float64(self.loo_error),
        )

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> KernelRidge:
        fields = StoredFields(arrays, prefix)
        return cls(
            fields["inputs"],
            fields.value("gamma"),
            fields.value("ridge"),
            fields["weights"],
            fields["offset"],
            fields["spacing"],
            fields.value("loo_error"),
            projection=fields.get("projection"),
            centre=fields.get("centre"),
        )
