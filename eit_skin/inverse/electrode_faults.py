"""Electrode and channel faults: detect them from frames, keep imaging without them.

Channel checks (per frame block ``[T, M]`` volts):
    * non-finite (NaN/Inf) in the reference or any frame;
    * saturated: ``|v| >= saturation_v`` (the ADC's full scale) in any frame.

Electrode checks (robust statistics over electrodes, measurements grouped by
:meth:`Protocol.touching`):
    For electrode ``i`` the score is the median over the channels that touch it
    (as drive or measurement electrode) of the per-channel noise level
    ``std_t(v) / s_ref`` relative to the median over all channels. A disconnected
    electrode makes every channel it touches large/erratic (floating input) or,
    when it is driven, makes the whole injection nonsense, so those channels share a
    large score; a good electrode's channels look like everyone else's. An electrode
    is flagged when its score exceeds ``threshold`` times the median electrode score
    (and the channels' mean relative deviation from the reference is also checked the
    same way, which catches a dead electrode in a single frame).

:class:`FaultTolerantReconstructor` wraps any method's reconstructor
(:class:`~eit_skin.inverse.methods.Reconstructor`) and images with the measurements touching
faulty electrodes removed; the reconstructor caches what it needs per excluded-channel set
(reduced matrices, or Gauss-Newton's reduced first factorisation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from eit_skin.inverse.one_step import reference_scale
from eit_skin.patch.protocol import Protocol

if TYPE_CHECKING:
    from eit_skin.inverse.methods import Reconstructor


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


def faulty_electrodes(
    frames: np.ndarray,
    reference: np.ndarray,
    protocol: Protocol,
    threshold: float = 10.0,
    saturation_v: float | None = None,
    min_deviation: float = 0.2,
) -> np.ndarray:
    """Indices (int64, sorted) of electrodes whose channels are outliers.

    Args:
        frames: ``[T, M]`` (or ``[M]``) volts.
        reference: ``[M]`` volts.
        protocol: the measurement protocol (which channels touch which electrode).
        threshold: how many times the median electrode score counts as faulty.
        saturation_v: ADC full scale, volts; saturated channels count as bad.
        min_deviation: a level outlier must also deviate from the reference by at least
            this fraction (a touch changes channels by a few per cent, a dead electrode
            by ~100 %).
    """
    v = np.atleast_2d(np.asarray(frames, dtype=np.float64))
    ref = np.asarray(reference, dtype=np.float64)
    n_el = protocol.n_electrodes
    touch = np.stack([protocol.touching([i]) for i in range(n_el)])  # [n_el, M]
    chan_bad = bad_channels(v, ref, saturation_v)
    scale = reference_scale(ref)
    with np.errstate(invalid="ignore"):
        dev = np.abs(v - ref) / scale  # [T, M]
    dev = np.where(np.isfinite(dev), dev, np.inf)
    # per-channel scores; inf for broken channels
    level = np.median(dev, axis=0)
    noise = np.std(np.where(np.isfinite(dev), dev, 0.0), axis=0) if v.shape[0] > 1 else None
    level[chan_bad] = np.inf
    faulty = np.zeros(n_el, dtype=bool)
    scores = [(level, min_deviation)] + ([] if noise is None else [(noise, 0.0)])
    # Peel off one electrode at a time: the worst electrode's channels are removed before
    # the others are scored again, so its neighbours (which share half of its channels)
    # are not flagged with it.
    for _ in range(n_el - 1):
        remaining = ~(touch[faulty].any(axis=0)) if faulty.any() else np.ones(v.shape[1], bool)
        worst, worst_ratio = -1, 1.0
        for score_per_channel, floor in scores:
            s = np.where(np.isfinite(score_per_channel), score_per_channel, 1e30)
            if not remaining.any():
                break
            med_all = max(float(np.median(s[remaining])), 1e-12)
            for i in np.flatnonzero(~faulty):
                sel = touch[i] & remaining
                if not sel.any():
                    continue
                el_score = float(np.median(s[sel]))
                ratio = el_score / med_all
                if ratio > threshold and el_score > floor and ratio > worst_ratio:
                    worst, worst_ratio = i, ratio
        if worst < 0:
            break
        faulty[worst] = True
    return np.flatnonzero(faulty).astype(np.int64)


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
