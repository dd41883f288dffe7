"""Press sessions of the real hydrogel recordings in data/real/ (one reader per file layout).

Shared by the benchmarks (``bench_press_calibration``, ``bench_multitouch``) and the tests
that use the same recordings; the layouts are written by data/real/README.md's converters.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from eit_skin.calibration.session import PressSession

REAL = Path(__file__).resolve().parents[2] / "data" / "real"


def load_real(name: str) -> dict[str, np.ndarray]:
    """Every array of ``data/real/<name>.npz`` (no pickles)."""
    with np.load(REAL / f"{name}.npz", allow_pickle=False) as d:
        return {k: d[k] for k in d.files}


def hydrogel_ohmc16_session() -> PressSession:
    """The 500 robot-arm presses of ``hydrogel_ohmc16``: each press's own unloaded frame."""
    path = REAL / "hydrogel_ohmc16.npz"
    d = load_real("hydrogel_ohmc16")
    return PressSession(
        d["reference"],
        d["downs"].astype(float),
        d["truth_xy"][:, 0],
        d["depth"],
        d["ups"].astype(float),
        str(path),
    )


def multitouch_single_presses(data: Mapping[str, np.ndarray] | None = None) -> PressSession:
    """The 500 single presses of ``hydrogel_multitouch`` (the two-probe session's calibration).

    ``data``: the recording's arrays when already loaded (:func:`load_real`).
    """
    d = load_real("hydrogel_multitouch") if data is None else data
    return PressSession(
        d["single_ups"].mean(axis=0).astype(float),
        d["single_downs"].astype(float),
        d["single_xy"],
        d["single_depth"],
        d["single_ups"].astype(float),
        "hydrogel_multitouch single presses",
    )
