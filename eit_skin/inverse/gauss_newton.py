"""Iterative regularised Gauss-Newton (the seed's equation 1) for large contrasts.

Unknown: the log-conductance change ``d = ln(sigma / sigma0)`` per element of a *parameter
mesh* (default: the forward mesh itself; or a coarser mesh over the same sheet, ``C`` the
fine-to-coarse 0/1 map of :func:`eit_skin.inverse.one_step.coarse_to_fine`, so
``sigma = sigma0 exp(C d)`` on the forward mesh and positivity is kept). Objective, in
relative data units (see :mod:`eit_skin.inverse.one_step`):

    ``phi(d) = || (v_target - F(sigma0 exp(C d))) / w ||^2 + lambda^2 d^T P d``

with ``w`` the floored reference scale (volts), ``P`` the sparse prior on the parameter mesh,
factorised once and reused in every iteration. Each step solves the normal equations in the
dual (``M x M``) form

    ``step = P^-1 J^T (J P^-1 J^T + lambda^2 I)^-1 (r + J d) - d``,

where ``J = diag(1/w) dF/dsigma diag(sigma) C``; ``lambda^2 = h^2 trace(J P^-1 J^T)/M``
is fixed at the first iteration. Speed: ``J = C_w G`` is used in the factored form of
:meth:`eit_skin.fem.forward.ForwardModel.jacobian_basis` (``G`` ``[P, N]``, ``P = 120`` field-pair
products for 16 electrodes, ``C_w`` sparse ``[M, P]``, constant), so each iteration needs
only ``P`` prior solves and a ``P x P`` product ``G P^-1 G^T``; with a coarse parameter mesh
``G C`` is one sparse product and everything after it is parameter-mesh sized. The forward
factorisation of the accepted line-search point is reused (cached) for the next Jacobian, so
an iteration costs one factorisation of the forward system when the full step is accepted.
A backtracking line search halves the step until ``phi`` decreases; iteration stops when the
relative residual ``||r|| / ||v_target / w||`` falls below ``tolerance``, when no step lowers
``phi`` or lowers it by less than ``stagnation`` (relative), or after ``max_iterations``.
``|d|`` is clipped to ``max_log_contrast`` so the output stays bounded and finite even for a
silver mesh (~zero resistance).

Channels can be left out (saturated, faulty electrode, NaN): the data term then runs over the
other rows only (rows of ``C_w`` and of ``r``), with ``lambda^2 = h^2 trace(K_used)/M_used``
and its own first factorisation, cached per excluded set - the one-step rule
(:meth:`eit_skin.inverse.one_step.ReconstructionMatrix.without_channels`), so that with the
same prior and ``h`` the first Gauss-Newton step *is* the one-step image on those channels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.dual_form import lambda_squared
from eit_skin.inverse.one_step import (
    channel_subset,
    coarse_to_fine,
    reference_scale,
    relative_difference,
)
from eit_skin.inverse.priors import Prior, make_prior

DEFAULT_MAX_LOG_CONTRAST = float(np.log(1e5))
#: Online convergence test: stop when the next step changes no ``ln sigma`` by more than this
#: fraction of the image's largest ``|ln sigma|`` (1 % of its peak, for any contrast), well
#: inside the 5 % agreement asked of the online path.
DEFAULT_STEP_TOLERANCE = 0.01
#: Online quasi-Newton: keep a linearisation until the solution moved this far from it (max
#: ``|ln sigma|`` change, i.e. a factor e^0.5 = 1.65 of some element's conductance).
DEFAULT_RELINEARISE = 0.5
_LINE_SEARCH_HALVINGS = 12


@dataclass(frozen=True)
class GaussNewtonResult:
    """Outcome of a fit (:meth:`GaussNewtonSolver.fit`, :meth:`GaussNewtonSolver.difference`).

    Attributes:
        sigma: ``[N]`` sheet conductance on the forward mesh, siemens.
        relative_change: ``[N]`` ``sigma / sigma0 - 1`` on the forward mesh (positive = more
            conductive).
        iterations: Gauss-Newton steps taken.
        relative_residuals: ``[iterations + 1]`` history of ``||r|| / ||v_target / w||``
            (:meth:`GaussNewtonSolver.difference`: ``||r|| / ||r_0||``, relative to the
            measured change), on the channels used.
        converged: True when the residual tolerance was met.
        parameter_change: ``[N_p]`` ``sigma / sigma0 - 1`` per parameter-mesh element.
        forward_solves: forward solves at new conductances (line-search trials included).
        linearisations: Jacobians (and normal matrices) computed; the one at ``sigma0`` is
            prepared once and not counted.
    """

    sigma: np.ndarray
    relative_change: np.ndarray
    iterations: int
    relative_residuals: np.ndarray
    converged: bool
    parameter_change: np.ndarray
    forward_solves: int
    linearisations: int = 0


@dataclass(frozen=True, eq=False)
class _Linearisation:
    """One linearisation of the data term: where, ``G^T``, ``P^-1 G^T``, Cholesky factor.

    Attributes:
        d: ``[N_p]`` log-conductance change it was taken at.
        gt: ``[N_p, P]`` ``(G diag(sigma) C)^T``.
        z: ``[N_p, P]`` ``P^-1 G^T``.
        factor: Cholesky factor of ``J P^-1 J^T + lambda^2 I`` on the fit's channels.
    """

    d: np.ndarray
    gt: np.ndarray
    z: np.ndarray
    factor: tuple[np.ndarray, bool]


@dataclass(eq=False)
class WarmStart:
    """The last fit's end point, where the next frame's fit starts (online Gauss-Newton).

    Filled by :meth:`GaussNewtonSolver.difference` when passed; empty (``d is None``) it
    gives a cold start from ``sigma0``. Valid for one channel set: a fit on other channels
    starts cold and replaces it.

    Attributes:
        channels: bytes of the used channel indices (``b""``: all channels).
        d: ``[N_p]`` log-conductance change of the last solution, or ``None``.
        voltages: ``[M]`` model volts at ``d`` (no forward solve to restart there).
        linearisation: the last linearisation kept (quasi-Newton steps reuse it), or None.
    """

    channels: bytes = b""
    d: np.ndarray | None = None
    voltages: np.ndarray | None = None
    linearisation: _Linearisation | None = None

    def reset(self) -> None:
        """Forget the last solution: the next fit starts from ``sigma0``."""
        self.channels, self.d, self.voltages, self.linearisation = b"", None, None, None


class _LineSearch(NamedTuple):
    """A line search's outcome: forward solves, the accepted point (None: no decrease)."""

    solves: int
    d: np.ndarray | None
    sigma: np.ndarray | None
    residual: np.ndarray | None
    voltages: np.ndarray | None
    damped: bool
    gain: float
    objective: float


@dataclass(frozen=True)
class FitOptions:
    """When a fit stops and what it reuses (:meth:`GaussNewtonSolver.difference` says each).

    Attributes:
        max_iterations: Gauss-Newton steps at most.
        tolerance: stop at this relative residual.
        stagnation: stop when a step lowers the objective by less than this (relative).
        step_tolerance: online convergence test on the next step (0: off).
        relinearise: keep a linearisation until the solution moved this far (0: never).
    """

    max_iterations: int = 10
    tolerance: float = 1e-3
    stagnation: float = 1e-9
    step_tolerance: float = 0.0
    relinearise: float = 0.0


class GaussNewtonSolver:
    """Regularised Gauss-Newton around one ``sigma0``, reusable for many targets or frames.

    Everything that does not depend on the data is prepared once: the parameter map, the
    factorised prior, the weighted combination ``C_w``, ``lambda^2`` and the whole first
    linearisation at ``sigma0`` (``G^T``, ``P^-1 G^T`` and the Cholesky factor of
    ``J P^-1 J^T + lambda^2 I``), so the first step of every fit costs two triangular solves
    and a forward solve. The data scale ``w`` (:attr:`weights_v`) is fixed: the floored
    ``|F(sigma0)|`` (the one-step convention, :func:`eit_skin.inverse.one_step.reference_scale`);
    ``|ln(sigma / sigma0)|`` is bounded by :data:`DEFAULT_MAX_LOG_CONTRAST`.

    Args:
        forward: model with ``.voltages(sigma)``, ``.jacobian_basis(sigma)`` (or
            ``.jacobian``), ``.mesh``, ``.n_measurements``.
        sigma0: starting and prior conductance, siemens, scalar or ``[N]`` (forward mesh).
        prior: prior kind or a built :class:`Prior` on the parameter mesh.
        hyperparameter: dimensionless ``h``.
        parameter_mesh: coarser mesh of the same sheet carrying the unknowns (default: the
            forward mesh).
    """

    def __init__(
        self,
        forward: Any,
        sigma0: np.ndarray | float,
        prior: str | Prior = "laplace",
        hyperparameter: float = 0.03,
        parameter_mesh: Mesh | None = None,
    ) -> None:
        if not (np.isfinite(hyperparameter) and hyperparameter > 0):
            raise ValueError(f"hyperparameter must be a positive number, got {hyperparameter}")
        self.forward = forward
        n = forward.mesh.n_triangles
        self.sigma0 = np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (n,)).copy()
        self.v0 = np.asarray(forward.voltages(self.sigma0), dtype=np.float64)  # [M] volts
        self.weights_v = reference_scale(self.v0)  # [M] volts, the data scale w
        self.max_log_contrast = DEFAULT_MAX_LOG_CONTRAST
        self._owner, self._to_params = _parameter_map(forward.mesh, parameter_mesh)
        self.n_parameters = n if self._owner is None else parameter_mesh.n_triangles  # type: ignore[union-attr]
        if isinstance(prior, Prior) and prior.n != self.n_parameters:
            raise ValueError(
                f"prior has {prior.n} elements, the parameter mesh {self.n_parameters}"
            )
        products, combination = _jacobian_factors(forward, self.sigma0)
        self._cw = sp.csr_matrix(combination.multiply(1.0 / self.weights_v[:, None]))
        gt = _parameter_jacobian(products, self.sigma0, self._to_params)
        if isinstance(prior, Prior):
            self.prior = prior
        else:
            j = np.asarray(self._cw @ gt.T) if prior == "noser" else None
            self.prior = make_prior(prior, parameter_mesh or forward.mesh, j)
        self.hyperparameter = float(hyperparameter)
        z, k = self._normal_matrix(gt, self._cw)
        self._first = (gt, z, k)  # the linearisation at sigma0, K not yet regularised
        self._all = self._channel_set(None)
        self.lam2 = self._all.lam2
        # no channel excluded: the full set
        self._subsets = {np.zeros(self.v0.size, dtype=bool).tobytes(): self._all}

    # ------------------------------------------------------------------ pieces
    def _normal_matrix(self, gt: np.ndarray, cw: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
        """``(P^-1 G^T [N_p, P], J P^-1 J^T [Mu, Mu])`` for ``G^T`` ``[N_p, P]``, rows ``cw``."""
        z = self.prior.solve(gt)
        kg = gt.T @ z
        kg = 0.5 * (kg + kg.T)
        return z, np.asarray(cw @ np.asarray(cw @ kg).T)

    def _channel_set(self, keep: np.ndarray | None) -> _ChannelSet:
        """The data rows ``keep`` (``None``: all) with their ``lambda^2`` and first factor."""
        k = self._first[2]
        cw = self._cw
        if keep is not None:
            k, cw = k[np.ix_(keep, keep)], sp.csr_matrix(cw[keep])
        lam2 = lambda_squared(self.hyperparameter, float(np.trace(k)), k.shape[0])
        return _ChannelSet(keep, cw, lam2, _cholesky(k.copy(), lam2))

    def _channels(self, excluded: np.ndarray | None) -> _ChannelSet:
        """The channel set without ``excluded`` (bool ``[M]``); cached per pattern."""
        if excluded is None:
            return self._all
        return channel_subset(excluded, self.v0.size, self._subsets, self._channel_set)

    def _fine_sigma(self, d: np.ndarray) -> np.ndarray:
        return self.sigma0 * np.exp(d if self._owner is None else d[self._owner])

    # ------------------------------------------------------------------ fits
    def fit(
        self,
        v_target: np.ndarray,
        max_iterations: int = 10,
        tolerance: float = 1e-3,
        stagnation: float = 1e-9,
        excluded: np.ndarray | None = None,
    ) -> GaussNewtonResult:
        """Fit ``F(sigma)`` to ``v_target`` ``[M]`` volts, starting from ``sigma0``.

        ``excluded``: optional bool ``[M]``, channels left out of the data term (their
        ``v_target`` may be NaN); every other channel must be finite. ``tolerance`` is on
        ``||r|| / ||v_target / w||``.
        """
        options = FitOptions(max_iterations, tolerance, stagnation)
        return self._fit(v_target, excluded, False, options)

    def _fit(
        self,
        v_target: np.ndarray,
        excluded: np.ndarray | None,
        relative_to_change: bool,
        options: FitOptions,
        warm: WarmStart | None = None,
    ) -> GaussNewtonResult:
        """The fit of :meth:`fit` and :meth:`difference`.

        ``relative_to_change``: the tolerance is on the change from ``F(sigma0)`` (no change:
        no iteration).
        """
        v_target = np.asarray(v_target, dtype=np.float64)
        if v_target.shape != self.v0.shape:
            raise ValueError(f"v_target must be finite [{self.v0.size}] volts")
        channels = self._channels(excluded)
        rows = slice(None) if channels.keep is None else channels.keep
        w = self.weights_v[rows]
        target = v_target[rows] / w
        if not np.isfinite(target).all():
            raise ValueError(f"v_target must be finite [{self.v0.size}] volts")
        change = target - self.v0[rows] / w
        norm = float(np.linalg.norm(change if relative_to_change else target)) or 1.0
        key = b"" if channels.keep is None else channels.keep.tobytes()
        moved = bool(np.any(change)) if relative_to_change else True
        if warm is not None and warm.channels == key and warm.d is not None and moved:
            d, model_v, lin = warm.d, warm.voltages, warm.linearisation
            sig = self._fine_sigma(d)
            resid = target - model_v[rows] / w
        else:
            gt, z, _ = self._first
            d, sig, resid = np.zeros(self.n_parameters), self.sigma0, change
            model_v, lin = self.v0, _Linearisation(d, gt, z, channels.first_factor)
        history = [float(np.linalg.norm(resid)) / norm]
        converged = history[0] <= options.tolerance
        solves, it, linearisations = 0, 0, 0
        relinearise = options.relinearise
        while not converged and it < options.max_iterations:
            stale = lin is not None and (
                (relinearise <= 0.0 and lin.d is not d)
                or float(np.max(np.abs(d - lin.d), initial=0.0)) > relinearise
            )
            if lin is None or stale:
                lin = self._linearise(d, sig, channels)
                linearisations += 1
            u = sla.cho_solve(lin.factor, resid + channels.cw @ (d @ lin.gt), check_finite=False)
            step = lin.z @ (channels.cw.T @ u) - d
            tol = options.step_tolerance
            if tol > 0.0 and float(np.max(np.abs(step))) <= tol * float(np.max(np.abs(d + step))):
                converged = True  # the next step would change the image by < tol of its peak
                break
            it += 1
            search = self._line_search(d, step, resid, lin, (target, rows, w, channels.lam2))
            solves += search.solves
            if search.d is None:
                if lin.d is not d:  # a kept linearisation failed: take a fresh one here
                    lin = None
                    it -= 1
                    continue
                break
            if search.damped and relinearise > 0.0:
                lin = None  # the model needed damping: do not keep it
            d, sig, resid, model_v = search.d, search.sigma, search.residual, search.voltages
            history.append(float(np.linalg.norm(resid)) / norm)
            converged = history[-1] <= options.tolerance
            if search.gain <= options.stagnation * search.objective:  # no progress left
                break
        if warm is not None:
            warm.channels, warm.d, warm.voltages, warm.linearisation = key, d, model_v, lin
        return GaussNewtonResult(
            sigma=sig,
            relative_change=sig / self.sigma0 - 1.0,
            iterations=it,
            relative_residuals=np.asarray(history),
            converged=converged,
            parameter_change=np.expm1(d),
            forward_solves=solves,
            linearisations=linearisations,
        )

    def _line_search(
        self,
        d: np.ndarray,
        step: np.ndarray,
        resid: np.ndarray,
        lin: _Linearisation,
        data: tuple[np.ndarray, Any, np.ndarray, float],
    ) -> _LineSearch:
        """Halve ``step`` from ``d`` until the objective decreases (at most 12 halvings).

        ``data``: ``(target [Mu], rows, w [Mu] V, lambda^2)`` of the fit. A kept
        linearisation (``lin.d is not d``) gets the full step only.
        """
        target, rows, w, lam2 = data
        objective = float(resid @ resid) + lam2 * self.prior.quadratic(d)
        alpha = 1.0
        for solves in range(1, _LINE_SEARCH_HALVINGS + 1):
            trial = np.clip(d + alpha * step, -self.max_log_contrast, self.max_log_contrast)
            sig_trial = self._fine_sigma(trial)
            v_trial = self.forward.voltages(sig_trial)
            r_trial = target - v_trial[rows] / w
            phi_trial = float(r_trial @ r_trial) + lam2 * self.prior.quadratic(trial)
            if np.isfinite(phi_trial) and phi_trial < objective:
                gain = objective - phi_trial
                return _LineSearch(
                    solves, trial, sig_trial, r_trial, v_trial, alpha < 1.0, gain, objective
                )
            if lin.d is not d:
                break
            alpha *= 0.5
        return _LineSearch(solves, None, None, None, None, True, 0.0, objective)

    def _linearise(self, d: np.ndarray, sig: np.ndarray, channels: _ChannelSet) -> _Linearisation:
        """Jacobian, prior solves and Cholesky factor at ``d`` (forward mesh ``sig``)."""
        products, _ = _jacobian_factors(self.forward, sig)  # cached factorisation of sig
        gt = _parameter_jacobian(products, sig, self._to_params)
        z, k = self._normal_matrix(gt, channels.cw)
        return _Linearisation(d, gt, z, _cholesky(k, channels.lam2))

    def difference(
        self,
        frame: np.ndarray,
        reference: np.ndarray,
        excluded: np.ndarray | None = None,
        options: FitOptions = FitOptions(),
        warm: WarmStart | None = None,
    ) -> GaussNewtonResult:
        """Difference imaging: fit ``F(sigma0) + s(F(sigma0)) (v - v_ref) / s_ref``.

        The measured relative change is applied to the model's reference voltages, so an
        unknown gain or absolute conductance cancels as in one-step imaging. Channels where
        ``excluded`` (bool ``[M]``) is True or that are NaN/Inf in the frame or reference
        are left out of the fit (own ``lambda^2`` and factorisation per excluded set, as the
        one-step matrix does). ``tolerance`` is relative to the measured change: the fit
        stops when ``||r|| <= tolerance * ||r_0||`` (``r_0`` the data change itself), so a
        small touch is imaged as fully as a large one, and no change gives no iteration.

        ``options`` (:class:`FitOptions`): ``max_iterations``, ``tolerance``, ``stagnation``,
        and the online options (their defaults give the plain cold Gauss-Newton fit):

        * ``warm`` (an argument of its own): start from the last fit's solution and model
          voltages (no forward solve to get there) and store this fit's end point in it; a
          different channel set, or a frame with no change at all, starts cold from
          ``sigma0``.
        * ``step_tolerance``: convergence test on the Gauss-Newton step: stop, without a
          forward solve, when the next step would change no element's ``ln sigma`` by more
          than this fraction of the largest ``|ln sigma|`` of the image (0.01: 1 % of its
          peak, whatever the contrast).
        * ``relinearise``: keep a linearisation (Jacobian, prior solves, Cholesky factor)
          for the following steps (quasi-Newton with a fixed Jacobian) until the solution
          has moved more than this from where it was taken (max ``|ln sigma|`` change), the
          full step fails to lower the objective or needed damping; 0: a new
          linearisation at every step (Gauss-Newton).
        """
        dv = relative_difference(frame, reference)
        bad = ~np.isfinite(dv)
        if excluded is not None:
            bad = bad | np.asarray(excluded, dtype=bool)
        target = self.v0 + reference_scale(self.v0) * np.where(bad, 0.0, dv)
        return self._fit(target, bad if bad.any() else None, True, options, warm)


@dataclass(frozen=True, eq=False)
class _ChannelSet:
    """The data rows of one fit: a channel subset, its ``lambda^2`` and first Cholesky factor.

    Attributes:
        keep: ``[M_used]`` int64 channel indices, or ``None`` for all channels.
        cw: ``[M_used, P]`` sparse weighted combination ``C_w`` on those rows.
        lam2: ``h^2 trace(K_used) / M_used`` at the first linearisation.
        first_factor: Cholesky factor of ``K_used + lambda^2 I`` at ``sigma0``.
    """

    keep: np.ndarray | None
    cw: sp.csr_matrix
    lam2: float
    first_factor: tuple[np.ndarray, bool]


def _cholesky(k: np.ndarray, lam2: float) -> tuple[np.ndarray, bool]:
    """Cholesky factor of ``K + lambda^2 I`` (overwrites ``k``)."""
    k[np.diag_indices_from(k)] += lam2
    return sla.cho_factor(k, lower=True, check_finite=False)


def _parameter_map(
    fine: Mesh, parameter_mesh: Mesh | None
) -> tuple[np.ndarray | None, sp.csr_matrix | None]:
    """``(owner [N], C^T [N_p, N] CSR)``: the parameter-mesh element of each forward element.

    ``(None, None)`` when the unknowns live on the forward mesh itself. A parameter element
    that owns no forward element (a boundary sliver) has a zero Jacobian column: the data
    never move it and the prior keeps it at (or smooths it towards) its neighbours.
    """
    if parameter_mesh is None or parameter_mesh is fine:
        return None, None
    c = coarse_to_fine(fine, parameter_mesh)  # [N, N_p], one 1 per row
    owner = c.indices.astype(np.int64)
    if owner.size != fine.n_triangles:
        raise ValueError("parameter mesh: every forward element needs exactly one owner")
    return owner, sp.csr_matrix(c.T)


def _parameter_jacobian(
    products: np.ndarray, sigma: np.ndarray, to_params: sp.csr_matrix | None
) -> np.ndarray:
    """``[N_p, P]`` ``(G diag(sigma) C)^T`` (C-contiguous), ``G`` = ``products`` ``[P, N]``."""
    if to_params is None:
        return np.ascontiguousarray((products * sigma[None, :]).T)
    weighted = sp.csr_matrix(
        (sigma[to_params.indices], to_params.indices, to_params.indptr), shape=to_params.shape
    )
    return np.asarray(weighted @ products.T)


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
