"""The small test disc (:func:`~test.support.patch_copies.small_disc_patch`) built into an
imager, with its no-load frame and the frame of one pressed spot (forward model, no noise)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.fem.forward import ForwardModel
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import Layer
from eit_skin.pipeline.builder import LayerImager
from test.support.patch_copies import small_disc_patch

PRESS_M = (0.015, 0.01)
"""Centre of the pressed spot, m."""
PRESS_RADIUS_M = 0.008
"""Radius of the pressed spot, m."""


@dataclass(frozen=True)
class PressedDisc:
    """The disc's patch file, layer and imager; ``unloaded_v`` / ``pressed_v``: ``[M]`` V."""

    path: Path
    layer: Layer
    imager: LayerImager
    unloaded_v: np.ndarray
    pressed_v: np.ndarray


def pressed_disc(folder: Path, solver: str, factor: float) -> PressedDisc:
    """The disc with ``solver`` written to ``folder``; the spot's conductance times ``factor``."""
    path = folder / "small.yaml"
    path.write_text(small_disc_patch(solver))
    layer = load_patch(path).layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    forward = ForwardModel(
        imager.mesh, imager.protocol, layer.contact_impedance_ohm_m, layer.current_a
    )
    s0 = layer.material.sheet_conductance_s
    sigma = np.full(imager.mesh.n_triangles, s0)
    sigma[np.linalg.norm(imager.mesh.centroids - PRESS_M, axis=1) < PRESS_RADIUS_M] *= factor
    return PressedDisc(path, layer, imager, forward.voltages(s0), forward.voltages(sigma))
