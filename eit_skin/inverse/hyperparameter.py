"""Choosing the regularisation hyperparameter without hand tuning.

Noise figure (Adler & Guardo 1996, as in EIDORS ``calc_noise_figure``):
``NF = SNR_out / SNR_in`` for a small target at the centre of the sheet, with
unit white noise on the relative voltage changes. ``SNR_in = mean|dv_h| / 1``;
``SNR_out = sum_e a_e |x_e| / sqrt(sum_e a_e var(x_e))`` with area weights ``a``. For a
channel-weighted matrix (measured noise, ``Sigma = diag(s^2)``) the noise is that measured
noise: the figure is computed in the whitened channels ``S^-1 dv``, where it is white.
Small ``h`` -> noisy image -> small NF; NF grows with ``h`` towards a plateau.
:func:`choose_by_noise_figure` finds the ``h`` that hits a target NF (bisection in
``log h``) from ``K = J P^-1 J^T`` and ``Y = P^-1 J^T`` cached in the
:class:`ReconstructionMatrix`. One symmetric eigendecomposition ``K = V diag(s) V^T`` and one
``[N, M] x [M, M]`` product are paid once; with ``c = 1 / (s + lambda^2)`` each trial is then
``x = (Y V) (c * V^T dv)`` and ``sum_e a_e var(x_e) = sum_i c_i^2 ||a^1/2 (Y V)_i||^2``:
O(N M), no factorisation and no rebuild, so a node imaging several patches does not stall when
they capture their references. The chosen ``h`` is returned so it can be stored in the patch
config (``solver.hyperparameter``).

Model error (a discrepancy principle, :func:`choose_for_model_error`): on a real device the
data's unexplained part is not the measured noise but what the model gets wrong. Its size is
measured once per reference: the typical relative misfit ``eps`` of the reference to the
homogeneous model at its scale (:func:`reference_misfit`, medians: faults are not model
error). Normalised difference data keep only a share of it (a common gain, contact impedance
or sheet conductance cancels), so the fit must leave unexplained ``MODEL_ERROR_SHARE * eps``
of the data: ``h`` such that
``sqrt(trace((I - A)^2 K) / trace(K)) = MODEL_ERROR_SHARE * eps`` with ``A = K (K +
lambda^2 I)^-1`` (the relative residual expected for data drawn from the prior, which
``K = J P^-1 J^T`` is the covariance of). Scale-free: ``eps`` and the residual are fractions.
The hyperparameter in use is the larger of the two rules' (noise figure on the measured
noise, discrepancy on the model error): each asks for at least that much regularisation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg as sla

from eit_skin.inverse.dual_form import lambda_squared, regularised_inverse
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE

if TYPE_CHECKING:
    from eit_skin.fem.mesh import Mesh
    from eit_skin.inverse.one_step import ReconstructionMatrix

H_RANGE = (1e-4, 1e1)

#: Share of the reference's relative misfit to the model that normalised difference data keep
#: as model error (:func:`choose_for_model_error`). Chosen with the default prior and noise
#: figure by leaving one set out over the five real recordings of ``data/real/`` and the
#: simulator among 1/2 .. 1/32, with equal channel weights (``solver.channel_weights``) and the
#: tanks' fitted depths (the table in ``bench/standing/real_data.md``: the choice on all six
#: sets and of four of the six folds, missing no goal on any set; 1/4 with measured weights
#: and 2-D tanks before); not fitted to any one set.
MODEL_ERROR_SHARE = 1.0 / 2.0


def _target(
    mesh: Mesh | None, n: int, radius_fraction: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Area weights ``[N]`` and a centre target indicator ``[N]`` on the imaging mesh."""
    if mesh is None:
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
    nf = _NoiseFigure(*rm.gram, rm.whitened_jacobian, rm.mesh)
    return nf(rm.hyperparameter if h is None else float(h))


class _NoiseFigure:
    """``h -> NF(h)`` for one matrix: one eigendecomposition up front, O(N M) per call."""

    def __init__(
        self, k: np.ndarray, y: np.ndarray, jacobian: np.ndarray, mesh: Mesh | None
    ) -> None:
        weights, target = _target(mesh, y.shape[0])
        dv = jacobian @ target  # [M_used], in units of the channel noise
        s, v = sla.eigh(k, driver="evr", check_finite=False)
        yv = y @ v  # [N, M]: Y in the eigenbasis of K
        self._s = np.clip(s, 0.0, None)  # K is positive semi-definite; clip rounding
        self._m = k.shape[0]
        self._yv = yv
        self._vdv = v.T @ dv  # [M]
        self._weights = weights
        self._snr_in = float(np.mean(np.abs(dv)))
        self._g = weights @ (yv * yv)  # [M] = diag(V^T Y^T diag(a) Y V)
        self._trace = float(np.trace(k))

    def __call__(self, h: float) -> float:
        c = 1.0 / (self._s + lambda_squared(h, self._trace, self._m))  # [M] eigenvalues of C^-1
        x = self._yv @ (c * self._vdv)  # [N] image of the centre target
        signal = float(self._weights @ np.abs(x))
        # sum_e a_e var(x_e) = trace(C^-1 G C^-1) = sum_i c_i^2 (V^T G V)_ii
        noise2 = float(self._g @ (c * c))
        if not (noise2 > 0 and self._snr_in > 0):
            return 0.0
        return (signal / np.sqrt(noise2)) / self._snr_in


def choose_by_noise_figure(
    rm: ReconstructionMatrix, target: float | None = None, tolerance: float = 1e-9
) -> float:
    """Hyperparameter ``h`` whose noise figure equals ``target`` (bisection in ``log h``).

    ``target`` ``None``: the default of the matrix's method
    (:data:`eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`). If the target lies outside what
    ``h`` in :data:`H_RANGE` can reach, the nearest end of the range is returned.
    """
    target = DEFAULT_NOISE_FIGURE[rm.method] if target is None else target
    return choose_for_gram(*rm.gram, rm.whitened_jacobian, rm.mesh, target, tolerance)


def choose_for_gram(
    k: np.ndarray,
    y: np.ndarray,
    jacobian: np.ndarray,
    mesh: Mesh | None,
    target: float,
    tolerance: float = 1e-9,
) -> float:
    """:func:`choose_by_noise_figure` from the Gram pair, before any matrix is assembled.

    Args:
        k: ``[Mu, Mu]`` ``K`` of the used (whitened) channels.
        y: ``[N, Mu]`` ``Y``, so that ``R = Y (K + lambda^2 I)^-1``.
        jacobian: ``[Mu, N]`` the (whitened) Jacobian of the used channels.
        mesh: the imaging mesh (area weights, centre target); None: equal weights.
        target: the noise figure to hit.
        tolerance: width of the final bracket in ``log h``.
    """
    target = float(target)
    if not (np.isfinite(target) and target > 0):
        raise ValueError(f"noise figure target must be > 0, got {target}")
    nf = _NoiseFigure(k, y, jacobian, mesh)
    lo, hi = np.log(H_RANGE[0]), np.log(H_RANGE[1])
    f_lo, f_hi = nf(float(np.exp(lo))), nf(float(np.exp(hi)))
    if target <= f_lo:
        return float(np.exp(lo))
    if target >= f_hi:
        return float(np.exp(hi))
    # bisection in log h: each trial is O(N M), so ~35 trials cost a few ms, and the node does
    # not import scipy.optimize (~10 MB resident, ~0.5 s) for one root
    while hi - lo > tolerance:
        mid = 0.5 * (lo + hi)
        if nf(float(np.exp(mid))) < target:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


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


def reference_misfit(
    reference: np.ndarray, model_voltages: np.ndarray, used: np.ndarray | None = None
) -> float:
    """Typical relative misfit of the reference to the homogeneous model, robust to faults.

    ``sqrt(median((v - s m)^2) / median(v^2))`` with the scale ``s = median(v / m)``: medians,
    so that a dead electrode or a saturated channel (faults, which the frame path leaves out
    by itself) does not count as model error; up to half of the channels may be bad.

    Args:
        reference: ``[M]`` measured reference (any unit, the model's signs).
        model_voltages: ``[M]`` homogeneous model voltages (V).
        used: bool ``[M]`` channels to compare (default: finite ones).

    Returns:
        the misfit (dimensionless, 0 for a reference proportional to the model); NaN when no
        channel can be compared.
    """
    v = np.asarray(reference, dtype=np.float64)
    m = np.asarray(model_voltages, dtype=np.float64)
    ok = np.isfinite(v) & np.isfinite(m) & (m != 0)
    if used is not None:
        ok &= np.asarray(used, dtype=bool)
    v, m = v[ok], m[ok]
    if v.size == 0:
        return float("nan")
    typical = float(np.median(v * v))
    if not typical > 0:
        return float("nan")
    scale = float(np.median(v / m))
    return float(np.sqrt(np.median((v - scale * m) ** 2) / typical))


def unexplained_fraction(k: np.ndarray, h: float) -> float:
    """``sqrt(trace((I - A)^2 K) / trace(K))``: the relative residual of prior-drawn data.

    ``k``: ``[M, M]`` ``K = J P^-1 J^T`` (whitened, used channels); ``A = K (K + lambda^2 I)^-1``.
    """
    s = np.clip(sla.eigvalsh(k, driver="evr", check_finite=False), 0.0, None)
    return _unexplained(s, float(np.trace(k)), h)


def _unexplained(s: np.ndarray, trace: float, h: float) -> float:
    c = lambda_squared(h, trace, s.size)
    residual = c / (s + c)  # eigenvalues of I - A
    return float(np.sqrt((residual * residual) @ s / max(float(s.sum()), 1e-300)))


def choose_for_model_error(k: np.ndarray, fraction: float, tolerance: float = 1e-9) -> float:
    """Hyperparameter whose fit leaves ``fraction`` of prior-drawn data unexplained.

    Args:
        k: ``[M, M]`` ``K`` of the used (whitened) channels.
        fraction: the model error's share of the data (``MODEL_ERROR_SHARE * misfit``).
        tolerance: width of the final bracket in ``log h``.

    Returns:
        ``h`` in :data:`H_RANGE` (its lower end when ``fraction`` is below what it leaves,
        or not a positive number; the upper end when above).
    """
    s = np.clip(sla.eigvalsh(k, driver="evr", check_finite=False), 0.0, None)
    trace = float(np.trace(k))
    lo, hi = np.log(H_RANGE[0]), np.log(H_RANGE[1])
    if not (np.isfinite(fraction) and fraction > _unexplained(s, trace, H_RANGE[0])):
        return float(H_RANGE[0])
    if fraction >= _unexplained(s, trace, H_RANGE[1]):
        return float(H_RANGE[1])
    while hi - lo > tolerance:  # the residual grows with h
        mid = 0.5 * (lo + hi)
        if _unexplained(s, trace, float(np.exp(mid))) < fraction:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))
