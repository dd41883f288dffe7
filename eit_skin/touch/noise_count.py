"""How well a learnt noise map is known: independent samples behind it, its START-bar margin.

A noise map calibrated from a few frames is wrong at some pixels, and a map of a smooth
image (the pooled image, the raw frames' filter) is wrong over the whole sheet together
(2026-11-27: 24 idle frames of the small disc's one-step NOSER image put the whole pooled
map at 0.85 of the noise of the next 20 s, single pixels down to 0.23). The bars are raised
by two standard errors of the estimate, and the map keeps learning, as a running mean while
it has seen few samples. The pooled maps are calibrated by standard deviations, the image's
noise map by robust MADs, which count for fewer samples. Why: docs/classifier.md, "START bar".
"""

from __future__ import annotations

import math

MAD_EFFICIENCY = 0.3675
"""Asymptotic efficiency of the median absolute deviation against the standard deviation
for Gaussian noise (variance of the estimate ``1.36 sigma^2 / n`` against ``sigma^2 / (2 n)``;
Rousseeuw & Croux, JASA 88, 1993: 37 %): a MAD from ``n`` samples is as precise as a standard
deviation from ``0.37 n``. Calibration maps are MADs (robust to a stray touch); learnt maps
are means of squares."""


class NoiseCount:
    """Independent samples behind a noise map, and how it learns from more.

    Args:
        frames: frames the map was calibrated from.
        sample_frames: consecutive frames per independent sample
            (:func:`~eit_skin.touch.contacts.noise_sample_frames`), >= 1.
        efficiency: of the calibration's estimator against a standard deviation:
            :data:`MAD_EFFICIENCY` for a robust MAD, 1 for a standard deviation.

    Attributes:
        samples: the standard-deviation-equivalent count behind the map.
    """

    def __init__(
        self, frames: float, sample_frames: float, efficiency: float = MAD_EFFICIENCY
    ) -> None:
        self.sample_frames = max(float(sample_frames), 1.0)
        self.samples = efficiency * float(frames) / self.sample_frames

    @property
    def inflation(self) -> float:
        """``1 + sqrt(2 / n)``: two standard errors of a noise estimate from ``n`` samples."""
        return 1.0 + math.sqrt(2.0 / max(self.samples, 1.0))

    def learn(self, alpha: float) -> float:
        """One more no-touch frame: the weight its square gets in the variance map.

        A running mean while fewer than ``2 / alpha`` samples were seen, then an exponential
        average of weight ``alpha``; the count is capped at ``2 / alpha`` samples (the
        exponential average's own). ``alpha`` in (0, 1].
        """
        step = 1.0 / self.sample_frames  # independent samples this frame adds
        weight = max(alpha, step / (self.samples + step))
        self.samples = min(self.samples + step, max(2.0 * step / alpha, 1.0))
        return weight

    def restart(self) -> None:
        """The images changed (an electrode left out of the imaging, or taken back).

        The map is of other images: it counts as one sample and is learnt again, fast.
        """
        self.samples = min(self.samples, 1.0)
