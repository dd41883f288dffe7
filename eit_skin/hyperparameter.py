"""Choosing the regularisation hyperparameter without hand tuning.

Noise figure (Adler & Guardo 1996, as in EIDORS ``calc_noise_figure``):
``NF = SNR_out / SNR_in`` for a small target at the centre of the sheet, with
unit white noise on the relative voltage changes. ``SNR_in = mean|dv_h| / 1``;
``SNR_out = sum_e a_e |x_e| / sqrt(sum_e a_e var(x_e))`` with area weights ``a``.
Small ``h`` -> noisy image -> small NF; NF grows with ``h`` towards a plateau.
:func:`choose_by_noise_figure` bisects ``log h`` to hit a target NF, using the
eigendecomposition cached in the :class:`ReconstructionMatrix` (each trial costs
one ``[N, M]`` product, no rebuild). The chosen ``h`` is returned so it can be
stored in the patch config (``solver.hyperparameter``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from eit_skin.reconstruction import ReconstructionMatrix

DEFAULT_NOISE_FIGURE = 1.0
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
    return float(_noise_figure_curve(rm, np.array([rm.hyperparameter if h is None else h]))[0])


def _noise_figure_curve(rm: ReconstructionMatrix, hs: np.ndarray) -> np.ndarray:
    from eit_skin.reconstruction import _lambda2

    s, u, yu = rm._eig
    weights, target = _target(rm)
    dv = rm.jacobian[rm.channels] @ target  # [M_used]
    snr_in = float(np.mean(np.abs(dv)))
    coeff = u.T @ dv
    w = weights @ (yu**2)  # [M_used]
    out = np.empty(len(hs))
    for i, h in enumerate(hs):
        g = 1.0 / (s + _lambda2(float(h), s))
        x = yu @ (coeff * g)
        signal = float(weights @ np.abs(x))
        noise = float(np.sqrt(w @ g**2))
        out[i] = (signal / noise) / snr_in if noise > 0 and snr_in > 0 else 0.0
    return out


def choose_by_noise_figure(
    rm: ReconstructionMatrix, target: float | None = None, iterations: int = 40
) -> float:
    """Hyperparameter ``h`` whose noise figure equals ``target`` (bisection in ``log h``).

    If the target lies outside what ``h`` in :data:`H_RANGE` can reach, the nearest end of
    the range is returned.
    """
    target = DEFAULT_NOISE_FIGURE if target is None else float(target)
    if not (np.isfinite(target) and target > 0):
        raise ValueError(f"noise figure target must be > 0, got {target}")
    lo, hi = np.log(H_RANGE[0]), np.log(H_RANGE[1])
    f_lo, f_hi = _noise_figure_curve(rm, np.exp([lo, hi]))
    if target <= f_lo:
        return float(np.exp(lo))
    if target >= f_hi:
        return float(np.exp(hi))
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if _noise_figure_curve(rm, np.array([np.exp(mid)]))[0] < target:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


def choose_by_gcv(rm: ReconstructionMatrix, dv: np.ndarray, n_grid: int = 60) -> float:
    """Hyperparameter minimising generalised cross-validation for data ``dv`` ``[M]``.

    ``GCV(h) = M ||(I - A) dv||^2 / trace(I - A)^2`` with influence matrix
    ``A = K (K + lambda^2 I)^-1`` (eigenvalues ``s / (s + lambda^2)``).
    """
    from eit_skin.reconstruction import _lambda2

    s, u, _ = rm._eig
    c2 = (u.T @ np.asarray(dv, dtype=np.float64)[rm.channels]) ** 2
    hs = np.exp(np.linspace(np.log(H_RANGE[0]), np.log(H_RANGE[1]), n_grid))
    scores = np.empty(n_grid)
    for i, h in enumerate(hs):
        f = _lambda2(float(h), s) / (s + _lambda2(float(h), s))  # eigenvalues of I - A
        scores[i] = s.size * float(c2 @ f**2) / float(f.sum()) ** 2
    return float(hs[int(np.argmin(scores))])
