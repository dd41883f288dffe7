"""The planned frame step compiled into one call: :func:`compiled_step`, bit for bit numpy's.

In numpy a planned frame (:mod:`eit_skin.pipeline.frame_plan`) is about twenty calls of a
microsecond or more each, on arrays of a few hundred values: with 50 patches in one process
(cold caches between a patch's frames) that was about half of a frame's CPU
(bench/standing/frame_cost.md). :func:`compiled_step` runs the arithmetic of
:func:`~eit_skin.pipeline.frame_plan.reference_step` (steps 0-4 there) compiled with numba in
one call: the same operations in the same order and precision (float64 quotients, one
rounding to float32 before the product, SciPy's float32 BLAS ``gemv``, no fused multiply-add:
numba's default without ``fastmath``), so its values, images, contact decisions and
references equal the numpy step's bit for bit (test/test_frame_plan_parity.py).

numba is a dependency of the package but not a hard one: without it, or with the environment
variable ``EIT_SKIN_JIT=0``, :func:`frame_step` is the numpy step (:func:`compiled_step_status`
says which). The kernel is compiled once per process, about a second, the first time
:func:`frame_step` is asked for it (a node does so before it spins); it is not cached on disk,
since numba's disk cache is not safe for processes that start together (numba issue #4807).
Only with ``EIT_SKIN_JIT_CACHE=1`` is it kept in numba's disk cache (``NUMBA_CACHE_DIR``):
the test suite compiles it there once before any node starts (test/conftest.py), so that
its hundred-odd node processes load it (about 0.1 s) instead of compiling it.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np

from eit_skin.inverse.one_step import reference_floor
from eit_skin.pipeline.frame_plan import FrameChecks, FramePlan, FrameResult, reference_step

#: Environment variable: ``0`` keeps every frame on the numpy step.
JIT_SWITCH = "EIT_SKIN_JIT"
#: Environment variable: ``1`` keeps the compiled kernel in numba's disk cache
#: (``NUMBA_CACHE_DIR``); only for a cache filled before processes start together.
JIT_CACHE_SWITCH = "EIT_SKIN_JIT_CACHE"

#: The signature of a planned frame step (:func:`reference_step`, :func:`compiled_step`).
FrameStep = Callable[[FramePlan, np.ndarray, np.ndarray, FrameChecks], FrameResult | None]


def _kernel(v, ref, plan, checks):  # type: ignore[no-untyped-def]
    """One frame: the documented kernel (plain Python until numba compiles it).

    ``plan``: ``(signs, a, index, weights, owner, low, high, pascals, h, w)``;
    ``checks``: ``(floor, noise, k, alpha, full_scale, previous, jump)`` (empty ``noise``:
    unknown; ``alpha < 0``: no tracking). Returns ``(values, reference, image, touching,
    planned)``; ``planned`` False: the numpy path decides.
    """
    signs, a, index, weights, owner, low, high, pascals, h, w = plan
    floor, noise, k, alpha, full_scale, prev, jump = checks
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
        row[i] = np.float32(np.float64(c) * pascals)
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
    tup = numba.types.Tuple
    plan = tup(
        (f64[::1], f32[::1, :], i64[::1], f64[::1], numba.intp[::1], f32, f32, f64, i64, i64)
    )
    checks = tup((f64, f64[::1], f64, f64, f64, f64[::1], f64[::1]))
    result = tup((f32[::1], f64[::1], f32[:, ::1], numba.boolean, numba.boolean))
    signature = result(f64[::1], f64[::1], plan, checks)
    cache = os.environ.get(JIT_CACHE_SWITCH, "0").strip() == "1"
    kernel = numba.njit(signature, cache=cache, nogil=True)(_kernel)
    return kernel, f"compiled (numba {numba.__version__})"


def compiled_step_status() -> str:
    """Which per-frame step this process runs: ``compiled (numba X)`` or ``numpy (why)``."""
    return _compiled()[1]


def frame_step(compiled: bool = True) -> FrameStep:
    """:func:`compiled_step` when asked for and numba is there, else :func:`reference_step`."""
    return compiled_step if compiled and _compiled()[0] is not None else reference_step


_NO_NOISE = np.zeros(0)


@functools.lru_cache(maxsize=64)
def _no_checks(m: int) -> tuple[np.ndarray, np.ndarray]:
    """(previous, limit) ``[M]`` that never flag a jump: NaN and infinity."""
    return np.full(m, np.nan), np.full(m, np.inf)


def compiled_step(
    plan: FramePlan, frame_v: np.ndarray, reference_v: np.ndarray, checks: FrameChecks
) -> FrameResult | None:
    """:func:`~eit_skin.pipeline.frame_plan.reference_step` in one compiled call.

    ``frame_v``, ``reference_v``: float64 C-contiguous ``[M]`` V (the kernel's types).
    """
    floor = reference_floor(reference_v)  # numpy's ddot, as the numpy step
    if not math.isfinite(floor):
        return None
    noise, k, alpha, full_scale, previous, limit = checks
    if previous is None or limit is None:
        previous, limit = _no_checks(reference_v.size)
    values, base, image, touching, planned = _compiled()[0](
        frame_v,
        reference_v,
        plan.packed,
        (
            floor,
            _NO_NOISE if noise is None else noise,
            float(k),
            -1.0 if alpha is None else float(alpha),
            math.inf if full_scale is None else float(full_scale),
            previous,
            limit,
        ),
    )
    return FrameResult(values, image, base, touching) if planned else None
