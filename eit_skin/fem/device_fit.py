"""Calibrate the forward model to a device: sheet conductance and contact impedance.

A no-load (object-free) frame ``v`` [M] of the device is fitted by the homogeneous CEM model
``gain * V(sigma, z)`` (:class:`~eit_skin.fem.forward.ForwardModel`): the sheet conductance
``sigma`` (S) and the contact impedance ``z`` (ohm*m), one common value or one per electrode,
by Levenberg-Marquardt on the logarithms (both stay positive), the residual relative to the
frame's rms.

What one frame can tell apart (the choices made here):

* ``gain`` and ``sigma`` cannot both be fitted: ``V(c sigma, z / c) = V(sigma, z) / c``, so
  ``gain / sigma`` and ``sigma z`` are all a homogeneous frame fixes. The gain is given
  (default 1: the frames are volts) and ``sigma`` is fitted; a board in other units gives
  its gain (volts per count), or reads the fitted ``sigma`` as ``sigma_true / gain``.
  :attr:`DeviceFit.gain_at` gives the gain that the patch's own conductance implies.
* A per-electrode ``z`` is fitted when the protocol measures on current-carrying electrodes
  (``measure_driven``, trigonometric patterns, full frames with the driven pairs): there
  ``z_l`` adds ``I z_l / width`` to the measured voltage. Without such measurements ``z_l``
  only acts through the weak shunting of the electrodes, and one common ``z`` is fitted
  (``per_electrode=True`` forces the per-electrode fit; its spread is then weakly
  determined).
* Where the data do not determine a ``z`` (its linearised log standard error at the fit's
  residual exceeds :data:`UNDETERMINED_LOG_STD`: on real tanks measured without the driven
  electrodes, the common ``z`` runs off to "no shunting" for a fraction of a percent of
  residual), it keeps its starting value and the rest is refitted; the report says so.
* The board's input gain mismatch (``fit_input_gain``: the minus input's gain ``g`` over the
  plus input's, :mod:`eit_skin.patch.protocol`): with the inputs referred to the sink, a
  homogeneous frame determines it (``g != 1`` leaks a common-mode voltage that grows towards
  the source, a shape ``sigma`` and ``z`` cannot make); fitted from the no-load frame only, as
  a device calibration, never from loads. Pair drives only.
* Bad contact: an electrode whose fitted ``z`` exceeds :data:`BAD_CONTACT_RATIO` times the
  median, or whose channels' rms residual exceeds :data:`BAD_CONTACT_RATIO` times the median
  over the electrodes (a scale-free rule: the same on any board and in any unit).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from eit_skin.fem.elements import TankDepth
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import Mesh
from eit_skin.patch.protocol import Protocol

#: An electrode is reported as a bad contact above this multiple of the median (z or residual).
BAD_CONTACT_RATIO = 3.0
#: Levenberg-Marquardt stops when a step improves the residual by less than this fraction.
RELATIVE_TOLERANCE = 1e-6
#: Steps of the logarithm of a parameter are limited to this (a factor e^2 ~ 7.4 per step).
MAX_LOG_STEP = 2.0
#: Starting values of a fitted negative input gain tried (a mismatch beyond a factor 2 between
#: the two inputs of one amplifier would be a fault, not a calibration).
INPUT_GAIN_GRID = np.geomspace(0.5, 2.0, 41)
#: A contact impedance whose log standard error exceeds this (a factor e) is not determined.
UNDETERMINED_LOG_STD = 1.0
#: Depths :func:`fit_depth` tries first, times the sheet's largest extent (beyond ~4 extents
#: a deeper tank changes the frame by less than the model's discretisation).
DEPTH_GRID = np.geomspace(1 / 16, 4.0, 7)
#: Golden-section steps after the grid (each narrows the bracket by 0.618).
DEPTH_REFINEMENTS = 6


@dataclass(frozen=True)
class DeviceFit:
    """Result of :func:`fit_device`.

    Attributes:
        sheet_conductance_s: fitted homogeneous sheet conductance, S (for the given gain).
        contact_impedance_ohm_m: ``[n_el]`` fitted contact impedance, ohm*m.
        gain: the gain the fit assumed (frame units per volt).
        negative_input_gain: the minus input's gain over the plus input's (fitted when asked,
            else the protocol's).
        per_electrode: whether ``z`` was fitted per electrode (else one common value).
        residual: rms of ``gain * V - v`` over the used channels / rms of ``v``.
        initial_residual: the same before the fit (the patch's values, best scale).
        electrode_residual: ``[n_el]`` rms relative residual of the channels touching each
            electrode (drive or measure), same normalisation as ``residual``.
        bad_contacts: electrodes flagged by the module's rule, increasing.
        used: bool ``[M]`` channels fitted (finite, non-zero).
        iterations: Levenberg-Marquardt iterations done.
        contact_determined: bool ``[n_el]``: whether the frame determines each electrode's
            ``z`` (else it is the starting value, scaled with the conductance).
        contact_ratio: ``[n_el]`` ``z sigma / width``, dimensionless: the contact's resistance
            ``z / width`` against the sheet's ``1 / sigma``; >> 1: contact-dominated
            (uniform current under the electrode, the gap model), << 1: a shunting electrode.
    """

    sheet_conductance_s: float
    contact_impedance_ohm_m: np.ndarray
    gain: float
    negative_input_gain: float
    per_electrode: bool
    residual: float
    initial_residual: float
    electrode_residual: np.ndarray
    bad_contacts: tuple[int, ...]
    used: np.ndarray
    iterations: int
    contact_determined: np.ndarray
    contact_ratio: np.ndarray

    def gain_at(self, sheet_conductance_s: float) -> float:
        """Gain (frame units per volt) that makes ``sheet_conductance_s`` S fit the frame."""
        return self.gain * sheet_conductance_s / self.sheet_conductance_s

    def lines(self) -> list[str]:
        """Human-readable report, one fact per line."""
        z = self.contact_impedance_ohm_m
        zs = (
            f"contact impedance per electrode: {', '.join(f'{v:.3g}' for v in z)} ohm*m"
            if self.per_electrode
            else f"contact impedance (common): {z[0]:.4g} ohm*m"
        )
        if not self.contact_determined.all():
            which = (
                ", ".join(map(str, np.flatnonzero(~self.contact_determined)))
                if self.per_electrode
                else "all"
            )
            zs += (
                f" (not determined by this frame, kept at the patch's value x the conductance's "
                f"scale: electrodes {which})"
            )
        bad = ", ".join(map(str, self.bad_contacts)) or "none"
        ratio = float(np.median(self.contact_ratio))
        kind = "contact-dominated" if ratio > 1 else "shunting electrodes"
        return [
            f"sheet conductance: {self.sheet_conductance_s:.4g} S (gain {self.gain:g})",
            zs,
            f"negative input gain: {self.negative_input_gain:.4g} (minus input over plus input)",
            f"z sigma / width: median {ratio:.3g} ({kind})",
            f"fit residual: {self.residual:.3%} of the frame's rms "
            f"(before: {self.initial_residual:.3%}), {self.iterations} iterations, "
            f"{int(self.used.sum())} channels",
            f"bad contact (> {BAD_CONTACT_RATIO:g} x median z or channel residual): {bad}",
        ]


def measures_driven(protocol: Protocol) -> bool:
    """Whether any measurement uses an electrode that carries current in its injection."""
    k, p, q = protocol.measurements.T
    currents = protocol.current_patterns[k]
    rows = np.arange(k.size)
    return bool(np.any((currents[rows, p] != 0) | (currents[rows, q] != 0)))


def fit_device(
    mesh: Mesh,
    protocol: Protocol,
    reference: np.ndarray,
    sheet_conductance_s: float,
    contact_impedance_ohm_m: float | np.ndarray,
    current_a: float,
    *,
    gain: float = 1.0,
    magnitude: bool = False,
    per_electrode: bool | None = None,
    fit_input_gain: bool = False,
    max_iterations: int = 40,
    depth: TankDepth | None = None,
) -> DeviceFit:
    """Fit ``sigma`` and ``z`` to a no-load frame (see the module docstring).

    Args:
        mesh: the forward mesh of the sheet.
        protocol: its protocol (``M`` channels).
        reference: ``[M]`` no-load frame in frame units (``gain`` per volt).
        sheet_conductance_s: starting sheet conductance, S (the patch's).
        contact_impedance_ohm_m: starting ``z``, scalar or ``[n_el]``, ohm*m.
        current_a: injected current amplitude, A.
        gain: frame units per volt (> 0).
        magnitude: the frame holds ``|V|`` (magnitude boards): the model's magnitudes are fitted.
        per_electrode: one ``z`` per electrode; None: when :func:`measures_driven`.
        fit_input_gain: fit the board's ``negative_input_gain`` too (starting from the
            protocol's; pair drives only).
        max_iterations: Levenberg-Marquardt iterations at most.
        depth: a tank's depth and electrode height (None: a 2-D sheet), held fixed.

    Raises:
        ValueError: a frame of the wrong shape, too few usable channels, or a frame whose
            sign is opposite to the model's (wrong ``protocol.sign`` or numbering).
    """
    v = np.asarray(reference, dtype=np.float64)
    n_el = mesh.n_electrodes
    if per_electrode is None:
        per_electrode = measures_driven(protocol)
    n_par = 1 + (n_el if per_electrode else 1) + int(fit_input_gain)
    used = _usable_channels(v, protocol.n_measurements, gain, n_par)
    z = np.broadcast_to(np.asarray(contact_impedance_ohm_m, dtype=np.float64), (n_el,)).copy()
    if not per_electrode:
        z[:] = np.exp(np.mean(np.log(z)))
    rms = float(np.sqrt(np.mean(v[used] ** 2)))
    options = (gain, magnitude, per_electrode, fit_input_gain, depth)
    frame = _FrameResidual(mesh, protocol, current_a, v, used, rms, *options)
    start, initial = frame.start(float(sheet_conductance_s), z, protocol.negative_input_gain)
    free = np.ones(n_par, dtype=bool)
    sigma, z, g, r, J, iterations = _levenberg_marquardt(frame, start, free, max_iterations)
    # where the data allow: a contact impedance the frame barely depends on (its log
    # standard error above UNDETERMINED_LOG_STD at the fit's own residual) wanders off to
    # where it no longer matters; such values are kept at their start and the rest refitted
    contacts = slice(1, n_par - int(fit_input_gain))
    determined = _log_std(J, r)[contacts] <= UNDETERMINED_LOG_STD
    if not determined.all():
        free[contacts] = determined
        sigma, z, g, r, J, more = _levenberg_marquardt(frame, start, free, max_iterations)
        iterations += more
    cost = float(r @ r)
    electrode_residual = _electrode_residual(protocol, used, r)
    bad = electrode_residual > BAD_CONTACT_RATIO * np.nanmedian(electrode_residual)
    if per_electrode:
        bad |= z > BAD_CONTACT_RATIO * np.median(z)
    return DeviceFit(
        sheet_conductance_s=sigma,
        contact_impedance_ohm_m=z,
        gain=float(gain),
        negative_input_gain=float(g),
        per_electrode=bool(per_electrode),
        residual=float(np.sqrt(cost / used.sum())),
        initial_residual=initial,
        electrode_residual=electrode_residual,
        bad_contacts=tuple(int(e) for e in np.flatnonzero(bad)),
        used=used,
        iterations=iterations,
        contact_determined=np.broadcast_to(determined, (n_el,)).copy(),
        contact_ratio=z * sigma / _electrode_lengths(mesh),
    )


@dataclass(frozen=True, eq=False)
class _FrameResidual:
    """The misfit of the model to a no-load frame, scaled by the frame's rms.

    ``v`` ``[M]`` is the frame (frame units), ``used`` ``[M]`` its usable channels, ``rms``
    their rms; the other fields are the arguments of :func:`fit_device`.
    """

    mesh: Mesh
    protocol: Protocol
    current_a: float
    v: np.ndarray
    used: np.ndarray
    rms: float
    gain: float
    magnitude: bool
    per_electrode: bool
    fit_input_gain: bool = False
    depth: TankDepth | None = None

    def __post_init__(self) -> None:
        if self.fit_input_gain and not self.protocol.pair_drive:
            raise ValueError("fit_input_gain: needs a pair drive (the inputs' ground is the sink)")

    def model(self, z: np.ndarray, g: float, sigma: float) -> ForwardModel:
        """The forward model at contact impedance ``z`` and negative input gain ``g``.

        A tank is homogeneous: ``sigma`` outside the imaged slab too.
        """
        depth = None if self.depth is None else replace(self.depth, outside_s=sigma)
        return ForwardModel(
            self.mesh, replace(self.protocol, negative_input_gain=g), z, self.current_a, depth
        )

    def evaluate(
        self, sigma: float, z: np.ndarray, g: float, jacobian: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Residual ``[m]`` on the used channels and, when ``jacobian``, its derivative.

        The derivative ``[m, n_par]`` is by ``log sigma``, ``log z`` (one column, or one
        per electrode) and, when fitted, ``log g``.
        """
        model = self.model(z, g, sigma)
        solution = model.solve(sigma)
        V = solution.voltages
        sign = np.sign(V) if self.magnitude else np.ones_like(V)
        r = (self.gain * sign * V - self.v)[self.used] / self.rms
        if not jacobian:
            return r, None
        dz = model.contact_jacobian(sigma) * z[None, :]  # dV / dlog z_l
        dsigma = -V + dz.sum(axis=1)  # dV / dlog sigma (the scaling law)
        cols = [dsigma[:, None], dz if self.per_electrode else dz.sum(axis=1, keepdims=True)]
        if self.fit_input_gain:  # dV / dlog g = -g (V(minus) - V(sink))
            u = solution.electrode_potentials
            k, _, minus = self.protocol.measurements.T
            sink = self.protocol.injections[k, 1]
            cols.append((-g * (u[k, minus] - u[k, sink]))[:, None])
        return r, (self.gain * sign[:, None] * np.hstack(cols))[self.used] / self.rms

    def start(
        self, sigma: float, z: np.ndarray, g: float
    ) -> tuple[tuple[float, np.ndarray, float, np.ndarray, np.ndarray], float]:
        """(the fit's start ``(sigma, z, g, r, J)``, the residual at the given values).

        At the best common scale; a fitted gain starts from the best of a grid (the misfit
        is not smooth in ``g`` where channels cross zero).
        """
        sigma, z = self.common_scale(sigma, z, g)
        r, J = self.evaluate(sigma, z, g, True)
        initial = float(np.sqrt(np.mean(r**2)))
        if self.fit_input_gain:
            g = self.best_gain(sigma, z, g)
            sigma, z = self.common_scale(sigma, z, g)
            r, J = self.evaluate(sigma, z, g, True)
        return (sigma, z.copy(), g, r, J), initial

    def best_gain(self, sigma: float, z: np.ndarray, g: float) -> float:
        """The gain of :data:`INPUT_GAIN_GRID` or ``g`` that fits best at a common scale.

        ``sigma`` and ``z`` as given; one solve (the reading is linear in the gain).
        """
        u = self.model(z, 1.0, sigma).solve(sigma).electrode_potentials
        k, plus, minus = self.protocol.measurements.T
        sink = self.protocol.injections[k, 1]
        a, b = u[k, plus] - u[k, sink], u[k, minus] - u[k, sink]  # [M]
        gains = np.append(INPUT_GAIN_GRID, g)
        shape = self.gain * (a[None, :] - gains[:, None] * b[None, :])[:, self.used]  # [G, m]
        if self.magnitude:
            shape = np.abs(shape)
        v = self.v[self.used]
        scale = np.maximum(shape @ v / np.einsum("gm,gm->g", shape, shape), 0.0)
        misfit = ((scale[:, None] * shape - v) ** 2).sum(axis=1)
        return float(gains[np.argmin(misfit)])

    def common_scale(self, sigma: float, z: np.ndarray, g: float) -> tuple[float, np.ndarray]:
        """``(sigma / c, z c)`` for the best common scale ``c`` (it keeps the shape).

        Fitted first, so a wrong unit or conductance does not have to be walked off by the
        iteration.
        """
        V = self.model(z, g, sigma).voltages(sigma)
        shape = self.gain * (np.abs(V) if self.magnitude else V)
        used, v = self.used, self.v
        c = float(shape[used] @ v[used] / (shape[used] @ shape[used]))
        if not c > 0:
            raise ValueError(
                "reference: its sign is opposite to the model's homogeneous voltages on most "
                "channels (check protocol.sign, electrode numbering, or values: magnitude)"
            )
        return sigma / c, z * c


def fit_depth(
    mesh: Mesh, protocol: Protocol, reference: np.ndarray, electrode_height_m: float, **options
) -> tuple[float | None, DeviceFit]:
    """The tank depth (m) that fits a no-load frame best, with its :func:`fit_device`.

    The conductance and the contact impedance are fitted jointly at every depth tried (the
    other arguments as :func:`fit_device`'s, ``options`` by keyword: ``sheet_conductance_s``,
    ``contact_impedance_ohm_m``, ``current_a`` required); the depth minimises the fit's
    residual: first over :data:`DEPTH_GRID` (multiples of the sheet's largest extent, from the
    electrode height, the 2-D sheet, up), then by :data:`DEPTH_REFINEMENTS` golden-section
    steps in ``log D`` between the best grid point's neighbours. None when the sheet (depth =
    the electrode height) fits best. Only the no-load frame is used: a device fact, as the
    contact impedance.
    """
    nodes = np.asarray(mesh.nodes, dtype=np.float64)
    extent = float(np.max(nodes.max(axis=0) - nodes.min(axis=0)))
    h = float(electrode_height_m)
    grid = np.unique(np.concatenate([[h], DEPTH_GRID * extent]))
    grid = grid[grid >= h]
    fits: dict[float, DeviceFit] = {}

    def residual(depth: float) -> float:
        if depth not in fits:
            tank = None if depth <= h * (1 + 1e-9) else TankDepth(depth, h)
            fits[depth] = fit_device(mesh, protocol, reference, depth=tank, **options)
        return fits[depth].residual

    best = int(np.argmin([residual(float(d)) for d in grid]))
    lo, hi = np.log(grid[max(best - 1, 0)]), np.log(grid[min(best + 1, len(grid) - 1)])
    ratio = (np.sqrt(5) - 1) / 2
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    for _ in range(DEPTH_REFINEMENTS):
        if residual(float(np.exp(a))) <= residual(float(np.exp(b))):  # minimum in [lo, b]
            hi, b = b, a
            a = hi - ratio * (hi - lo)
        else:  # in [a, hi]
            lo, a = a, b
            b = lo + ratio * (hi - lo)
    depth = min(fits, key=lambda d: fits[d].residual)
    return (None if depth <= h * (1 + 1e-9) else depth), fits[depth]


def _levenberg_marquardt(
    frame: _FrameResidual,
    start: tuple[float, np.ndarray, float, np.ndarray, np.ndarray],
    free: np.ndarray,
    max_iterations: int,
) -> tuple[float, np.ndarray, float, np.ndarray, np.ndarray, int]:
    """Minimise over the ``free`` log-parameters; ``(sigma, z, g, r, J, iterations)``.

    ``start`` is ``(sigma, z, g, r, J)`` (left unchanged).
    """
    sigma, z, g, r, J = start
    n_z = free.size - 1 - int(frame.fit_input_gain)
    z = z.copy()
    n_par = free.size
    cost = float(r @ r)
    damping = 1e-3
    done = 0
    for done in range(1, max_iterations + 1):  # noqa: B007 (returned)
        Jf = J[:, free]
        JtJ = Jf.T @ Jf
        gradient = Jf.T @ r
        improved = False
        while damping < 1e12:
            step_f = -np.linalg.solve(JtJ + damping * np.diag(np.diag(JtJ) + 1e-30), gradient)
            step_f *= min(1.0, MAX_LOG_STEP / max(np.abs(step_f).max(), 1e-300))
            step = np.zeros(n_par)
            step[free] = step_f
            new_sigma = sigma * float(np.exp(step[0]))
            new_z = z * np.exp(step[1 : 1 + n_z] if frame.per_electrode else step[1])
            new_g = g * float(np.exp(step[-1])) if frame.fit_input_gain else g
            r_new, _ = frame.evaluate(new_sigma, new_z, new_g, False)
            new_cost = float(r_new @ r_new)
            if new_cost < cost:
                improved = True
                damping = max(damping / 3, 1e-9)
                break
            damping *= 4
        if not improved:
            break
        fraction = (cost - new_cost) / max(cost, 1e-300)
        sigma, z, g, cost = new_sigma, new_z, new_g, new_cost
        r, J = frame.evaluate(sigma, z, g, True)
        if fraction < RELATIVE_TOLERANCE:
            break
    return sigma, z, g, r, J, done


def _usable_channels(v: np.ndarray, n_measurements: int, gain: float, n_par: int) -> np.ndarray:
    """``[M]`` bool: the finite, non-zero channels of ``v``, at least twice ``n_par`` of them."""
    if v.shape != (n_measurements,):
        raise ValueError(f"reference: expected [{n_measurements}] values, got {v.shape}")
    if not (np.isfinite(gain) and gain > 0):
        raise ValueError(f"gain: must be finite and > 0, got {gain}")
    used = np.isfinite(v) & (v != 0)
    if used.sum() < 2 * n_par:
        raise ValueError(
            f"reference: {int(used.sum())} usable channels for {n_par} parameters; "
            "need twice as many"
        )
    return used


def _electrode_residual(protocol: Protocol, used: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``[n_el]`` rms of the scaled residual ``r`` over the used channels at each electrode.

    NaN for an electrode no used channel touches.
    """
    full = np.zeros(used.shape)
    full[used] = r
    touching = np.stack([protocol.touching([e]) & used for e in range(protocol.n_electrodes)])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt((touching * full**2).sum(axis=1) / touching.sum(axis=1))


def _electrode_lengths(mesh: Mesh) -> np.ndarray:
    """``[n_el]`` length of each electrode along the boundary, m."""
    nodes = np.asarray(mesh.nodes, dtype=np.float64)
    return np.array(
        [
            np.linalg.norm(np.diff(nodes[np.asarray(e).reshape(-1, 2)], axis=1), axis=2).sum()
            for e in mesh.electrode_edges
        ]
    )


def _log_std(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Linearised standard error of each log-parameter at residual ``r`` (pseudo-inverse)."""
    dof = max(r.size - J.shape[1], 1)
    cov = np.linalg.pinv(J.T @ J) * float(r @ r) / dof
    return np.sqrt(np.maximum(np.diag(cov), 0.0))
