"""Electrode and channel faults: detect them from frames, keep imaging without them.

Channel checks (per frame block ``[T, M]`` volts):
    * non-finite (NaN/Inf) in the reference or any frame;
    * saturated: ``|v| >= saturation_v`` (the ADC's full scale) in any frame.

Electrode checks: which channels are spoiled, then which electrodes explain them.

A channel is **spoiled** when it is bad (above), or when over the frames its voltage is no
longer that of a loaded sheet, or when it is erratic:

* **lost signal**: the median over the frames of ``q = v / v_ref`` (signed, ``v_ref``
  floored like :func:`~eit_skin.inverse.one_step.reference_scale`) lies outside
  ``[1/K, K]``, ``K`` = :data:`~eit_skin.patch.material.CONDUCTANCE_RATIO_LIMIT`: a
  zeroed channel (``q = 0``), a floating input (median ``q`` near 0) or a sign flip.
  A load, even one covering an electrode, scales a channel by a bounded factor
  (the images' own range, :mod:`eit_skin.patch.material`);
* **erratic** (two frames or more): its robust roughness, ``1.4826 * MAD`` of the second
  differences in time of ``q`` (first differences for two frames), exceeds ``threshold``
  times the median over the other channels, or ``1/K`` (a tenth of the signal: noise-free
  or quantised data can have a median of 0). A press or a joint bend moves channels
  smoothly (a ramp has no second difference, and its bends are a minority of frames, which
  the median ignores, also when frames are dropped); a floating or loose input jumps every
  frame.

A dead electrode ``e`` spoils **every** channel touching ``e`` (it drives or measures with
``e``: :meth:`Protocol.touching`); a neighbour shares some of those channels, but its own
channels not touching ``e`` are fine. So electrodes are named one at a time, each time the
one with the most spoiled channels among those candidates whose channels **not touching an
electrode named before** are spoiled in more than ``(1 + s) / 2`` of cases, ``s`` the largest
fraction of one electrode's channels that another electrode shares (from the protocol:
28/52 for adjacent drive and measurement, so 0.77), i.e. above the midpoint between what a
dead neighbour spoils and all. The named electrode's channels are then explained, and the rest
are looked at again. An electrode all of whose channels touch other named ones (between two
dead electrodes) cannot be judged and is not named (also when it was named first: a last
pass drops it); its channels are left out anyway.

A **noisy electrode** (a degrading contact: its channels several times noisier than the
others, but not ``threshold`` times) is named in the same loop when, no electrode having
been named yet, the median roughness of its channels exceeds ``sqrt(threshold)`` (3.2 for
the default 10) times the median roughness of the channels not touching it, or when more
than the majority above of its channels are each that rough. One channel that rough stays
in (it is not erratic); an electrode most of whose channels are is the common cause. A
neighbour shares only 28 of its 52 channels, and once an electrode is named this test is
not made again (after a dead electrode, a neighbour's remaining channels can look rough).
Issue 18: 10x noise on one electrode's channels put their roughness at ~5x the median
channel's (the channels' own noise differs), so fewer than the majority crossed the
erratic threshold and the noise reached the images (and a false touch). A healthy sheet's
channel roughness scatters by tens of per cent over a check's frames, and a press near an
electrode moves its channels smoothly (no second difference).

:class:`FaultTolerantReconstructor` wraps any method's reconstructor
(:class:`~eit_skin.inverse.methods.Reconstructor`) and images with the measurements touching
faulty electrodes removed; the reconstructor caches what it needs per excluded-channel set
(reduced matrices, or Gauss-Newton's reduced first factorisation).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from eit_skin.inverse.one_step import reference_scale
from eit_skin.patch.material import CONDUCTANCE_RATIO_LIMIT
from eit_skin.patch.protocol import Protocol

if TYPE_CHECKING:
    from eit_skin.inverse.methods import Reconstructor

#: MAD -> standard deviation of a normal distribution.
_MAD_TO_STD = 1.4826


def bad_channels(
    frames: np.ndarray, reference: np.ndarray, saturation_v: float | None = None
) -> np.ndarray:
    """``[M]`` bool: channels non-finite (reference or any frame) or saturated in any frame."""
    v = np.atleast_2d(np.asarray(frames, dtype=np.float64))
    ref = np.asarray(reference, dtype=np.float64)
    bad = ~np.isfinite(ref) | ~np.isfinite(v).all(axis=0)
    if saturation_v is not None:
        with np.errstate(invalid="ignore"):
            bad |= (np.abs(v) >= saturation_v).any(axis=0) | (np.abs(ref) >= saturation_v)
    return bad


def spoiled_channels(
    frames: np.ndarray,
    reference: np.ndarray,
    threshold: float = 10.0,
    saturation_v: float | None = None,
) -> np.ndarray:
    """``[M]`` bool: channels bad, lost their signal or erratic over ``frames`` (module docstring).

    Args:
        frames: ``[T, M]`` (or ``[M]``) volts.
        reference: ``[M]`` volts.
        threshold: how many times the median channel roughness counts as erratic.
        saturation_v: ADC full scale, volts; saturated channels count as bad.
    """
    return _channel_state(frames, reference, threshold, saturation_v)[0]


def _channel_state(
    frames: np.ndarray,
    reference: np.ndarray,
    threshold: float = 10.0,
    saturation_v: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(spoiled [M] bool, roughness [M])``: roughness relative to the median channel's.

    ``roughness`` is each channel's robust noise over that of the median unspoiled channel
    (0 where undefined: one frame, or a noise-free median).
    """
    v = np.atleast_2d(np.asarray(frames, dtype=np.float64))
    ref = np.asarray(reference, dtype=np.float64)
    spoiled = bad_channels(v, ref, saturation_v)
    # channel by row [M, T]: each median below is then one sort of contiguous rows
    with np.errstate(invalid="ignore"):
        q = 1.0 + (v.T - ref[:, None]) * (np.sign(ref) / reference_scale(ref))[:, None]
    q[spoiled] = 0.0
    level = median_of_rows(q)
    spoiled |= (level < 1.0 / CONDUCTANCE_RATIO_LIMIT) | (level > CONDUCTANCE_RATIO_LIMIT)
    relative = np.zeros(spoiled.shape)
    if v.shape[0] > 1:
        steps = np.diff(q, n=min(2, v.shape[0] - 1), axis=1)  # [M, T-2]: a ramp's are 0
        noise = _MAD_TO_STD * median_of_rows(np.abs(steps - median_of_rows(steps)[:, None]))
        typical = float(median_of_rows(noise[None, ~spoiled])[0]) if (~spoiled).any() else 0.0
        spoiled |= noise > 1.0 / CONDUCTANCE_RATIO_LIMIT
        if typical > 0:
            spoiled |= noise > threshold * typical
            relative = noise / typical
    return spoiled, relative


@functools.lru_cache(maxsize=64)  # per protocol (compared by identity): each fault check
def shared_fraction(protocol: Protocol) -> float:
    """Largest fraction of one electrode's channels that touch another given electrode.

    ``max over i != j of |touching(i) & touching(j)| / |touching(i)|``: 28/52 for adjacent drive
    and measurement on 16 electrodes (a neighbour shares one drive pair, one measurement pair
    and two more channels). 0 for fewer than two electrodes.
    """
    touch = protocol.touching_table().astype(float)
    if touch.shape[0] < 2:
        return 0.0
    shared = touch @ touch.T  # [n_el, n_el] channels in common
    own = np.maximum(np.diag(shared), 1.0)
    np.fill_diagonal(shared, 0.0)
    return float((shared / own[:, None]).max())


def faulty_electrodes(
    frames: np.ndarray,
    reference: np.ndarray,
    protocol: Protocol,
    threshold: float = 10.0,
    saturation_v: float | None = None,
) -> np.ndarray:
    """Indices (int64, sorted) of the electrodes that explain the spoiled channels.

    Args:
        frames: ``[T, M]`` (or ``[M]``) volts.
        reference: ``[M]`` volts.
        protocol: the measurement protocol (which channels touch which electrode).
        threshold: how many times the median channel roughness counts as erratic.
        saturation_v: ADC full scale, volts; saturated channels count as bad.

    The rule (module docstring) names a dead electrode, never its healthy neighbours, and
    nothing for a load on a healthy sheet. For naming electrodes, a channel also counts as
    spoiled when it is ``sqrt(threshold)`` times rougher than the median channel (a
    **noisy electrode**, module docstring): only an electrode nearly all of whose channels
    are that rough is named.
    """
    spoiled, roughness = _channel_state(frames, reference, threshold, saturation_v)
    noisy = math.sqrt(threshold)
    spoiled = spoiled | (roughness > noisy)
    n_el = protocol.n_electrodes
    touch = protocol.touching_table()  # [n_el, M]
    majority = 0.5 * (1.0 + shared_fraction(protocol))
    faulty = np.zeros(n_el, dtype=bool)
    explained = np.zeros(spoiled.shape, dtype=bool)
    # the median roughness of the channels not touching each electrode: "the others"
    others = row_medians(roughness, ~touch)
    while True:
        remaining = touch & ~explained  # [n_el, M] channels still to judge
        n_left = remaining.sum(axis=1)
        n_spoiled = (remaining & spoiled).sum(axis=1)
        own = row_medians(roughness, remaining)
        # a noisy electrode (module docstring); only while none is named: after a dead
        # electrode, a neighbour's channels still to judge can look rough too
        rough = (others > 0) & (own > noisy * others) & ~faulty.any()
        candidate = ~faulty & (n_left > 0) & ((n_spoiled > majority * n_left) | rough)
        if not candidate.any():
            break
        worst = int(np.argmax(np.where(candidate, n_spoiled, -1)))
        faulty[worst] = True
        explained |= touch[worst]
    for i in np.flatnonzero(faulty)[::-1]:  # drop one all of whose channels the others touch
        others = faulty.copy()
        others[i] = False
        if others.any() and not (touch[i] & ~touch[others].any(axis=0)).any():
            faulty[i] = False
    return np.flatnonzero(faulty).astype(np.int64)


def median_of_rows(x: np.ndarray) -> np.ndarray:
    """``[R]``: the median of each row of ``x`` ``[R, T]``, equal to ``np.median(x, axis=1)``.

    The mean of the two middle values for an even ``T``, NaN for a row with a NaN. One sort
    of the contiguous rows instead of numpy's partition: the sort is vectorised and does not
    branch on the data, while the partition's branches, on fresh frames each fault check,
    made a median of 208 channels x 50 frames cost ~0.13 ms instead of ~0.014 ms.
    """
    ordered = np.sort(np.ascontiguousarray(x, dtype=np.float64), axis=1)  # NaN sort last
    n = ordered.shape[1]
    if n == 0:
        return np.full(ordered.shape[0], np.nan)
    # an even count: np.median's mean of the two, (a + b) / 2, is exactly 0.5 * (a + b)
    high = ordered[:, n // 2]
    middle = high if n % 2 else 0.5 * (ordered[:, n // 2 - 1] + high)
    return np.where(np.isnan(ordered[:, -1]), np.nan, middle)


def row_medians(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``[R]``: per row of ``rows`` ``[R, M]`` bool, the median of ``values`` ``[M]`` there.

    The mean of the two middle values for an even count; 0 for a row with none. One sort
    of ``[R, M]`` (the left-out entries sorted last as +inf), not a masked median.
    """
    ordered = np.sort(np.where(rows, values[None, :], np.inf), axis=1)
    n = rows.sum(axis=1)
    low = np.maximum(n - 1, 0) // 2
    middle = np.take_along_axis(
        ordered, np.stack([low, n // 2], axis=1).clip(max=rows.shape[1] - 1), 1
    )
    return np.where(n > 0, 0.5 * (middle[:, 0] + middle[:, 1]), 0.0)


def excluded_channels(
    frames: np.ndarray,
    reference: np.ndarray,
    protocol: Protocol,
    threshold: float = 10.0,
    saturation_v: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(electrodes, mask [M])``: faulty electrodes and every channel to leave out."""
    el = faulty_electrodes(frames, reference, protocol, threshold, saturation_v)
    mask = bad_channels(frames, reference, saturation_v)
    if el.size:
        mask = mask | protocol.touching(el)
    return el, mask


@dataclass
class FaultTolerantReconstructor:
    """Imaging (any method) that leaves out faulty electrodes' and bad channels' measurements.

    Attributes:
        reconstructor: the method, set up on all channels.
        protocol: the protocol it was built for.
        threshold: outlier factor for :func:`faulty_electrodes`.
        saturation_v: ADC full scale, volts, or ``None``.
    """

    reconstructor: Reconstructor
    protocol: Protocol
    threshold: float = 10.0
    saturation_v: float | None = None
    last_faulty: np.ndarray | None = None

    def reconstruct(self, frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """``[T, M]``/``[M]`` volts -> ``[T, N]``/``[N]`` float32 relative conductivity change."""
        el, mask = excluded_channels(
            frames, reference, self.protocol, self.threshold, self.saturation_v
        )
        self.last_faulty = el
        return self.reconstructor.reconstruct(frames, reference, excluded=mask)
