"""Iterative regularised Gauss-Newton (the seed's equation 1) for large contrasts.

Unknown: log sheet conductance ``s = ln sigma`` per forward-mesh element (keeps
``sigma > 0``). Objective, in relative data units (see :mod:`eit_skin.reconstruction`):

    ``phi(s) = || (v_target - F(e^s)) / w ||^2 + lambda^2 (s - s0)^T P (s - s0)``

with ``w`` the floored reference scale (volts), ``P`` the sparse prior, factorised
once and reused in every iteration. Each step solves the normal equations in the
dual (``M x M``) form

    ``ds = P^-1 J^T (J P^-1 J^T + lambda^2 I)^-1 (r + J d) - d``,  ``d = s - s0``,

where ``J = diag(1/w) dF/dsigma diag(sigma)``; ``lambda^2 = h^2 trace(J P^-1 J^T)/M``
is fixed at the first iteration. Speed: ``J = C G`` is used in the factored form of
:meth:`eit_skin.forward.ForwardModel.jacobian_basis` (``G`` ``[P, N]``, ``P = 120`` field-pair
products for 16 electrodes, ``C`` sparse ``[M, P]``), so each iteration needs only ``P``
prior solves and a ``P x P`` product ``G P^-1 G^T``; the forward factorisation of the accepted
line-search point is reused (cached) for the next Jacobian. A backtracking line search halves
the step until ``phi`` decreases (one forward solve when the full step is accepted); iteration
stops when the relative residual ``||r|| / ||v_target / w||`` falls below ``tolerance``, when
no step lowers ``phi`` or lowers it by less than ``stagnation`` (relative), or after
``max_iterations``. ``|s - s0|`` is clipped to ``max_log_contrast``
so the output stays bounded and finite even for a silver mesh (~zero resistance).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from eit_skin.priors import Prior, make_prior
from eit_skin.reconstruction import reference_scale

DEFAULT_MAX_LOG_CONTRAST = float(np.log(1e5))


@dataclass(frozen=True)
class GaussNewtonResult:
    """Outcome of :func:`gauss_newton`.

    Attributes:
        sigma: ``[N]`` sheet conductance, siemens.
        relative_change: ``[N]`` ``sigma / sigma0 - 1`` (positive = more conductive).
        iterations: Gauss-Newton steps taken.
        relative_residuals: ``[iterations + 1]`` ``||r|| / ||v_target / w||`` history.
        converged: True when the residual tolerance was met.
    """

    sigma: np.ndarray
    relative_change: np.ndarray
    iterations: int
    relative_residuals: np.ndarray
    converged: bool


def gauss_newton(
    forward: Any,
    v_target: np.ndarray,
    sigma0: np.ndarray | float,
    prior: str | Prior = "laplace",
    hyperparameter: float = 0.03,
    max_iterations: int = 10,
    tolerance: float = 1e-3,
    max_log_contrast: float = DEFAULT_MAX_LOG_CONTRAST,
    weights_v: np.ndarray | None = None,
    stagnation: float = 1e-9,
) -> GaussNewtonResult:
    """Absolute regularised Gauss-Newton fit of ``F(sigma)`` to ``v_target`` ``[M]`` volts.

    Args:
        forward: model with ``.voltages(sigma)``, ``.jacobian(sigma)``, ``.mesh``.
        v_target: ``[M]`` volts to fit (finite).
        sigma0: starting and prior conductance, siemens, scalar or ``[N]``.
        prior: prior kind or a built :class:`Prior` (reuse it between calls).
        hyperparameter: dimensionless ``h``.
        max_iterations: at most this many Gauss-Newton steps.
        tolerance: stop when the relative residual is below this.
        max_log_contrast: bound on ``|ln(sigma / sigma0)|``.
        weights_v: ``[M]`` data scale ``w`` in volts (default: floored ``|v_target|``).
        stagnation: stop when a step lowers the objective by less than this fraction.
    """
    v_target = np.asarray(v_target, dtype=np.float64)
    if v_target.shape != (forward.n_measurements,) or not np.isfinite(v_target).all():
        raise ValueError(f"v_target must be finite [{forward.n_measurements}] volts")
    n = forward.mesh.n_triangles
    s0 = np.log(np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (n,)).copy())
    w = reference_scale(v_target) if weights_v is None else np.asarray(weights_v, float)
    target = v_target / w
    norm_target = float(np.linalg.norm(target)) or 1.0

    s = s0.copy()
    resid = target - forward.voltages(np.exp(s)) / w
    lam2 = None
    p = None
    history = [float(np.linalg.norm(resid)) / norm_target]
    phi = float(resid @ resid)  # data term at s
    converged = history[0] <= tolerance
    it = 0
    while not converged and it < max_iterations:
        sig = np.exp(s)
        products, combination = _jacobian_factors(forward, sig)
        g = products * sig[None, :]  # [P, N] d/d(ln sigma)
        cw = sp.csr_matrix(sp.diags(1.0 / w) @ combination)  # [M, P]
        if p is None:
            if isinstance(prior, Prior):
                p = prior
            else:
                j_first = None if prior != "noser" else np.asarray(cw @ g)
                p = make_prior(prior, forward.mesh, j_first)
        z = p.solve(g.T)  # [N, P] = P^-1 G^T, P <= M right-hand sides
        kg = g @ z
        k = np.asarray(cw @ (cw @ (0.5 * (kg + kg.T))).T)  # [M, M] = J P^-1 J^T
        if lam2 is None:
            lam2 = float(hyperparameter) ** 2 * max(float(np.trace(k)) / k.shape[0], 1e-300)
        d = s - s0
        rhs = resid + cw @ (g @ d)
        low = np.linalg.cholesky(k + lam2 * np.eye(k.shape[0]))
        u = sla.cho_solve((low, True), rhs, check_finite=False)
        step = z @ (cw.T @ u) - d
        it += 1
        objective = phi + lam2 * p.quadratic(d)
        alpha, improved = 1.0, False
        for _ in range(12):
            trial = s0 + np.clip(s + alpha * step - s0, -max_log_contrast, max_log_contrast)
            r_trial = target - forward.voltages(np.exp(trial)) / w
            dt = trial - s0
            phi_trial = float(r_trial @ r_trial) + lam2 * p.quadratic(dt)
            if np.isfinite(phi_trial) and phi_trial < objective:
                improved = True
                break
            alpha *= 0.5
        if not improved:
            break
        s, resid = trial, r_trial
        phi = float(resid @ resid)
        history.append(float(np.linalg.norm(resid)) / norm_target)
        converged = history[-1] <= tolerance
        if objective - phi_trial <= stagnation * objective:  # no progress left
            break
    sigma = np.exp(s)
    return GaussNewtonResult(
        sigma=sigma,
        relative_change=np.expm1(s - s0),
        iterations=it,
        relative_residuals=np.asarray(history),
        converged=converged,
    )


def _jacobian_factors(forward: Any, sigma: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
    """``(products [P, N], combination [M, P])`` with ``dV/dsigma = combination @ products``.

    Uses :meth:`ForwardModel.jacobian_basis` (``P = (n_el - 1) n_el / 2 < M``) when the model
    has it, else the plain Jacobian with an identity combination.
    """
    if hasattr(forward, "jacobian_basis"):
        basis = forward.jacobian_basis(sigma)
        return basis.products, basis.combination
    j = np.asarray(forward.jacobian(sigma), dtype=np.float64)
    return j, sp.identity(j.shape[0], format="csr")


def gauss_newton_difference(
    forward: Any,
    frame: np.ndarray,
    reference: np.ndarray,
    sigma0: np.ndarray | float = 1.0,
    **kwargs: Any,
) -> GaussNewtonResult:
    """Difference imaging with the iterative solver (large contrasts).

    The measured relative change ``(v - v_ref) / s_ref`` is applied to the model's
    reference voltages ``F(sigma0)``, and that target is fitted from ``sigma0``; so an
    unknown gain or absolute conductance cancels as in one-step imaging. Channels that
    are NaN/Inf in the frame or reference keep the model's value (no information).
    """
    from eit_skin.reconstruction import relative_difference

    sig0 = np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (forward.mesh.n_triangles,))
    v0 = forward.voltages(sig0)
    dv = relative_difference(frame, reference)
    dv = np.where(np.isfinite(dv), dv, 0.0)
    return gauss_newton(forward, v0 + reference_scale(v0) * dv, sig0, **kwargs)
