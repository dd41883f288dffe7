"""Baseline and noise following: what the pressure image looks like while nothing touches.

The first ``calibration_s`` of frames give a per-pixel baseline and noise map (a
:class:`Background` is built from them); afterwards no-touch frames keep teaching both (time
constants ``baseline_tau_s``, ``noise_tau_s``), and every image loses its sheet-wide offset
(the median away from the latest contacts) before segmentation. Why each rule: docs/classifier.md.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import ndimage

from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import (
    ContactSegmenter,
    estimate_noise,
    estimate_noise_map,
    noise_sample_frames,
)
from eit_skin.touch.noise_count import NoiseCount


def running_mean(stack: np.ndarray, n: int) -> np.ndarray:
    """``[T - n + 1, ...]`` means of ``n`` consecutive frames of ``stack`` ``[T, ...]``."""
    if n <= 1:
        return stack
    c = np.cumsum(np.concatenate([np.zeros_like(stack[:1]), stack]), axis=0)
    return (c[n:] - c[:-n]) / n


def _nan_median(stack: np.ndarray) -> np.ndarray:
    """Per-pixel median of ``stack`` ``[T, H, W]``, 0 where a pixel is never finite."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels outside the sheet
        median = np.nanmedian(stack, axis=0)
    return np.where(np.isfinite(median), median, 0.0)


class Background:
    """Baseline, noise map and sheet-wide offset of one pressure image stream (and stretch).

    Attributes:
        baseline: ``[H, W]`` no-touch pressure image, Pa.
        stretch_baseline: ``[H, W]`` no-touch stretch image (strain), or None.
        segmenter: the contact segmenter, holding the noise map ``noise_sigma`` (Pa).
        pressure_noise_pa: overall pressure image noise, Pa.
        stretch_noise: overall stretch image noise (strain), or None.
        noise_var: ``[H, W]`` learnt noise variance of the averaged image, Pa^2, or None when
            the noise is fixed (given, or too few calibration frames to map it).
    """

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        config: ClassifierConfig,
        stack: np.ndarray,
        stretch_stack: np.ndarray | None = None,
        *,
        pressure_noise_pa: float | None = None,
        stretch_noise: float | None = None,
        margin_px: int = 0,
    ) -> None:
        """Calibrate on ``stack`` ``[T, H, W]`` no-touch pressure images, Pa (NaN outside).

        ``stretch_stack``: the stretch images of the same frames, or None; a noise given
        (not None or 0) is used instead of its estimate; ``margin_px``: pixels around the
        latest contacts left out of the sheet offset.
        """
        self.config = config
        self.baseline = _nan_median(stack)
        n_avg = min(config.average_frames, len(stack))
        averaged = running_mean(stack, n_avg)  # what the segmentation will look at
        self.noise_var: np.ndarray | None = None
        self.noise_floor = 0.0
        self.count = NoiseCount(0, config.average_frames)  # samples behind the noise map
        self.pressure_noise_pa = pressure_noise_pa
        if pressure_noise_pa:
            sigma = pressure_noise_pa / math.sqrt(n_avg)
        else:
            self.pressure_noise_pa = estimate_noise(stack)
            if len(averaged) >= 3:
                # conservative start (few frames): the larger of the smoothed map and each
                # pixel's own spread; then the noise keeps being learnt (follow_noise)
                sigma = np.maximum(
                    estimate_noise_map(averaged, window=config.noise_window),
                    estimate_noise_map(averaged, window=1),
                )
                self.noise_var = sigma**2
                self.noise_floor = config.noise_floor_fraction * estimate_noise(averaged)
                self.count = NoiseCount(
                    len(averaged), noise_sample_frames(averaged - self.baseline, n_avg)
                )
            else:
                sigma = estimate_noise(averaged)
        self.stretch_baseline = None
        self.stretch_noise = stretch_noise
        if stretch_stack is not None:
            self.stretch_baseline = _nan_median(stretch_stack)
            if stretch_noise is None:
                self.stretch_noise = estimate_noise(stretch_stack)
        self.segmenter = ContactSegmenter(x, y, sigma, config.segmentation)
        self.margin_px = margin_px
        self.touched = np.zeros(self.baseline.shape, dtype=bool)  # last contacts, grown

    @property
    def noise_sigma(self) -> np.ndarray | float:
        """The averaged image's noise, Pa: ``[H, W]`` map or a scalar."""
        return self.segmenter.noise_sigma

    def offset(self, image: np.ndarray) -> float:
        """Sheet-wide offset of a baseline-free ``image`` ``[H, W]``: its median away from touch.

        sigma0 drifts over the whole sheet (temperature, humidity) while touches keep the
        baseline from following it; a touch covers far less than half of the rest of the
        sheet, so the median over the pixels away from the latest contacts
        (``offset_margin``) is that offset (over the whole sheet if the contacts leave less
        than a quarter of it). Only its part beyond ``offset_deadband`` noise sigmas is
        returned: a smaller one moves no pixel across the contact thresholds by itself.
        """
        ok = np.isfinite(image)
        free = ok & ~self.touched
        if np.count_nonzero(free) < 0.25 * np.count_nonzero(ok):
            free = ok
        if not free.any():
            return 0.0
        offset = float(np.median(image[free]))
        band = self.config.offset_deadband * float(np.median(self.segmenter.noise_sigma))
        return math.copysign(max(abs(offset) - band, 0.0), offset)

    def note_contacts(self, mask: np.ndarray, any_contact: bool) -> None:
        """The latest frame's contact pixels ``mask`` ``[H, W]``, kept out of the next offset."""
        self.touched = mask
        if self.margin_px and any_contact:
            self.touched = ndimage.binary_dilation(mask, iterations=self.margin_px)

    def stands_out(self, signal: np.ndarray, mask: np.ndarray) -> bool:
        """Whether a contact pixel of ``signal`` ``[H, W]`` (``mask``) clears the START bar.

        The bar is ``k_high`` times the noise map's uncertainty
        (:attr:`~eit_skin.touch.noise_count.NoiseCount.inflation`: x1.67 after a 0.5 s
        calibration, x1.06 after ~20 s of learning): a pixel whose estimate is half its true
        noise makes contacts out of noise. Segmentation and shapes keep the plain map.
        """
        if self.noise_var is None:
            return True
        bar = self.config.segmentation.k_high * self.count.inflation
        with np.errstate(invalid="ignore", divide="ignore"):
            z = signal[mask] / self.segmenter.noise_sigma[mask]
        return bool(np.any(z >= bar))

    def follow(self, dt: float, pressure: np.ndarray, stretch: np.ndarray | None) -> None:
        """Move the baselines towards a no-touch frame (time constant ``baseline_tau_s``)."""
        alpha = 1.0 - math.exp(-dt / self.config.baseline_tau_s)
        ok = np.isfinite(pressure)
        self.baseline[ok] += alpha * (pressure[ok] - self.baseline[ok])
        if stretch is not None and self.stretch_baseline is not None:
            ok = np.isfinite(stretch)
            self.stretch_baseline[ok] += alpha * (stretch[ok] - self.stretch_baseline[ok])

    def follow_noise(self, alpha: float, signal: np.ndarray) -> None:
        """Per-pixel noise variance: learn ``signal**2`` (weight ``alpha`` once learnt).

        By :meth:`~eit_skin.touch.noise_count.NoiseCount.learn`: a running mean while few
        samples were seen, then an exponential average. ``signal`` ``[H, W]``: a no-touch
        averaged image minus baseline and offset, Pa. The short calibration cannot see every
        pixel's noise well; this keeps learning it.
        """
        if self.noise_var is None:
            return
        weight = self.count.learn(alpha)
        ok = np.isfinite(signal)
        self.noise_var[ok] += weight * (signal[ok] ** 2 - self.noise_var[ok])
        self.segmenter.noise_sigma = np.maximum(np.sqrt(self.noise_var), self.noise_floor)
