"""The reference frame's health and the measured per-channel noise of difference imaging.

Both act on the relative data ``dv = (v - v_ref) / s_ref`` of
:func:`eit_skin.inverse.one_step.relative_difference` and are the same online (the no-load
frames :class:`~eit_skin.pipeline.processor.LayerProcessor` captures) and offline.

Reference check (:func:`check_reference`), per channel ``m``:

* **unusable value**: ``v_ref`` NaN, +-Inf or exactly 0;
* **near zero**: ``|v_ref| < REFERENCE_FLOOR * rms(v_ref)`` (the floor of ``s_ref``: below
  it the relative change is not a relative change any more);
* **sign flip**: the model of the sheet (homogeneous forward voltages, when given) predicts
  the other sign with a magnitude of at least :data:`SIGN_TRUSTED` times its median
  magnitude (so the sign is the sheet's, not a near-zero channel's accident).

Those channels are excluded, each named by channel, injection and electrodes. More than
:data:`MAX_BAD_FRACTION` of the channels bad (every channel for an all-zero reference) is an
unusable reference: :class:`UnusableReferenceError`.

Noise (:func:`estimate_channel_noise`), volts per channel, first available of:

1. ``K >= 2`` repeated no-load frames: sample standard deviation over the frames;
2. ``T >= MIN_DIFFERENCE_FRAMES`` frames: robust scale of consecutive differences,
   ``1.4826 * MAD(v[t+1] - v[t]) / sqrt(2)`` (a moving object changes a minority of steps,
   which the median ignores);
3. the reference alone: reciprocity. Driving pair ``a`` and measuring pair ``b`` reads what
   driving ``b`` and measuring ``a`` reads, so ``|v_m - v_r| / sqrt(2)`` of every channel with
   a reciprocal partner ``r`` is a one-sample noise estimate (it also holds contact and
   electrode-placement error, which images see as noise too).

Channel weights (:func:`channel_scale`): the relative noise ``sigma_m / s_ref,m`` divided by
its median over the usable channels, floored at 1: weighted least squares with
``Sigma = diag(scale^2)``, and no channel is trusted more than the median channel (a
one-sample estimate can be small by chance). Scale-free: volts, gain and the noise level
cancel; only the channels' spread relative to each other counts.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from eit_skin.inverse.one_step import REFERENCE_FLOOR, reference_scale
from eit_skin.patch.protocol import Protocol

#: More than this fraction of channels bad: the reference is unusable (an error).
MAX_BAD_FRACTION = 0.5
#: Model magnitude (fraction of its median) from which the model's sign is trusted.
SIGN_TRUSTED = 0.1
#: Fewest frames for the consecutive-difference noise estimate.
MIN_DIFFERENCE_FRAMES = 10
#: MAD -> standard deviation of a normal distribution.
_MAD_TO_STD = 1.4826


class UnusableReferenceError(ValueError):
    """The reference frame cannot be imaged against (all zero, or most channels bad)."""


@dataclass(frozen=True)
class ReferenceCheck:
    """What :func:`check_reference` found.

    Attributes:
        excluded: bool ``[M]`` channels left out because of their reference value.
        problems: one line per excluded channel: channel, injection, electrodes, reason.
    """

    excluded: np.ndarray
    problems: tuple[str, ...]

    @property
    def summary(self) -> str:
        """One line: how many channels are excluded and the first few reasons."""
        n = int(self.excluded.sum())
        if n == 0:
            return "reference: all channels usable"
        shown = "; ".join(self.problems[:3]) + ("; ..." if n > 3 else "")
        return f"reference: {n} of {self.excluded.size} channels excluded ({shown})"


def describe_channel(protocol: Protocol, m: int) -> str:
    """``channel 17 (injection 1: 1->2, measure 4-5)``: where a channel comes from."""
    k, plus, minus = (int(x) for x in protocol.measurements[m])
    source, sink = (int(x) for x in protocol.injections[k])
    drive = f"{source}->{sink}" if protocol.pair_drive else "current pattern"
    return f"channel {m} (injection {k}: {drive}, measure {plus}-{minus})"


def check_reference(
    reference: np.ndarray, protocol: Protocol, model_voltages: np.ndarray | None = None
) -> ReferenceCheck:
    """Check a reference ``[M]`` V channel by channel (rules in the module docstring).

    Args:
        reference: ``[M]`` no-load frame, volts (any unit).
        protocol: the layer's protocol (``M`` channels), for the diagnostics.
        model_voltages: ``[M]`` homogeneous model voltages for the sign check, or None.

    Raises:
        UnusableReferenceError: all channels zero/non-finite, or more than
            :data:`MAX_BAD_FRACTION` of them bad.
        ValueError: wrong shape.
    """
    ref = np.asarray(reference, dtype=np.float64)
    m = protocol.n_measurements
    if ref.shape != (m,):
        raise ValueError(f"reference must be [{m}] volts, got shape {ref.shape}")
    finite = np.isfinite(ref)
    usable = finite & (ref != 0)
    if not usable.any():
        raise UnusableReferenceError(f"reference: all {m} channels are zero or non-finite")
    rms = float(np.sqrt(np.mean(ref[usable] ** 2)))
    with np.errstate(invalid="ignore"):
        near_zero = usable & (np.abs(ref) < REFERENCE_FLOOR * rms)
    flipped = np.zeros(m, dtype=bool)
    if model_voltages is not None:
        model = np.asarray(model_voltages, dtype=np.float64)
        trusted = np.abs(model) >= SIGN_TRUSTED * np.median(np.abs(model))
        flipped = usable & trusted & (np.sign(ref) == -np.sign(model))
    reasons = np.full(m, "", dtype=object)
    reasons[~finite] = "reference is NaN/Inf"
    reasons[finite & (ref == 0)] = "reference is 0"
    reasons[near_zero] = "reference near zero"
    reasons[flipped & ~near_zero] = "reference has the wrong sign"
    excluded = reasons != ""
    problems = tuple(
        f"{describe_channel(protocol, int(i))}: {reasons[i]}" for i in np.flatnonzero(excluded)
    )
    if excluded.sum() > MAX_BAD_FRACTION * m:
        raise UnusableReferenceError(
            f"reference: {int(excluded.sum())} of {m} channels unusable (more than "
            f"{MAX_BAD_FRACTION:.0%}), e.g. {problems[0]}"
        )
    return ReferenceCheck(excluded, problems)


@dataclass(frozen=True)
class ChannelNoise:
    """Measured noise per channel.

    Attributes:
        sigma_v: ``[M]`` noise standard deviation of one frame, volts (NaN: unknown).
        source: how it was measured (one of the three rules of the module docstring).
    """

    sigma_v: np.ndarray
    source: str

    def relative(self, reference: np.ndarray) -> np.ndarray:
        """``[M]`` noise of the relative data ``dv`` (dimensionless)."""
        with np.errstate(invalid="ignore"):
            return self.sigma_v / reference_scale(reference)


def reciprocal_partners(protocol: Protocol) -> tuple[np.ndarray, np.ndarray]:
    """``([M] partner index or -1, [M] +-1 sign)``: ``v_m = sign * v_partner`` by reciprocity.

    Only pair drives have reciprocal partners (a multi-electrode pattern is not a pair).
    """
    if not protocol.pair_drive:
        m = protocol.n_measurements
        return np.full(m, -1, dtype=np.int64), np.ones(m, dtype=np.int64)
    inj = protocol.injections
    meas = protocol.measurements
    drive = inj[meas[:, 0]]  # [M, 2] (source, sink)
    pairs = meas[:, 1:]  # [M, 2] (plus, minus)
    n = protocol.n_electrodes
    # key of an unordered (drive pair, measure pair); orientation gives the sign
    d_lo, d_hi = drive.min(1), drive.max(1)
    p_lo, p_hi = pairs.min(1), pairs.max(1)
    d_sign = np.where(drive[:, 0] < drive[:, 1], 1, -1)
    p_sign = np.where(pairs[:, 0] < pairs[:, 1], 1, -1)
    key = (d_lo * n + d_hi) * n * n + p_lo * n + p_hi
    swapped = (p_lo * n + p_hi) * n * n + d_lo * n + d_hi
    order = np.argsort(key, kind="stable")
    pos = np.searchsorted(key[order], swapped)
    pos = np.minimum(pos, len(key) - 1)
    found = key[order][pos] == swapped
    partner = np.where(found, order[pos], -1)
    sign = np.where(found, d_sign * p_sign * d_sign[partner] * p_sign[partner], 1)
    partner[partner == np.arange(len(key))] = -1  # a channel is not its own partner
    return partner, sign


def difference_noise(frames: np.ndarray) -> np.ndarray:
    """``[M]`` per-channel noise, volts, of ``frames`` ``[T >= 2, M]`` V (rule 2 above).

    ``1.4826 * MAD(v[t+1] - v[t]) / sqrt(2)``; NaN steps are ignored, a channel without any
    gets NaN.
    """
    steps = np.diff(np.asarray(frames, dtype=np.float64), axis=0)
    steps = np.where(np.isfinite(steps), steps, np.nan)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN channel: NaN
        mad = np.nanmedian(np.abs(steps - np.nanmedian(steps, axis=0)), axis=0)
    return _MAD_TO_STD * mad / np.sqrt(2.0)


def estimate_channel_noise(
    reference: np.ndarray,
    protocol: Protocol,
    reference_frames: np.ndarray | None = None,
    frames: np.ndarray | None = None,
) -> ChannelNoise | None:
    """Per-channel noise, volts, by the first rule that applies (module docstring).

    Args:
        reference: ``[M]`` no-load frame, volts.
        protocol: the layer's protocol (reciprocal partners).
        reference_frames: ``[K, M]`` repeated no-load frames, volts, or None.
        frames: ``[T, M]`` measured frames, volts, or None.

    Returns:
        None when no rule applies (no repeated frames, too few frames, no reciprocal pair).
    """
    ref = np.asarray(reference, dtype=np.float64)
    if reference_frames is not None and len(reference_frames) >= 2:
        stack = np.asarray(reference_frames, dtype=np.float64)
        with warnings.catch_warnings():  # a channel flagged in all but one frame: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            sigma = np.nanstd(np.where(np.isfinite(stack), stack, np.nan), axis=0, ddof=1)
        return ChannelNoise(sigma, f"{len(stack)} repeated reference frames")
    if frames is not None and len(frames) >= MIN_DIFFERENCE_FRAMES:
        return ChannelNoise(
            difference_noise(frames), f"differences of {len(frames)} consecutive frames"
        )
    partner, sign = reciprocal_partners(protocol)
    has = partner >= 0
    if not has.any():
        return None
    sigma = np.full(ref.shape, np.nan)
    sigma[has] = np.abs(ref[has] - sign[has] * ref[partner[has]]) / np.sqrt(2.0)
    return ChannelNoise(sigma, f"reciprocity of the reference ({int(has.sum())} channels)")


def channel_scale(relative_sigma: np.ndarray, usable: np.ndarray | None = None) -> np.ndarray:
    """``[M]`` noise scale of each channel: ``sigma / median(sigma)`` floored at 1.

    ``usable``: bool ``[M]`` channels the median is taken over (default: finite ones).
    Unknown (NaN) or non-positive noise gets 1, as does every channel when the median is 0.
    """
    sigma = np.asarray(relative_sigma, dtype=np.float64)
    good = np.isfinite(sigma) & (sigma > 0)
    if usable is not None:
        good &= np.asarray(usable, dtype=bool)
    if not good.any():
        return np.ones_like(sigma)
    median = float(np.median(sigma[good]))
    with np.errstate(invalid="ignore"):
        scale = np.where(np.isfinite(sigma), sigma / median, 1.0)
    return np.maximum(scale, 1.0)
