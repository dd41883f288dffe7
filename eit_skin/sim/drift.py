"""Slow drift of a layer's background conductance (temperature), as the simulator applies it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DriftModel:
    """Slow, smooth drift of the background conductance (temperature).

    ``d(t) = rate_per_min * t / 60 + wobble * sin(2 pi t / period_s + phase)``; sigma0 becomes
    ``sigma0 (1 + d)``, applied as the voltage gain ``1 / (1 + d)`` (exact for the sheet,
    ignoring the contact impedance's share of the voltages).
    """

    rate_per_min: float = 0.003
    wobble: float = 0.0005
    period_s: float = 120.0
    phase: float = 0.0

    @classmethod
    def random(cls, seed: int) -> DriftModel:
        """Rate 0.1-0.5 %/min of random sign, 0.05 % wobble of random phase (seeded)."""
        rng = np.random.default_rng([int(seed), 0xD21F7])
        rate = float(rng.uniform(0.001, 0.005)) * (1 if rng.random() < 0.5 else -1)
        return cls(rate, 0.0005, 120.0, float(rng.uniform(0, 2 * math.pi)))

    def offset(self, t: float) -> float:
        """Relative change of sigma0 at ``t`` s."""
        wobble = self.wobble * (math.sin(2 * math.pi * t / self.period_s + self.phase))
        return self.rate_per_min * t / 60.0 + wobble - self.wobble * math.sin(self.phase)


NO_DRIFT = DriftModel(0.0, 0.0)
"""No drift: the background conductance stays at sigma0."""
