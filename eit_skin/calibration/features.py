"""Press features: a frame's relative change, split into a unit pattern and a magnitude.

See :mod:`eit_skin.calibration.localiser` for how the localiser (and its physics prior,
:mod:`eit_skin.calibration.physics_prior`) use them.
"""

from __future__ import annotations

import numpy as np


def relative_change(frames: np.ndarray, baselines: np.ndarray) -> np.ndarray:
    """``[T, M]`` ``(v - v_ref) / |v_ref|`` of ``frames`` [T, M]; ``baselines`` [M] or [T, M]."""
    frames = np.asarray(frames, float)
    baselines = np.asarray(baselines, float)
    return (frames - baselines) / np.abs(baselines)


def split_features(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(``[T, M]`` unit pattern ``q / |q|``, ``[T]`` log-magnitude ``log |q|``) of ``q`` [T, M]."""
    norm = np.linalg.norm(q, axis=1)
    norm = np.where(norm > 0, norm, np.finfo(float).tiny)
    return q / norm[:, None], np.log(norm)
