"""The skin board's acquisition model: programmable gain, 12-bit ADC, 1000x oversampling.

Signal chain of one differential measurement ``v`` (V):

* an instrumentation amplifier of gain ``g`` (chosen from :data:`PGA_GAINS`) adds
  ``mid = 2^(bits-1)`` codes of offset, so the ADC input in codes is
  ``x = mid + g v / lsb_adc`` with ``lsb_adc = vref_v / 2^bits`` (3.3 V / 4096 = 0.806 mV);
  the representable range is ``v in [-mid, mid - 1] * lsb_v`` with ``lsb_v = lsb_adc / g``
  (:attr:`AdcModel.full_scale_v` = ``mid * lsb_v``);
* each of the ``oversampling`` conversions adds white input noise of ``noise_lsb`` codes rms
  and rounds to an integer code in ``[0, 2^bits - 1]``; the board reports the sum of the codes
  (``volts_per_count = lsb_v / oversampling`` on the wire).

With ``noise_lsb >= 0.5`` the noise dithers the quantiser, so the error of one conversion is
the noise plus an independent uniform rounding error (variance ``1/12`` code^2). The mean of
``N`` conversions is therefore simulated in one draw as ``x + Normal(0, (noise_lsb^2 + 1/12)
/ N)`` and rounded to the ``1/N``-code step of the sum: **the noise of a reported value is
``sqrt((noise_lsb^2 + 1/12) / N)`` codes** (1.0 LSB, N = 1000: 0.033 LSB rms). A channel
whose conversions reach a rail (``x`` within 3 noise sigma of ``0`` or ``2^bits - 1``) is
clipped there and flagged ``FLAG_SATURATED``.

The gain is the largest PGA gain for which the largest no-load value stays below
``headroom`` of the full scale (default 40 %), leaving room for touches that raise the
voltages (stretch lowers the conductance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from eit_skin.frames import FLAG_OK, FLAG_SATURATED

PGA_GAINS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)


@dataclass(frozen=True)
class AdcConfig:
    """Acquisition settings.

    Attributes:
        bits: ADC resolution.
        vref_v: ADC reference (input span), V.
        oversampling: conversions averaged per reported value.
        noise_lsb: input-referred white noise per conversion, codes rms (>= 0.5 to dither).
        gain: amplifier gain, or ``None`` to choose it from the no-load frame.
        headroom: fraction of the full scale the largest no-load value may use (auto gain).
    """

    bits: int = 12
    vref_v: float = 3.3
    oversampling: int = 1000
    noise_lsb: float = 1.0
    gain: float | None = None
    headroom: float = 0.4

    def __post_init__(self) -> None:
        if not 2 <= self.bits <= 24:
            raise ValueError(f"bits: expected 2..24, got {self.bits}")
        if not self.vref_v > 0:
            raise ValueError(f"vref_v: must be > 0 V, got {self.vref_v}")
        if self.oversampling < 1:
            raise ValueError(f"oversampling: must be >= 1, got {self.oversampling}")
        if not self.noise_lsb >= 0:
            raise ValueError(f"noise_lsb: must be >= 0, got {self.noise_lsb}")
        if self.gain is not None and not self.gain > 0:
            raise ValueError(f"gain: must be > 0, got {self.gain}")
        if not 0 < self.headroom <= 1:
            raise ValueError(f"headroom: must be in (0, 1], got {self.headroom}")

    def with_full_scale(self, full_scale_v: float) -> AdcConfig:
        """These settings with the gain that makes the full scale ``full_scale_v`` V.

        ``full_scale_v = 2^(bits-1) lsb_adc / gain = vref_v / (2 gain)``: a patch layer's
        stated ``full_scale_v`` is the simulated board's.
        """
        return replace(self, gain=self.vref_v / (2.0 * float(full_scale_v)))


class AdcModel:
    """Quantise, add noise and clip frames like the board.

    Args:
        config: acquisition settings.
        reference_v: ``[M]`` no-load voltages, V (used for the automatic gain).
    """

    def __init__(self, config: AdcConfig, reference_v: np.ndarray) -> None:
        self.config = config
        self.mid = 2 ** (config.bits - 1)
        self.top = 2**config.bits - 1
        lsb_adc = config.vref_v / 2**config.bits
        if config.gain is None:
            peak = float(np.max(np.abs(reference_v)))
            fits = [g for g in PGA_GAINS if peak * g / lsb_adc <= config.headroom * self.mid]
            self.gain = fits[-1] if fits else PGA_GAINS[0]
        else:
            self.gain = float(config.gain)
        self.lsb_v = lsb_adc / self.gain
        self.noise_codes = math.sqrt((config.noise_lsb**2 + 1.0 / 12.0) / config.oversampling)

    @property
    def full_scale_v(self) -> float:
        """Largest magnitude representable, V (the rails are ``-full_scale_v`` and ~``+``)."""
        return self.mid * self.lsb_v

    @property
    def volts_per_count(self) -> float:
        """Volts per unit of the summed code, V (``lsb_v / oversampling``)."""
        return self.lsb_v / self.config.oversampling

    @property
    def noise_v(self) -> float:
        """Noise of one reported value, V rms."""
        return self.noise_codes * self.lsb_v

    def snr_db(self, reference_v: np.ndarray) -> tuple[float, float]:
        """(median, minimum) over channels of ``20 log10(|v| / noise_v)``, dB."""
        snr = 20.0 * np.log10(np.maximum(np.abs(reference_v), 1e-300) / self.noise_v)
        return float(np.median(snr)), float(np.min(snr))

    def rail_v(self, positive: bool = True) -> float:
        """Voltage reported for a channel pinned to a rail, V."""
        return (self.top - self.mid) * self.lsb_v if positive else -self.mid * self.lsb_v

    def convert(
        self, volts: np.ndarray, rng: np.random.Generator | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reported voltages and flags for true voltages ``[..., M]`` (V).

        ``rng=None`` gives the noise-free quantised value. Returns (volts float64, flags uint8),
        both of the input's shape.
        """
        x = self.mid + np.asarray(volts, dtype=np.float64) / self.lsb_v
        sigma_sample = self.config.noise_lsb
        near = 3.0 * max(sigma_sample, 0.5)
        saturated = (x >= self.top - near) | (x <= near)
        if rng is not None:
            x = x + rng.standard_normal(x.shape) * self.noise_codes
        n = self.config.oversampling
        x = np.clip(np.round(x * n) / n, 0.0, float(self.top))
        flags = np.where(saturated, FLAG_SATURATED, FLAG_OK).astype(np.uint8)
        return (x - self.mid) * self.lsb_v, flags
