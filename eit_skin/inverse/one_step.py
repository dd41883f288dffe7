"""One-step difference imaging: a reconstruction matrix built once per layer.

Data convention (used everywhere in this package):
    The input of difference imaging is the *relative* voltage change per channel
    ``dv = (v - v_ref) / s_ref`` with ``s_ref = max(|v_ref|, floor * rms(v_ref))``
    (``floor`` = :data:`REFERENCE_FLOOR`, so near-zero channels do not blow up).
    The output is the relative conductivity change ``x = delta sigma / sigma0`` per
    element, positive where the sheet became more conductive. The model side is
    normalised the same way: ``J_rel[m, e] = J[m, e] * sigma0[e] / s0[m]`` with
    ``s0`` the floored model voltages at ``sigma0``. This cancels the unknown
    absolute sheet conductance, current amplitude and amplifier gain.

Solution of method ``one_step`` (linearised Gauss-Newton around the reference, dual form):
    ``x = P^-1 J^T (J P^-1 J^T + lambda^2 I)^-1 dv``
with ``P`` the sparse prior (:mod:`eit_skin.inverse.priors`). Only ``P^-1 J^T`` (``M``
sparse solves) and an ``M x M`` Cholesky factorisation are needed, so building scales
with ``N`` (elements), never ``N^3``. ``lambda^2 = h^2 * trace(J P^-1 J^T) / M`` so
the hyperparameter ``h`` is dimensionless and comparable between meshes
(:mod:`eit_skin.inverse.dual_form`).

Channel weights (:meth:`ReconstructionMatrix.with_channel_scale`): with measured relative noise
``Sigma = diag(s^2)`` (:mod:`eit_skin.inverse.channel_noise`) the solution is the weighted
least-squares one, ``x = Y (K + lambda^2 Sigma)^-1 dv`` =
``Y S^-1 (S^-1 K S^-1 + lambda^2 I)^-1 S^-1 dv``: the same dual form on the whitened
``K_w = S^-1 K S^-1``, ``Y_w = Y S^-1`` (``lambda^2`` from ``trace(K_w)``), so a new weighting
costs one ``M x M`` factorisation and never a Jacobian.

Method ``greit`` (:func:`eit_skin.inverse.greit.greit_matrix`) is the matrix trained on
simulated targets: the same dual form with ``K = Y Y^T`` and ``D Y^T`` in place of
``J P^-1 J^T`` and ``P^-1 J^T``; it has no prior.

Three steps, apart: building a method's dual-form pieces (:class:`PriorModel` here,
:class:`~eit_skin.inverse.greit.GreitModel`), choosing the hyperparameter on them
(:mod:`eit_skin.inverse.hyperparameter`, called by :func:`linear_matrix` and
:func:`assemble`) and solving with the matrix (:class:`ReconstructionMatrix`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from eit_skin.fem.image_grid import locate_points, proportional_columns
from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.dual_form import lambda_squared, regularised_inverse
from eit_skin.inverse.hyperparameter import choose_by_noise_figure, choose_for_gram
from eit_skin.inverse.priors import Prior, make_prior

REFERENCE_FLOOR = 1e-2
"""Channels whose reference is below this fraction of the RMS reference are normalised by it."""

#: SciPy's float32 ``gemv`` (``a @ u`` is ``_GEMV(1.0, a, u)``): the BLAS the compiled kernel
#: calls, so the numpy and compiled products agree bit for bit.
_GEMV = sla.get_blas_funcs("gemv", dtype=np.float32)

#: ``h`` of the matrix assembled before the noise-figure choice (which replaces it).
_PROVISIONAL_H = 0.05


def reference_floor(reference: np.ndarray) -> float:
    """``floor * rms(v_ref)`` (``rms`` 1 for an all-zero reference), volts: the least ``s_ref``.

    ``reference``: float64 ``[M]`` volts. One ``ddot``; not finite for a reference that is
    not (callers that need a finite floor check it). Shared by :func:`reference_scale` and
    the single-frame paths, which must give its numbers bit for bit.
    """
    ss = float(reference @ reference)
    return REFERENCE_FLOOR * (math.sqrt(ss / max(reference.size, 1)) or 1.0)


def reference_scale(reference: np.ndarray) -> np.ndarray:
    """Per-channel normalisation ``s_ref = max(|v_ref|, floor * rms(v_ref))``, ``[M]`` volts.

    Non-finite entries are ignored for the RMS and give ``nan``.
    """
    ref = np.asarray(reference, dtype=np.float64)
    if ref.ndim == 1 and np.isfinite(ref).all():  # the common case, once per frame in a node
        return np.maximum(np.abs(ref), reference_floor(ref))
    finite = np.isfinite(ref)
    rms = float(np.sqrt(np.mean(ref[finite] ** 2))) if finite.any() else 0.0
    if rms == 0.0:
        rms = 1.0
    with np.errstate(invalid="ignore"):
        return np.where(finite, np.maximum(np.abs(ref), REFERENCE_FLOOR * rms), np.nan)


def relative_difference(frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(v - v_ref) / s_ref`` for frames ``[M]`` or ``[T, M]`` volts; dimensionless."""
    with np.errstate(invalid="ignore"):
        return (np.asarray(frames, dtype=np.float64) - reference) / reference_scale(reference)


def coarse_to_fine(fine: Mesh, coarse: Mesh) -> sp.csr_matrix:
    """``[N_fine, N_coarse]`` 0/1 map: fine element -> coarse element containing its centroid.

    Fine centroids outside every coarse triangle (curved boundaries) go to the nearest
    coarse centroid.
    """
    owner = locate_points(coarse, fine.centroids)
    missing = owner < 0
    if missing.any():
        from scipy.spatial import cKDTree

        owner[missing] = cKDTree(coarse.centroids).query(fine.centroids[missing])[1]
    n = fine.n_triangles
    return sp.csr_matrix((np.ones(n), (np.arange(n), owner)), shape=(n, coarse.n_triangles))


def relative_jacobian(
    jacobian: np.ndarray, voltages: np.ndarray, sigma0: np.ndarray | float
) -> np.ndarray:
    """``J_rel = diag(1/s0) J diag(sigma0)``: ``[M, N]`` d(relative v)/d(relative sigma)."""
    s0 = reference_scale(voltages)
    sig = np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (jacobian.shape[1],))
    return np.asarray(jacobian, dtype=np.float64) * sig[None, :] / s0[:, None]


def imaging_jacobian(
    forward: Any, sigma0: np.ndarray | float = 1.0, inverse_mesh: Mesh | None = None
) -> np.ndarray:
    """``[M, N]`` relative Jacobian of ``forward`` at ``sigma0`` on the imaging mesh.

    Args:
        forward: the (fine) forward model (``.jacobian(sigma)``, ``.voltages(sigma)``,
            ``.mesh``).
        sigma0: reference sheet conductance, siemens, scalar or ``[N_forward]``.
        inverse_mesh: coarser mesh to reconstruct on (default: the forward mesh); its
            Jacobian is ``J_fine C`` (:func:`coarse_to_fine`): a coarse element's change is
            that of all fine elements in it.
    """
    n_fwd = forward.mesh.n_triangles
    sig = np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (n_fwd,)).copy()
    j = relative_jacobian(forward.jacobian(sig), forward.voltages(sig), sig)
    if inverse_mesh is not None and inverse_mesh is not forward.mesh:
        j = np.asarray(coarse_to_fine(forward.mesh, inverse_mesh).T @ j.T).T.copy()
    return j


class LinearModel(Protocol):
    """What a linear method's matrix is assembled from (building, apart from solving).

    Attributes:
        method: the method's name (:data:`~eit_skin.inverse.methods.METHODS`).
        jacobian: ``[M, N]`` relative Jacobian (all channels).
        mesh: the mesh of the ``N`` elements.
    """

    method: ClassVar[str]

    @property
    def jacobian(self) -> np.ndarray: ...

    @property
    def mesh(self) -> Mesh | None: ...

    def gram(self, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(K [Mu, Mu], Y [N, Mu])`` of the dual form on the used channels ``[Mu]``."""
        ...


def checked_frames(
    frames: np.ndarray, reference: np.ndarray, n_channels: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(frames, reference)`` as float64 volts; ValueError unless ``[M]``/``[T, M]``, ``[M]``."""
    v = np.asarray(frames, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape != (n_channels,):
        raise ValueError(f"reference must be [{n_channels}] volts, got {ref.shape}")
    if v.shape[-1] != n_channels or v.ndim not in (1, 2):
        raise ValueError(f"frames must be [M] or [T, M] with M={n_channels}, got {v.shape}")
    return v, ref


_Subset = TypeVar("_Subset")


def channel_subset(
    excluded: np.ndarray,
    n_channels: int,
    cache: dict[bytes, _Subset],
    build: Callable[[np.ndarray], _Subset],
) -> _Subset:
    """``build(keep)`` for the channels ``keep`` not ``excluded`` (bool ``[M]``), cached per mask.

    Raises:
        ValueError: the mask is not ``[n_channels]``, or excludes every channel.
    """
    excluded = np.asarray(excluded, dtype=bool)
    if excluded.shape != (n_channels,):
        raise ValueError(f"excluded mask must be [{n_channels}], got {excluded.shape}")
    key = excluded.tobytes()
    hit = cache.get(key)
    if hit is None:
        keep = np.flatnonzero(~excluded)
        if keep.size == 0:
            raise ValueError("all channels excluded: nothing to reconstruct from")
        hit = cache[key] = build(keep)
    return hit


@dataclass(frozen=True, eq=False)
class PriorModel:
    """The one-step method's dual form: ``K = J P^-1 J^T``, ``Y = P^-1 J^T`` (module docstring).

    Attributes:
        prior: the sparse prior ``P`` on the mesh.
        jacobian: ``[M, N]`` relative Jacobian.
        mesh: the imaging mesh (``N`` elements).
        p_inv_jt: ``[N, M]`` ``P^-1 J^T`` (``M`` sparse solves, once).
    """

    method: ClassVar[str] = "one_step"
    prior: Prior
    jacobian: np.ndarray
    mesh: Mesh
    p_inv_jt: np.ndarray

    @classmethod
    def build(cls, jacobian: np.ndarray, mesh: Mesh, prior: str | Prior) -> PriorModel:
        """From a relative Jacobian ``[M, N]`` and a prior kind or built prior on ``mesh``."""
        j = checked_jacobian(jacobian, mesh)
        p = prior if isinstance(prior, Prior) else make_prior(prior, mesh, j)
        if p.n != mesh.n_triangles:
            raise ValueError(f"prior has {p.n} elements, the mesh {mesh.n_triangles}")
        return cls(p, j, mesh, p.solve(j.T))

    def gram(self, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J_c P^-1 J_c^T [Mu, Mu], P^-1 J_c^T [N, Mu])`` on the used channels ``[Mu]``."""
        y = self.p_inv_jt[:, channels]
        k = self.jacobian[channels] @ y
        return 0.5 * (k + k.T), y


def linear_matrix(
    model: LinearModel,
    hyperparameter: float | None = None,
    noise_figure: float | None = None,
    channels: np.ndarray | None = None,
) -> ReconstructionMatrix:
    """The matrix of ``model`` at ``hyperparameter``, or at the one chosen for ``noise_figure``.

    ``hyperparameter`` None: chosen by :func:`~eit_skin.inverse.hyperparameter.\
choose_by_noise_figure` (``noise_figure`` None: the method's default) on all channels;
    ``channels``: the channel subset to use (default: all).
    """
    base = assemble(model, np.arange(model.jacobian.shape[0]), _PROVISIONAL_H)
    if hyperparameter is None:
        hyperparameter = choose_by_noise_figure(base, noise_figure)
    return base.with_hyperparameter(float(hyperparameter), channels=channels)


def assemble(
    model: LinearModel,
    channels: np.ndarray,
    h: float,
    channel_scale: np.ndarray | None = None,
    noise_figure: float | None = None,
) -> ReconstructionMatrix:
    """The matrix on ``channels`` for hyperparameter ``h``, or for the one hitting ``noise_figure``.

    ``channel_scale``: ``[M]`` relative noise of every channel (whitening); None: unweighted.
    """
    channels = np.asarray(channels, dtype=np.int64)
    k, y = model.gram(channels)
    j = model.jacobian
    if channel_scale is not None:
        w = 1.0 / channel_scale[channels]  # whitening S^-1 on the used channels
        k = k * w[:, None] * w[None, :]
        y = y * w[None, :]
    if noise_figure is not None:  # chosen on the Gram pair: the matrix is assembled once
        used = j[channels] if channel_scale is None else j[channels] * w[:, None]
        h = choose_for_gram(k, y, used, model.mesh, noise_figure)
    return ReconstructionMatrix(
        _matrix(k, y, h, channel_scale, channels), channels, float(h), model, channel_scale, (k, y)
    )


@dataclass(frozen=True, eq=False)
class ReconstructionMatrix:
    """A precomputed linear difference-imaging operator ``R = Y (K + lambda^2 I)^-1``.

    Two methods build one (:mod:`eit_skin.inverse.methods`): ``one_step`` with a sparse
    prior (:meth:`build`, :meth:`from_jacobian`) and ``greit``, the matrix trained on
    simulated targets (:meth:`greit`); both share the dual form, the hyperparameter rule and
    the channel handling below.

    Attributes:
        matrix: ``[N, M_used]`` float64 reconstruction matrix on the used channels.
        channels: ``[M_used]`` int64 indices of the channels it uses (of ``n_channels``).
        n_channels: ``M``, channels in a full frame.
        hyperparameter: dimensionless ``h`` (see module docstring).
        model: what supplies ``(K, Y)`` (:class:`LinearModel`): the :class:`PriorModel` of a
            one-step matrix, or the :class:`~eit_skin.inverse.greit.GreitModel` (training
            set and simulated responses) of a GREIT-trained one.
        channel_scale: ``[M]`` relative noise scale of every channel (weighted least squares,
            ``Sigma = diag(scale^2)``); None: all 1 (unweighted).
    """

    matrix: np.ndarray
    channels: np.ndarray
    hyperparameter: float
    model: LinearModel
    channel_scale: np.ndarray | None = None
    _gram: tuple[np.ndarray, np.ndarray] = field(default=None, repr=False)  # type: ignore[assignment]
    _reduced: dict[bytes, ReconstructionMatrix] = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ build
    @classmethod
    def build(
        cls,
        forward: Any,
        prior: str = "laplace",
        hyperparameter: float | None = None,
        sigma0: np.ndarray | float = 1.0,
        inverse_mesh: Mesh | None = None,
        noise_figure: float | None = None,
    ) -> ReconstructionMatrix:
        """One-step matrix with a prior, from a forward model (see :func:`imaging_jacobian`).

        Args:
            forward: the (fine) forward model.
            prior: one of :data:`~eit_skin.inverse.priors.PRIOR_KINDS`.
            hyperparameter: dimensionless ``h``; ``None`` chooses it by ``noise_figure``
                (:func:`eit_skin.inverse.hyperparameter.choose_by_noise_figure`).
            sigma0: reference sheet conductance, siemens, scalar or ``[N_forward]``.
            inverse_mesh: coarser mesh to reconstruct on (default: the forward mesh).
            noise_figure: target noise figure when ``hyperparameter`` is ``None`` (default:
                the method's, :data:`eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`).
        """
        j = imaging_jacobian(forward, sigma0, inverse_mesh)
        mesh = forward.mesh if inverse_mesh is None else inverse_mesh
        return cls.from_jacobian(j, mesh, prior, hyperparameter, noise_figure=noise_figure)

    @classmethod
    def from_jacobian(
        cls,
        jacobian: np.ndarray,
        mesh: Mesh,
        prior: str | Prior = "laplace",
        hyperparameter: float | None = None,
        noise_figure: float | None = None,
    ) -> ReconstructionMatrix:
        """One-step matrix from a relative Jacobian ``[M, N]`` (:func:`relative_jacobian`).

        ``prior``: a kind (:data:`~eit_skin.inverse.priors.PRIOR_KINDS`) or a built
        :class:`~eit_skin.inverse.priors.Prior` on ``mesh``; other arguments as in
        :meth:`build` (a channel subset: :meth:`without_channels`).
        """
        model = PriorModel.build(jacobian, mesh, prior)
        return linear_matrix(model, hyperparameter, noise_figure)

    @property
    def method(self) -> str:
        """``"one_step"`` or ``"greit"``: the model's method."""
        return self.model.method

    @property
    def jacobian(self) -> np.ndarray:
        """``[M, N]`` relative Jacobian (all channels) the model was built from."""
        return self.model.jacobian

    @property
    def mesh(self) -> Mesh | None:
        """The mesh of the ``N`` elements, if known."""
        return self.model.mesh

    @property
    def n_channels(self) -> int:
        """``M``, channels in a full frame."""
        return int(self.model.jacobian.shape[0])

    @property
    def linearised(self) -> ReconstructionMatrix:
        """The method's linear matrix: this one (the shared reconstructor interface)."""
        return self

    @property
    def gram(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K, Y)`` on the used channels, ``R = Y (K + lambda^2 I)^-1`` (whitened: ``R S^-1``).

        Prior: ``K = J P^-1 J^T`` ``[Mu, Mu]``, ``Y = P^-1 J^T`` ``[N, Mu]``; GREIT:
        ``K = Y_t Y_t^T`` and ``Y = D Y_t^T`` (:mod:`eit_skin.inverse.greit`).
        """
        return self._gram

    # ------------------------------------------------------------ variants
    def with_hyperparameter(
        self, h: float, channels: np.ndarray | None = None
    ) -> ReconstructionMatrix:
        """Same model and Jacobian, another ``h`` (and optionally another channel subset)."""
        if not (np.isfinite(h) and h > 0):
            raise ValueError(f"hyperparameter must be a positive number, got {h}")
        ch = self.channels if channels is None else np.asarray(channels, dtype=np.int64)
        if not np.array_equal(ch, self.channels):
            return assemble(self.model, ch, h, self.channel_scale)
        k, y = self._gram
        return ReconstructionMatrix(
            _matrix(k, y, h, self.channel_scale, ch), ch, float(h), self.model,
            self.channel_scale, self._gram,
        )  # fmt: skip

    def with_channel_scale(
        self,
        scale: np.ndarray | None,
        h: float | None = None,
        noise_figure: float | None = None,
    ) -> ReconstructionMatrix:
        """Same model and channels weighted by relative noise ``scale`` ``[M]`` (None: unweighted).

        ``h``: the hyperparameter (default: this matrix's); ``noise_figure``: instead of ``h``,
        the noise figure (on the weighted channels) the hyperparameter is chosen to hit. One
        ``M x M`` factorisation.
        """
        if h is not None and noise_figure is not None:
            raise ValueError("give a hyperparameter or a noise figure target, not both")
        if scale is not None:
            scale = np.asarray(scale, dtype=np.float64)
            if scale.shape != (self.n_channels,) or not (
                np.isfinite(scale).all() and (scale > 0).all()
            ):
                raise ValueError(f"channel scale must be [{self.n_channels}] positive numbers")
        h = self.hyperparameter if h is None else float(h)
        return assemble(self.model, self.channels, h, scale, noise_figure)

    @property
    def whitened_jacobian(self) -> np.ndarray:
        """``S^-1 J`` on the used channels ``[Mu, N]`` (``J`` when unweighted)."""
        j = self.jacobian[self.channels]
        if self.channel_scale is None:
            return j
        return j / self.channel_scale[self.channels, None]

    def without_channels(self, excluded: np.ndarray) -> ReconstructionMatrix:
        """The matrix that ignores channels where ``excluded`` (bool ``[M]``) is True; cached."""
        return channel_subset(
            excluded,
            self.n_channels,
            self._reduced,
            lambda keep: self.with_hyperparameter(self.hyperparameter, channels=keep),
        )

    # ----------------------------------------------------------- imaging
    @property
    def n_elements(self) -> int:
        return int(self.matrix.shape[0])

    def solve(self, dv: np.ndarray) -> np.ndarray:
        """Relative voltage changes ``[M]``/``[T, M]`` (all channels) -> ``[N]``/``[T, N]`` float32.

        Only the used channels are read, so NaN in other channels cannot leak in.
        """
        d = np.asarray(dv)
        if self.channels.size != self.n_channels:
            d = d[..., self.channels]
        return d.astype(np.float32) @ self.matrix32_t

    @cached_property
    def matrix32_t(self) -> np.ndarray:
        """float32 ``[Mu, N]`` C-contiguous transpose of :attr:`matrix` (made on first use).

        ``frame @ R.T`` on this layout is OpenBLAS's column-update matrix-vector kernel,
        20-30 % faster than row dot products on the ``[N, Mu]`` rows
        (bench/standing/reconstruction.md).
        """
        return np.ascontiguousarray(np.asarray(self.matrix).T, dtype=np.float32)

    @cached_property
    def merged(self) -> MergedColumns:
        """The matrix with its reciprocal channels merged (made on first use; every channel)."""
        if self.channels.size != self.n_channels:
            raise ValueError("merged: the matrix must use every channel")
        return MergedColumns.of(np.asarray(self.matrix))

    def reconstruct(
        self,
        frames: np.ndarray,
        reference: np.ndarray,
        excluded: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (volts) -> relative conductivity change per element.

        Args:
            frames: ``[M]`` or ``[T, M]`` volts, in the protocol's measurement order.
            reference: ``[M]`` volts.
            excluded: optional bool ``[M]`` channels to ignore (faulty electrodes).

        Returns:
            float32 ``[N]`` or ``[T, N]``; channels that are NaN/Inf in the reference or in
            a frame are dropped for that frame (cached reduced matrices), never imaged.
        """
        v, ref = checked_frames(frames, reference, self.n_channels)
        single = v.ndim == 1
        if single and excluded is None and self.channels.size == self.n_channels:
            out = self.merged.solve_frame(v, ref)
            if out is not None:
                return out
        v2 = v[None] if single else v
        scale = reference_scale(ref)  # a few microseconds; drift moves ref every frame
        with np.errstate(invalid="ignore"):
            dv = (v2 - ref) / scale
        finite = np.isfinite(dv)
        if excluded is None and finite.all():  # the common case: every channel usable
            out = self.solve(dv)
            return out[0] if single else out
        base = np.zeros(self.n_channels, dtype=bool) if excluded is None else np.asarray(excluded)
        bad = ~finite | base[None, :] | ~np.isfinite(ref)[None, :]
        out = np.empty((v2.shape[0], self.n_elements), dtype=np.float32)
        if not bad.any():
            out[:] = self.solve(dv)
        else:
            patterns, inverse = np.unique(bad, axis=0, return_inverse=True)
            inverse = inverse.ravel()
            for g, pattern in enumerate(patterns):
                rows = np.flatnonzero(inverse == g)
                op = self.without_channels(pattern) if pattern.any() else self
                out[rows] = op.solve(dv[rows])
        return out[0] if single else out


@dataclass(frozen=True, eq=False)
class MergedColumns:
    """A matrix ``[N, M]`` with its reciprocal channels merged: half the product.

    ``x`` ``[M]`` with a zero appended maps to ``u = g[:P] + g[P:]``, ``g = weights *
    x[index]`` (float64, rounded once to float32), and ``R x = matrix @ u``
    (:func:`~eit_skin.fem.image_grid.proportional_columns`, flattened).

    Attributes:
        matrix: float32 ``[N, P]`` column-major (one ``sgemv`` of contiguous column updates).
        index: int64 ``[2P]`` channel of each merged input (``M``: the appended zero).
        weights: float64 ``[2P]`` their weights.
    """

    matrix: np.ndarray
    index: np.ndarray
    weights: np.ndarray

    @classmethod
    def of(cls, matrix: np.ndarray) -> MergedColumns:
        """Merge the proportional columns of ``matrix`` ``[N, M]``."""
        inputs, weights = proportional_columns(matrix)
        a = np.asfortranarray(matrix[:, inputs[0]], dtype=np.float32)
        index = np.ascontiguousarray(inputs.ravel(), dtype=np.int64)
        return cls(a, index, np.ascontiguousarray(weights.ravel(), dtype=np.float64))

    def solve_frame(self, v: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
        """One frame ``[M]`` against ``ref`` ``[M]`` (float64 V) -> float32 ``[N]``, or None.

        The numpy reference of the compiled kernel's product
        (:mod:`eit_skin.pipeline.frame_kernel`): the float64 quotient ``(v - ref) / s_ref``,
        its reciprocal channels combined and rounded once to float32, one float32 ``sgemv``
        of SciPy's BLAS. None when the reference, the frame or the product is not finite (or
        overflows float32): :meth:`ReconstructionMatrix.reconstruct`'s general path then
        leaves the bad channels out.
        """
        floor = reference_floor(ref)
        if not math.isfinite(floor):
            return None
        m = ref.size
        scale = np.abs(ref)
        np.maximum(scale, floor, out=scale)
        d = np.empty(m + 1)
        d[m] = 0.0  # the zero input of unpaired channels
        dm = d[:m]
        np.subtract(v, ref, out=dm)
        np.divide(dm, scale, out=dm)  # finite ref: no invalid operation
        g = d.take(self.index, mode="wrap")
        np.multiply(g, self.weights, out=g)
        p = self.matrix.shape[1]
        g0 = g[:p]
        np.add(g0, g[p:], out=g0)
        y = _GEMV(1.0, self.matrix, g0.astype(np.float32))  # no FP warning: NaN/Inf in y[0]
        return y if math.isfinite(y[0]) else None


def _matrix(
    k: np.ndarray, y: np.ndarray, h: float, scale: np.ndarray | None, channels: np.ndarray
) -> np.ndarray:
    """``R = Y_w (K_w + lambda^2 I)^-1 S^-1`` ``[N, Mu]`` from the (whitened) Gram pair."""
    r = y @ regularised_inverse(k, lambda_squared(h, np.trace(k), k.shape[0]))
    return r if scale is None else r / scale[channels][None, :]


def checked_jacobian(jacobian: np.ndarray, mesh: Mesh) -> np.ndarray:
    """``jacobian`` as float64 ``[M, N]``; ValueError unless finite with ``N`` = mesh elements."""
    j = np.asarray(jacobian, dtype=np.float64)
    if j.ndim != 2 or j.shape[1] != mesh.n_triangles:
        raise ValueError(f"Jacobian shape {j.shape} does not match {mesh.n_triangles} elements")
    if not np.isfinite(j).all():
        raise ValueError("Jacobian contains NaN or Inf")
    return j
