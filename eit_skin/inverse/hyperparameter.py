"""Choosing the regularisation hyperparameter without hand tuning.

Noise figure (Adler & Guardo 1996, as in EIDORS ``calc_noise_figure``):
``NF = SNR_out / SNR_in`` for a small target at the centre of the sheet, with
unit white noise on the relative voltage changes. ``SNR_in = mean|dv_h| / 1``;
``SNR_out = sum_e a_e |x_e| / sqrt(sum_e a_e var(x_e))`` with area weights ``a``. For a
channel-weighted matrix (measured noise, ``Sigma = diag(s^2)``) the noise is that measured
noise: the figure is computed in the whitened channels ``S^-1 dv``, where it is white.
Small ``h`` -> noisy image -> small NF; NF grows with ``h`` towards a plateau.
:func:`choose_by_noise_figure` finds the ``h`` that hits a target NF (Brent's method in
``log h``) from ``K = J P^-1 J^T`` and ``Y = P^-1 J^T`` cached in the
:class:`ReconstructionMatrix`: each trial is one ``M x M`` Cholesky factorisation and one
``[N, M]`` matrix-vector product, no rebuild. The chosen ``h`` is returned so it can be
stored in the patch config (``solver.hyperparameter``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg as sla
from scipy.optimize import brentq

from eit_skin.inverse.dual_form import lambda_squared, regularised_inverse
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE

if TYPE_CHECKING:
    from eit_skin.inverse.one_step import ReconstructionMatrix

H_RANGE = (1e-4, 1e1)


def _target(
    rm: ReconstructionMatrix, radius_fraction: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Area weights ``[N]`` and a centre target indicator ``[N]`` on the imaging mesh."""
    mesh = rm.mesh
    if mesh is None:
        n = rm.n_elements
        return np.full(n, 1.0 / n), np.eye(1, n, n // 2).ravel()
    areas = np.abs(mesh.areas)
    c = mesh.centroids
    centre = (areas[:, None] * c).sum(0) / areas.sum()
    size = np.sqrt(areas.sum())
    d = np.linalg.norm(c - centre, axis=1)
    target = (d <= radius_fraction * size).astype(float)
    if not target.any():
        target[d.argmin()] = 1.0
    return areas / areas.sum(), target * areas


def noise_figure(rm: ReconstructionMatrix, h: float | None = None) -> float:
    """Noise figure of ``rm`` (or of the same matrix with hyperparameter ``h``)."""
    return _NoiseFigure(rm)(rm.hyperparameter if h is None else float(h))


class _NoiseFigure:
    """``h -> NF(h)`` for one matrix; each call costs one ``M x M`` Cholesky and O(N M)."""

    def __init__(self, rm: ReconstructionMatrix) -> None:
        k, y = rm.gram
        weights, target = _target(rm)
        self._k = k
        self._y = y
        self._weights = weights
        self._dv = rm.whitened_jacobian @ target  # [M_used], in units of the channel noise
        self._snr_in = float(np.mean(np.abs(self._dv)))
        self._g = (y * weights[:, None]).T @ y  # [M, M] = Y^T diag(a) Y
        self._trace = float(np.trace(k))

    def __call__(self, h: float) -> float:
        m = self._k.shape[0]
        c = self._k + lambda_squared(h, self._trace, m) * np.eye(m)
        low = np.linalg.cholesky(c)
        w = sla.solve_triangular(low, np.eye(m), lower=True, check_finite=False)  # C^-1 = W^T W
        x = self._y @ (w.T @ (w @ self._dv))
        signal = float(self._weights @ np.abs(x))
        # sum_e a_e var(x_e) = trace(C^-1 G C^-1) = trace((W G W^T)(W W^T))
        noise2 = float(np.sum((w @ self._g @ w.T) * (w @ w.T)))
        if not (noise2 > 0 and self._snr_in > 0):
            return 0.0
        return (signal / np.sqrt(noise2)) / self._snr_in


def choose_by_noise_figure(
    rm: ReconstructionMatrix, target: float | None = None, tolerance: float = 1e-9
) -> float:
    """Hyperparameter ``h`` whose noise figure equals ``target`` (Brent's method in ``log h``).

    ``target`` ``None``: the default of the matrix's method
    (:data:`eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`). If the target lies outside what
    ``h`` in :data:`H_RANGE` can reach, the nearest end of the range is returned.
    """
    target = DEFAULT_NOISE_FIGURE[rm.method] if target is None else float(target)
    if not (np.isfinite(target) and target > 0):
        raise ValueError(f"noise figure target must be > 0, got {target}")
    nf = _NoiseFigure(rm)
    lo, hi = np.log(H_RANGE[0]), np.log(H_RANGE[1])
    f_lo, f_hi = nf(float(np.exp(lo))), nf(float(np.exp(hi)))
    if target <= f_lo:
        return float(np.exp(lo))
    if target >= f_hi:
        return float(np.exp(hi))
    root = brentq(lambda t: nf(float(np.exp(t))) - target, lo, hi, xtol=tolerance, rtol=1e-12)
    return float(np.exp(root))


def choose_by_gcv(rm: ReconstructionMatrix, dv: np.ndarray, n_grid: int = 60) -> float:
    """Hyperparameter minimising generalised cross-validation for data ``dv`` ``[M]``.

    ``GCV(h) = M ||(I - A) dv||^2 / trace(I - A)^2`` with influence matrix
    ``A = K (K + lambda^2 I)^-1``, so ``I - A = lambda^2 (K + lambda^2 I)^-1``.
    """
    k, _ = rm.gram
    m = k.shape[0]
    d = np.asarray(dv, dtype=np.float64)[rm.channels]
    if rm.channel_scale is not None:
        d = d / rm.channel_scale[rm.channels]
    trace = float(np.trace(k))
    hs = np.exp(np.linspace(np.log(H_RANGE[0]), np.log(H_RANGE[1]), n_grid))
    scores = np.empty(n_grid)
    for i, h in enumerate(hs):
        lam2 = lambda_squared(float(h), trace, m)
        resid_op = lam2 * regularised_inverse(k, lam2)  # I - A
        scores[i] = m * float(np.sum((resid_op @ d) ** 2)) / float(np.trace(resid_op)) ** 2
    return float(hs[int(np.argmin(scores))])
