"""Pair patterns and trigonometric current patterns (:mod:`eit_skin.patch.protocol`)."""

from __future__ import annotations

import numpy as np


def trigonometric_currents(n: int) -> np.ndarray:
    """``[n - 1, n]`` trigonometric current patterns (board numbering, peak 1).

    Rows ``cos(k theta_b)`` for ``k = 1 .. n//2``, then ``sin(k theta_b)`` for
    ``k = 1 .. (n-1)//2``, ``theta_b = 2 pi b / n``; every row sums to zero.
    """
    theta = 2 * np.pi * np.arange(n) / n
    k_cos = np.arange(1, n // 2 + 1)
    k_sin = np.arange(1, (n - 1) // 2 + 1)
    rows = np.vstack([np.cos(np.outer(k_cos, theta)), np.sin(np.outer(k_sin, theta))])
    rows[np.abs(rows) < 1e-12] = 0.0  # exact zeros where cos/sin vanish
    return rows


def pattern_offset(pattern: str, skip: int, n: int) -> int:
    """Electrodes from the first to the second of a pair pattern's pairs (``n`` electrodes)."""
    if pattern == "adjacent":
        return 1
    if pattern == "opposite":
        return n // 2
    return skip + 1
