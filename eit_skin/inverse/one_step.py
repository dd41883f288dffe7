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

Method ``greit`` (:meth:`ReconstructionMatrix.greit`) is the matrix trained on simulated
targets (:mod:`eit_skin.inverse.greit`): the same dual form with ``K = Y Y^T`` and ``D Y^T``
in place of ``J P^-1 J^T`` and ``P^-1 J^T``; it has no prior.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from eit_skin.fem.image_grid import ImageGrid, PixelMatrix, locate_points, proportional_columns
from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.dual_form import lambda_squared, regularised_inverse
from eit_skin.inverse.greit import GreitModel, training_set
from eit_skin.inverse.hyperparameter import choose_by_noise_figure, choose_for_gram
from eit_skin.inverse.priors import Prior, make_prior

REFERENCE_FLOOR = 1e-2
"""Channels whose reference is below this fraction of the RMS reference are normalised by it."""

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
        model: what supplies ``(K, Y)``: the :class:`~eit_skin.inverse.priors.Prior` of a
            one-step matrix, or the :class:`~eit_skin.inverse.greit.GreitModel` (training
            set and simulated responses) of a GREIT-trained one.
        jacobian: ``[M, N]`` relative Jacobian (all channels) it was built from.
        mesh: the mesh of the ``N`` elements, if known.
        channel_scale: ``[M]`` relative noise scale of every channel (weighted least squares,
            ``Sigma = diag(scale^2)``); None: all 1 (unweighted).
    """

    matrix: np.ndarray
    channels: np.ndarray
    n_channels: int
    hyperparameter: float
    model: Prior | GreitModel
    jacobian: np.ndarray
    mesh: Mesh | None = None
    channel_scale: np.ndarray | None = None
    _p_inv_jt: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    _gram: tuple[np.ndarray, np.ndarray] = field(default=None, repr=False)  # type: ignore[assignment]
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False)

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
        channels: np.ndarray | None = None,
        noise_figure: float | None = None,
    ) -> ReconstructionMatrix:
        """One-step matrix from a relative Jacobian ``[M, N]`` (:func:`relative_jacobian`).

        ``prior``: a kind (:data:`~eit_skin.inverse.priors.PRIOR_KINDS`) or a built
        :class:`~eit_skin.inverse.priors.Prior` on ``mesh``; other arguments as in
        :meth:`build`; ``channels``: the channel subset to use (default: all).
        """
        j = _checked_jacobian(jacobian, mesh)
        p = prior if isinstance(prior, Prior) else make_prior(prior, mesh, j)
        if p.n != mesh.n_triangles:
            raise ValueError(f"prior has {p.n} elements, the mesh {mesh.n_triangles}")
        return cls._from_model(j, mesh, p, hyperparameter, channels, noise_figure)

    @classmethod
    def greit(
        cls,
        jacobian: np.ndarray,
        mesh: Mesh,
        hyperparameter: float | None = None,
        noise_figure: float | None = None,
        channels: np.ndarray | None = None,
        model: GreitModel | None = None,
    ) -> ReconstructionMatrix:
        """GREIT-trained matrix from a relative Jacobian ``[M, N]`` (no prior).

        ``model``: a :class:`~eit_skin.inverse.greit.GreitModel` built from this Jacobian
        (default: trained on :func:`~eit_skin.inverse.greit.training_set` of ``mesh``, which
        depends only on the mesh, so the same Jacobian always gives the same matrix); other
        arguments as in :meth:`from_jacobian`.
        """
        j = _checked_jacobian(jacobian, mesh)
        trained = GreitModel.build(j, training_set(mesh)) if model is None else model
        return cls._from_model(j, mesh, trained, hyperparameter, channels, noise_figure)

    @classmethod
    def _from_model(
        cls,
        j: np.ndarray,
        mesh: Mesh,
        model: Prior | GreitModel,
        hyperparameter: float | None,
        channels: np.ndarray | None,
        noise_figure: float | None,
    ) -> ReconstructionMatrix:
        p_inv_jt = model.solve(j.T) if isinstance(model, Prior) else None  # [N, M]
        all_channels = np.arange(j.shape[0])
        base = cls._assemble(j, model, p_inv_jt, all_channels, _PROVISIONAL_H, mesh)
        if hyperparameter is None:
            hyperparameter = choose_by_noise_figure(base, noise_figure)
        return base.with_hyperparameter(float(hyperparameter), channels=channels)

    @classmethod
    def _assemble(
        cls,
        j: np.ndarray,
        p: Prior | GreitModel,
        p_inv_jt: np.ndarray | None,
        channels: np.ndarray,
        h: float,
        mesh: Mesh | None,
        channel_scale: np.ndarray | None = None,
        noise_figure: float | None = None,
    ) -> ReconstructionMatrix:
        """The matrix for hyperparameter ``h``, or for the one hitting ``noise_figure``."""
        channels = np.asarray(channels, dtype=np.int64)
        if isinstance(p, GreitModel):
            k, y = p.gram(channels)
        else:
            y = p_inv_jt[:, channels]
            k = j[channels] @ y
            k = 0.5 * (k + k.T)
        if channel_scale is not None:
            w = 1.0 / channel_scale[channels]  # whitening S^-1 on the used channels
            k = k * w[:, None] * w[None, :]
            y = y * w[None, :]
        if noise_figure is not None:  # chosen on the Gram pair: the matrix is assembled once
            used = j[channels] if channel_scale is None else j[channels] * w[:, None]
            h = choose_for_gram(k, y, used, mesh, noise_figure)
        return cls(
            matrix=_matrix(k, y, h, channel_scale, channels),
            channels=channels,
            n_channels=j.shape[0],
            hyperparameter=float(h),
            model=p,
            jacobian=j,
            mesh=mesh,
            channel_scale=channel_scale,
            _p_inv_jt=p_inv_jt,
            _gram=(k, y),
        )

    @property
    def method(self) -> str:
        """``"greit"`` for the trained matrix, else ``"one_step"``."""
        return "greit" if isinstance(self.model, GreitModel) else "one_step"

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
        if np.array_equal(ch, self.channels):
            k, y = self._gram
            return ReconstructionMatrix(
                matrix=_matrix(k, y, h, self.channel_scale, ch),
                channels=ch,
                n_channels=self.n_channels,
                hyperparameter=float(h),
                model=self.model,
                jacobian=self.jacobian,
                mesh=self.mesh,
                channel_scale=self.channel_scale,
                _p_inv_jt=self._p_inv_jt,
                _gram=self._gram,
            )
        return ReconstructionMatrix._assemble(
            self.jacobian, self.model, self._p_inv_jt, ch, h, self.mesh, self.channel_scale
        )

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
        return ReconstructionMatrix._assemble(
            self.jacobian,
            self.model,
            self._p_inv_jt,
            self.channels,
            h,
            self.mesh,
            scale,
            noise_figure,
        )

    @property
    def whitened_jacobian(self) -> np.ndarray:
        """``S^-1 J`` on the used channels ``[Mu, N]`` (``J`` when unweighted)."""
        j = self.jacobian[self.channels]
        if self.channel_scale is None:
            return j
        return j / self.channel_scale[self.channels, None]

    def without_channels(self, excluded: np.ndarray) -> ReconstructionMatrix:
        """The matrix that ignores channels where ``excluded`` (bool ``[M]``) is True; cached."""
        excluded = np.asarray(excluded, dtype=bool)
        if excluded.shape != (self.n_channels,):
            raise ValueError(f"excluded mask must be [{self.n_channels}], got {excluded.shape}")
        key = excluded.tobytes()
        hit = self._cache.get(key)
        if hit is None:
            keep = np.flatnonzero(~excluded)
            if keep.size == 0:
                raise ValueError("all channels excluded: nothing to reconstruct from")
            hit = self.with_hyperparameter(self.hyperparameter, channels=keep)
            self._cache[key] = hit
        return hit

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
        return d.astype(np.float32) @ self._matrix32_t()

    def _matrix32_t(self) -> np.ndarray:
        """float32 ``[Mu, N]`` C-contiguous transpose of :attr:`matrix` (cached).

        ``frame @ R.T`` on this layout is OpenBLAS's column-update matrix-vector kernel,
        20-30 % faster than row dot products on the ``[N, Mu]`` rows (bench/REPORT.md).
        """
        m = self._cache.get("float32_t")
        if m is None:
            m = np.ascontiguousarray(np.asarray(self.matrix).T, dtype=np.float32)
            self._cache["float32_t"] = m
        return m

    def pixel_matrix(
        self,
        grid: ImageGrid,
        scale: float = 1.0,
        floor: float = -np.inf,
        ceiling: float = np.inf,
    ) -> PixelMatrix:
        """This matrix on ``grid``: unit ``scale``, clip to ``[floor, ceiling]`` (cached)."""
        if self.channels.size != self.n_channels:
            raise ValueError("pixel_matrix: the matrix must use every channel")
        key = ("pixels", id(grid), float(scale), float(floor), float(ceiling))
        hit = self._cache.get(key)
        if hit is None or hit[0] is not grid:
            pixels = PixelMatrix.build(grid, self.matrix, scale, floor, ceiling)
            hit = self._cache[key] = (grid, pixels)
        return hit[1]

    def images(
        self,
        frames: np.ndarray,
        reference: np.ndarray,
        grid: ImageGrid,
        scale: float = 1.0,
        floor: float = -np.inf,
        excluded: np.ndarray | None = None,
        ceiling: float = np.inf,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (volts) -> float32 images ``[H, W]``/``[T, H, W]``, NaN outside the sheet.

        Pixel value: ``scale`` times the relative change, clipped to ``[floor, ceiling]``.
        Frames with every channel usable are one product with :meth:`pixel_matrix`
        (``[K, P]``, the ``K`` elements under pixels, reciprocal channels merged); one frame
        runs in preallocated buffers (:class:`FrameImager`); others go through
        :meth:`reconstruct` (left-out channels) and the same gather. Same values as
        ``scale *`` :meth:`reconstruct` gridded, to float32 rounding. ``out``: optional
        float32 C-contiguous ``[H, W]`` the image of a single frame is written to (and
        returned); default a new array.
        """
        if excluded is None:
            image = self.frame_imager(grid, scale, floor, ceiling).image(frames, reference, out)
            if image is not None:
                return image
        pixels = self.pixel_matrix(grid, scale, floor, ceiling)
        if excluded is None and self.channels.size == self.n_channels:
            f = np.asarray(frames)
            if f.shape[-1:] == (self.n_channels,) and f.ndim == 2:
                ref_scale = self._reference_scale(reference)
                # NaN/Inf anywhere in the frames makes their sum non-finite (so does an
                # overflow of finite volts, which then takes the exact path below too)
                if ref_scale is not None and math.isfinite(np.add.reduce(f, axis=None)):
                    return pixels.apply(np.subtract(f, ref_scale[0]) / ref_scale[1])
        images = pixels.from_elements(self.reconstruct(frames, reference, excluded))
        if out is not None and images.ndim == 2:
            out[...] = images
            return out
        return images

    def frame_imager(
        self,
        grid: ImageGrid,
        scale: float = 1.0,
        floor: float = -np.inf,
        ceiling: float = np.inf,
    ) -> FrameImager:
        """The single-frame imager of :meth:`images` on ``grid`` (cached per grid and unit).

        The last one used is checked first (four comparisons, no key to build).
        """
        plan = self._cache.get("frame_imager")
        if (
            plan is None
            or plan.grid is not grid
            or plan.scale != scale
            or plan.floor != floor
            or plan.ceiling != ceiling
        ):
            key = ("frame_imager", id(grid), float(scale), float(floor), float(ceiling))
            plan = self._cache.get(key)
            if plan is None or plan.grid is not grid:
                pixels = self.pixel_matrix(grid, scale, floor, ceiling)
                plan = FrameImager(pixels, grid, self.n_channels, scale, floor, ceiling)
                self._cache[key] = plan
            self._cache["frame_imager"] = plan
        return plan

    def _solve_finite_frame(self, v: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
        """One frame ``[M]`` against ``ref`` ``[M]`` (float64 V) in the fewest numpy calls.

        The numbers of the general path of :meth:`reconstruct` to float32 rounding: the same
        float64 quotient ``(v - ref) / s_ref``, whose reciprocal channels are then combined
        (:meth:`merged_matrix`, half the product for an adjacent protocol) and rounded once to
        float32, and one ``sgemv``. None when the reference, the frame or the product is not
        finite (or overflows float32): the general path handles those. A node calls this once
        per frame against a reference that drift moves every frame, so nothing here is cached
        but the merged matrix.
        """
        a, index, weights, gemv = self.merged_matrix()
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
        g = d.take(index, mode="wrap")
        np.multiply(g, weights, out=g)
        p = a.shape[1]
        g0 = g[:p]
        np.add(g0, g[p:], out=g0)
        y = gemv(1.0, a, g0.astype(np.float32))  # no FP warning: NaN/Inf show in y[0]
        return y if math.isfinite(y[0]) else None

    def merged_matrix(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
        """The matrix with its reciprocal channels merged (cached; every channel used).

        Returns ``(a, index, weights, gemv)``: ``a`` float32 ``[N, P]`` column-major, ``index``
        and ``weights`` ``[2P]`` (:func:`~eit_skin.fem.image_grid.proportional_columns`
        flattened: ``x`` ``[M]`` with a zero appended maps to ``u = g[:P] + g[P:]``,
        ``g = weights * x[index]``), and SciPy's float32 ``gemv`` (``a @ u`` is
        ``gemv(1.0, a, u)``).
        """
        hit = self._cache.get("merged")
        if hit is None:
            inputs, weights = proportional_columns(np.asarray(self.matrix))
            a = np.asfortranarray(np.asarray(self.matrix)[:, inputs[0]], dtype=np.float32)
            gemv = sla.get_blas_funcs("gemv", dtype=np.float32)
            hit = self._cache["merged"] = (a, inputs.ravel(), weights.ravel(), gemv)
        return hit

    def _reference_scale(self, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``(reference, reference_scale(reference))`` float64 ``[M]``, None unless finite.

        Cached while the reference's bytes stay the same.
        """
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (self.n_channels,):
            return None
        key = ref.tobytes()
        cached = self._cache.get("reference_scale")
        if cached is None or cached[0] != key:
            usable = bool(np.isfinite(ref).all())
            value = (ref.copy(), reference_scale(ref)) if usable else None
            cached = self._cache["reference_scale"] = (key, value)
        return cached[1]

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
        v = np.asarray(frames, dtype=np.float64)
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != (self.n_channels,):
            raise ValueError(f"reference must be [{self.n_channels}] volts, got {ref.shape}")
        if v.shape[-1] != self.n_channels or v.ndim not in (1, 2):
            raise ValueError(
                f"frames must be [M] or [T, M] with M={self.n_channels}, got {v.shape}"
            )
        single = v.ndim == 1
        if single and excluded is None and self.channels.size == self.n_channels:
            out = self._solve_finite_frame(v, ref)
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


class FrameImager:
    """One frame ``[M]`` V -> its image through a :class:`PixelMatrix`, in preallocated buffers.

    Per frame: ``d = v - ref``; ``g = d[inputs]``; ``g *= w``; ``u = g[0] + g[1]`` (float64,
    rounded once to float32); ``y = A u`` (BLAS ``sgemv`` into ``y``); clip; one gather of
    ``y`` (NaN last) onto the ``[H, W]`` pixels: seven numpy calls and one BLAS call, nothing
    allocated but the returned image. ``w = weights / s_ref[inputs]`` is computed once per
    reference (cached while the reference's bytes stay the same): the one-step data
    convention ``dv = (v - v_ref) / s_ref`` folded into the channel merge.

    NaN/Inf need no check before the product: any non-finite input makes every product value
    non-finite (IEEE arithmetic, no term of a matrix-vector sum is skipped), so the first
    value tells, and the caller takes its exact path; ``sgemv``, unlike ``np.matmul``, raises
    no floating-point warning for it. A call made while another thread uses the buffers
    returns None (the caller's allocating path) instead of waiting.

    Attributes:
        pixels: the folded matrix (``K`` rows, ``P`` merged columns).
        grid: the grid it was folded onto.
        scale, floor, ceiling: as in :meth:`ReconstructionMatrix.images`.
        n_channels: ``M``.
    """

    __slots__ = (
        "_d", "_dm", "_frame_shape", "_g", "_g0", "_g1", "_gemv", "_high", "_index", "_key",
        "_lock", "_low", "_matrix", "_owner", "_ref", "_u", "_w", "_y", "_yk", "ceiling",
        "floor", "grid", "n_channels", "pixels", "scale",
    )  # fmt: skip

    def __init__(
        self,
        pixels: PixelMatrix,
        grid: ImageGrid,
        n_channels: int,
        scale: float,
        floor: float,
        ceiling: float,
    ) -> None:
        self.pixels, self.grid = pixels, grid
        self.scale, self.floor, self.ceiling = scale, floor, ceiling
        self.n_channels = m = int(n_channels)
        self._frame_shape = (m,)
        self._matrix = pixels.matrix
        self._owner = pixels.owner.reshape(pixels.shape)  # the gather gives [H, W] directly
        k, p = pixels.matrix.shape
        self._index = pixels.inputs.ravel()  # [2P] into d, whose last entry stays 0
        self._d = np.zeros(m + 1)
        self._dm = self._d[:m]
        self._g = np.empty(2 * p)
        self._g0, self._g1 = self._g[:p], self._g[p:]
        self._u = np.zeros(p, dtype=np.float32)
        self._y = np.zeros(k + 1, dtype=np.float32)
        self._y[k] = np.nan
        self._yk = self._y[:k]
        # full-length bounds: a ufunc without broadcasting costs less per call
        self._low = None if floor == -np.inf else np.full(k, floor, dtype=np.float32)
        self._high = None if ceiling == np.inf else np.full(k, ceiling, dtype=np.float32)
        self._key: bytes | None = None
        self._lock = threading.Lock()
        self._ref = np.empty(m)
        self._w = np.empty(2 * p)
        # f2py's sgemv with positional arguments (keywords cost ~1.5 us per call); used only
        # if it writes into y in place, as it does for a contiguous float32 y
        gemv = sla.get_blas_funcs("gemv", dtype=np.float32)
        product = gemv(1.0, self._matrix, self._u, 0.0, self._yk, 0, 1, 0, 1, 0, 1)
        self._gemv = gemv if np.shares_memory(product, self._yk) else None

    def image(
        self, frame: np.ndarray, reference: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Frame ``[M]`` V against ``reference`` ``[M]`` V -> float32 ``[H, W]``, or None.

        None: not a single finite frame against a finite reference, or the buffers are in use
        by another thread (the caller's general path handles it). ``out``: float32
        C-contiguous ``[H, W]`` to write the image to.
        """
        if getattr(frame, "shape", None) != self._frame_shape:
            return None  # not one [M] frame (T frames, a list: the caller's general path)
        if not self._lock.acquire(False):  # positional: a keyword costs 0.4 us
            return None
        try:  # one function body: a further call costs as much as a small numpy step
            ref = np.asarray(reference, dtype=np.float64)
            key = ref.tobytes()
            if key != self._key and not self._use_reference(ref, key):
                return None
            g, g0, u, yk = self._g, self._g0, self._u, self._yk
            np.subtract(frame, self._ref, out=self._dm)
            self._d.take(self._index, out=g, mode="wrap")  # the method: np.take wraps it slowly
            np.multiply(g, self._w, out=g)
            np.add(g0, self._g1, out=g0)
            u[...] = g0  # the float64 sum rounded once (cheaper than add's casting output)
            if self._gemv is not None:
                self._gemv(1.0, self._matrix, u, 0.0, yk, 0, 1, 0, 1, 0, 1)
            else:
                with np.errstate(all="ignore"):
                    np.matmul(self._matrix, u, out=yk)
            if not math.isfinite(yk[0]):
                yk.fill(0.0)  # no NaN left behind for the next product (beta 0 may keep NaN)
                return None
            if self._low is not None:
                np.maximum(yk, self._low, out=yk)
            if self._high is not None:
                np.minimum(yk, self._high, out=yk)
            if out is None:
                return self._y.take(self._owner, mode="wrap")
            return self._y.take(self._owner, out=out, mode="wrap")
        finally:
            self._lock.release()

    def _use_reference(self, ref: np.ndarray, key: bytes) -> bool:
        """Weights for a new reference ``[M]``; False (nothing kept) unless it is finite."""
        if ref.shape != (self.n_channels,) or not np.isfinite(ref).all():
            return False
        s = np.append(reference_scale(ref), 1.0)  # the zero input's scale
        np.divide(self.pixels.weights.ravel(), s[self._index], out=self._w)
        self._ref[:] = ref
        self._key = key
        return True


def _matrix(
    k: np.ndarray, y: np.ndarray, h: float, scale: np.ndarray | None, channels: np.ndarray
) -> np.ndarray:
    """``R = Y_w (K_w + lambda^2 I)^-1 S^-1`` ``[N, Mu]`` from the (whitened) Gram pair."""
    r = y @ regularised_inverse(k, lambda_squared(h, np.trace(k), k.shape[0]))
    return r if scale is None else r / scale[channels][None, :]


def _checked_jacobian(jacobian: np.ndarray, mesh: Mesh) -> np.ndarray:
    """``jacobian`` as float64 ``[M, N]``; ValueError unless finite with ``N`` = mesh elements."""
    j = np.asarray(jacobian, dtype=np.float64)
    if j.ndim != 2 or j.shape[1] != mesh.n_triangles:
        raise ValueError(f"Jacobian shape {j.shape} does not match {mesh.n_triangles} elements")
    if not np.isfinite(j).all():
        raise ValueError("Jacobian contains NaN or Inf")
    return j
