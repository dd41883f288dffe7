"""What the simulator produces: one frame of a layer, a layer's frames, a whole recording."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.io.npz import save_frames_npz
from eit_skin.sim.scenario import TouchTruth


@dataclass(frozen=True)
class SimFrame:
    """One simulated drive cycle of one layer.

    Attributes:
        voltages_v: ``[M]`` float64 reported voltages, V, protocol order.
        flags: ``[M]`` uint8 ``FLAG_*`` bits (1 = saturated).
        t_s: acquisition time from the start of the scenario, s.
    """

    voltages_v: np.ndarray
    flags: np.ndarray
    t_s: float


@dataclass(frozen=True, eq=False)
class LayerRecording:
    """All frames of one layer.

    Attributes:
        frames: ``[T, M]`` float64 V.
        flags: ``[T, M]`` uint8.
        reference: ``[M]`` V, mean of the frames before the first touch (or posture change), or
            the noise-free quantised no-load frame when there is none (``reference_kind``).
        reference_kind: ``"pre-touch mean of N frames"`` or ``"noise-free"``.
        noise_free_reference: ``[M]`` V, exact no-load forward voltages.
    """

    frames: np.ndarray
    flags: np.ndarray
    reference: np.ndarray
    reference_kind: str
    noise_free_reference: np.ndarray


@dataclass(frozen=True, eq=False)
class SimulatedRecording:
    """Frames of every layer plus the ground truth."""

    t: np.ndarray
    layers: dict[str, LayerRecording]
    truth: tuple[TouchTruth, ...]
    posture: tuple[tuple[float, float], ...]
    meta: dict[str, Any] = field(default_factory=dict)

    def save(self, out_dir: str | Path) -> list[Path]:
        """Write ``<layer>.npz`` (reference, frames, t) and ``truth.json``; returns the paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name, rec in self.layers.items():
            path = out / f"{name}.npz"
            save_frames_npz(path, rec.reference, rec.frames, self.t)
            written.append(path)
        doc = {
            **self.meta,
            "n_frames": len(self.t),
            "layers": {
                name: {**self.meta.get("layers", {}).get(name, {}), "reference": rec.reference_kind}
                for name, rec in self.layers.items()
            },
            "saturated_values": {
                name: int(rec.flags.astype(bool).sum()) for name, rec in self.layers.items()
            },
            "touches": [tr.to_dict() for tr in self.truth],
            "posture": [list(p) for p in self.posture],
        }
        path = out / "truth.json"
        path.write_text(json.dumps(doc, indent=1) + "\n")
        written.append(path)
        return written
