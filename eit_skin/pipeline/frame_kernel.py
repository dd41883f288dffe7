"""A pressure layer's per-frame step in one compiled call, bit for bit the numpy step.

Most frames a node images take one path through :meth:`LayerProcessor.step
<eit_skin.pipeline.processor.LayerProcessor.step>`: every channel finite and used, a linear
(one-step or GREIT) matrix, a pressure layer, no posture table. In numpy that path is about
twenty calls of a microsecond or more each, on arrays of a few hundred values: with 50 patches
in one process (cold caches between a patch's frames) it cost about half of a frame's CPU
(bench/frame_cost.md). :class:`FrameKernel` runs the same arithmetic in one call compiled with
numba:

0. the values no sheet can give (beyond the full scale, a one-frame jump): the kernel only
   finds that there are some and leaves the frame to the numpy step, which flags them;
1. the relative change ``x = R (v - v_ref) / s_ref`` of the single-frame path of
   :class:`~eit_skin.inverse.one_step.ReconstructionMatrix` (the float64 quotient, the
   reciprocal channels merged, one float32 ``sgemv`` of SciPy's BLAS);
2. the contact decision of :meth:`ReferenceTracker.touching
   <eit_skin.pipeline.reference.ReferenceTracker.touching>` (``|x| / noise > contact_k``);
3. drift tracking of an untouched frame, ``ref + alpha (v - ref)``;
4. the physical image of :meth:`LayerImager.physical_image
   <eit_skin.pipeline.builder.LayerImager.physical_image>` (clip, Pa, one gather).

The same operations in the same order and precision (float64 quotients, one rounding to
float32 before the product, no fused multiply-add: numba's default without ``fastmath``), so
its images, contact decisions and references equal the numpy step's bit for bit (tested on
frames with drift, touches, a magnitude device and a floored channel). Anything else (a
missing or flagged channel, a faulty electrode, Gauss-Newton, stretch, posture, a product
that is not finite) takes the numpy path, which stays the reference implementation.

numba is a dependency of the package but not a hard one: without it, or with the environment
variable ``EIT_SKIN_JIT=0``, every frame takes the numpy path (:func:`compiled_step_status`
says which). The kernel is compiled once per process, about a second, when the first
:class:`FrameKernel` is made (a node does so before it spins); it is not cached on disk, since
numba's disk cache is not safe for processes that start together (numba issue #4807).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from eit_skin.inverse.one_step import ReconstructionMatrix, reference_floor
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE

if TYPE_CHECKING:
    from eit_skin.pipeline.builder import LayerImager

#: Environment variable: ``0`` keeps every frame on the numpy path.
JIT_SWITCH = "EIT_SKIN_JIT"


def _step(
    v, ref, signs, a, index, weights, floor, noise, k, alpha, low, high, scale, owner, h, w,
    full_scale, prev, jump,
):  # fmt: skip
    """One frame; see :class:`FrameKernel` (plain Python until numba compiles it)."""
    m = ref.size
    d = np.empty(m + 1)
    d[m] = 0.0  # the zero input of unpaired channels
    for i in range(m):
        if abs(v[i]) > full_scale or abs(v[i] - prev[i]) > jump[i]:  # NaN prev: no jump
            return np.empty(0, dtype=np.float32), ref, np.empty((h, w), np.float32), True, False
        r = ref[i] * signs[i]
        s = abs(r)
        if s < floor:
            s = floor
        d[i] = (v[i] * signs[i] - r) / s
    p = a.shape[1]
    u = np.empty(p, dtype=np.float32)
    for j in range(p):
        u[j] = np.float32(d[index[j]] * weights[j] + d[index[j + p]] * weights[j + p])
    y = a @ u
    n = y.size
    image = np.empty((h, w), dtype=np.float32)
    if not math.isfinite(y[0]):  # NaN/Inf anywhere shows in y[0]: the numpy path decides
        return y, ref, image, True, False
    touching = noise.size == 0  # unknown noise: never learn into the reference
    if not touching:
        for i in range(n):
            if abs(np.float64(y[i])) / noise[i] > k:
                touching = True
                break
    base = ref
    if not touching and alpha >= 0.0:
        base = np.empty(m)
        for i in range(m):
            base[i] = ref[i] + alpha * (v[i] - ref[i])
    row = np.empty(n + 1, dtype=np.float32)
    for i in range(n):
        c = y[i]
        if c < low:
            c = low
        if c > high:
            c = high
        row[i] = np.float32(np.float64(c) * scale)
    row[n] = np.nan
    flat = image.reshape(h * w)
    for q in range(h * w):
        flat[q] = row[owner[q]]
    return y, base, image, touching, True


@functools.cache
def _compiled() -> tuple[Callable[..., Any] | None, str]:
    """(the compiled kernel or None, why): compiled once per process, on first use."""
    if os.environ.get(JIT_SWITCH, "1").strip() == "0":
        return None, f"numpy ({JIT_SWITCH}=0)"
    try:
        import numba
    except ImportError:
        return None, "numpy (numba is not installed)"
    f64, f32, i64 = numba.float64, numba.float32, numba.int64
    signature = numba.types.Tuple(
        (f32[::1], f64[::1], f32[:, ::1], numba.boolean, numba.boolean)
    )(
        f64[::1], f64[::1], f64[::1], f32[::1, :], i64[::1], f64[::1], f64, f64[::1], f64,
        f64, f32, f32, f64, numba.intp[::1], i64, i64, f64, f64[::1], f64[::1],
    )  # fmt: skip
    kernel = numba.njit(signature, cache=False, nogil=True)(_step)
    return kernel, f"compiled (numba {numba.__version__})"


def compiled_step_status() -> str:
    """Which per-frame step this process runs: ``compiled (numba X)`` or ``numpy (why)``."""
    return _compiled()[1]


class FrameKernel:
    """The compiled per-frame step of one layer (see the module docstring).

    Args:
        imager: the layer's :class:`~eit_skin.pipeline.builder.LayerImager`.
        enabled: False: never compile, every frame takes the numpy path.

    :meth:`usable` says whether the layer's configuration allows it at all (a pressure layer
    with a linear matrix over every channel); :meth:`step` then images one frame.
    """

    def __init__(self, imager: LayerImager, enabled: bool = True) -> None:
        self.imager = imager
        material = imager.layer.material
        low, high = RELATIVE_CHANGE_RANGE
        self._low, self._high = np.float32(low), np.float32(high)
        scale = material.pressure_scale_pa if material.quantity == "pressure" else None
        self._scale = float(scale or 0.0)
        self._owner = np.ascontiguousarray(imager.grid.pixel_owner, dtype=np.intp)
        self._shape = imager.grid.shape
        m = imager.n_measurements
        self._signs = (
            np.ones(m) if imager.signs is None else np.asarray(imager.signs, dtype=np.float64)
        )
        self._no_noise = np.zeros(0)
        self._no_previous = np.full(m, np.nan)  # no jump check
        self._no_limit = np.full(m, np.inf)
        self.kernel = _compiled()[0] if enabled and self._scale > 0 else None
        self._checked: object = None  # the reconstructor :meth:`usable` last looked at
        self._plan: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # its matrix

    def usable(self) -> bool:
        """Whether frames of this layer can take the compiled step now.

        True for a pressure layer with a linear matrix over every channel, numba present.
        Looked at again when the reconstructor changes (a new reference re-weights it).
        """
        rec = self.imager.reconstructor
        if rec is not self._checked:
            self._checked = rec
            self._plan = None
            if (
                self.kernel is not None
                and isinstance(rec, ReconstructionMatrix)
                and rec.channels.size == rec.n_channels
                and rec.matrix.shape[0] == self.imager.mesh.n_triangles
            ):
                a, index, weights, _ = rec.merged_matrix()  # in the kernel's exact types
                self._plan = (
                    np.asfortranarray(a, dtype=np.float32),
                    np.ascontiguousarray(index, dtype=np.int64),
                    np.ascontiguousarray(weights, dtype=np.float64),
                )
        return self._plan is not None

    def step(
        self,
        frame_v: np.ndarray,
        reference_v: np.ndarray,
        element_noise: np.ndarray | None,
        contact_k: float,
        alpha: float | None,
        full_scale_v: float | None = None,
        previous_v: np.ndarray | None = None,
        jump_limit_v: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool] | None:
        """One frame ``[M]`` V (every value finite) against the reference ``[M]`` V.

        Args:
            frame_v: float64 ``[M]`` volts as the device reports them (a magnitude device's
                signs are applied here, as :class:`LayerImager` does).
            reference_v: float64 ``[M]`` volts, the same way.
            element_noise: ``[N]`` noise of the relative change per element; None: unknown
                (the frame counts as touched).
            contact_k: contact threshold in noise units.
            alpha: drift weight of an untouched frame (``ReferenceTracker.drift_alpha``);
                None: tracking off.
            full_scale_v: the board's full scale, V; None: no range check.
            previous_v: float64 ``[M]`` the previous frame, V (NaN: no comparison); None: none.
            jump_limit_v: float64 ``[M]`` largest plausible one-frame change, V; None: none.

        Returns:
            ``(values float32 [N], image float32 [H, W], reference [M] V after drift
            tracking, touching)``, or None when the numpy path must decide (the reference's
            floor or the product is not finite, a value beyond ``full_scale_v`` or jumped
            more than ``jump_limit_v`` from ``previous_v``: the numpy step flags it). Call
            only when :meth:`usable`.
        """
        a, index, weights = self._plan
        floor = reference_floor(reference_v)  # numpy's ddot, as the numpy path
        if not math.isfinite(floor):
            return None
        h, w = self._shape
        y, base, image, touching, finite = self.kernel(
            frame_v, reference_v, self._signs, a, index, weights, floor,
            self._no_noise if element_noise is None else element_noise, float(contact_k),
            -1.0 if alpha is None else float(alpha), self._low, self._high, self._scale,
            self._owner, h, w, math.inf if full_scale_v is None else float(full_scale_v),
            self._no_previous if previous_v is None or jump_limit_v is None else previous_v,
            self._no_limit if previous_v is None or jump_limit_v is None else jump_limit_v,
        )  # fmt: skip
        if not finite:
            return None
        return y, image, base, touching
