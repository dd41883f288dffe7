"""Synthetic pressure images for classifier tests: Gaussian blobs plus white noise.

A blob of amplitude ``a`` Pa and width ``w`` m at ``(x, y)`` is ``a exp(-r^2 / (2 w^2))``; the
noise is white, ``sigma`` Pa per pixel; pixels outside a disc of radius ``R`` are NaN (the sheet).
"""

from __future__ import annotations

import numpy as np

PIXELS = 48
RADIUS_M = 0.04
X = np.linspace(-RADIUS_M, RADIUS_M, PIXELS)
Y = np.linspace(-RADIUS_M, RADIUS_M, PIXELS)
XX, YY = np.meshgrid(X, Y)
INSIDE = XX**2 + YY**2 <= RADIUS_M**2
SIGMA_PA = 10.0
WIDTH_M = 0.005


def blobs(centres, amplitude_pa: float = 5000.0, width_m: float = WIDTH_M) -> np.ndarray:
    """``[H, W]`` noise-free image of blobs at ``centres`` ([k, 2] m), NaN outside the sheet."""
    image = np.zeros(XX.shape)
    for cx, cy in np.reshape(centres, (-1, 2)):
        image += amplitude_pa * np.exp(-((XX - cx) ** 2 + (YY - cy) ** 2) / (2 * width_m**2))
    return np.where(INSIDE, image, np.nan)


def sequence(script, duration_s: float, rate_hz: float = 50.0, seed: int = 0):
    """``(t [T], images [T, H, W])``: ``script(t) -> (centres [k, 2], amplitude)`` plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(duration_s * rate_hz)) / rate_hz
    frames = []
    for ti in t:
        centres, amplitude = script(float(ti))
        image = blobs(centres, amplitude) if len(centres) and amplitude > 0 else blobs([], 0)
        frames.append(image + SIGMA_PA * rng.standard_normal(image.shape))
    return t, np.asarray(frames, dtype=np.float32)


def envelope(t: float, start: float, end: float, ramp: float = 0.1) -> float:
    """0..1: linear ramp up over ``ramp`` s from ``start``, hold, ramp down to ``end``."""
    return float(np.clip(min((t - start) / ramp, (end - t) / ramp), 0.0, 1.0))
