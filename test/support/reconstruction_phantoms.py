"""Simulated phantoms for the reconstruction tests: a fine forward mesh, a coarser inverse mesh.

The data are always simulated on ``FINE`` (a different triangulation, 2.4x finer) and
reconstructed on ``COARSE``, so no test images data generated on its own mesh.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

RADIUS_M = 0.05
CONTACT_OHM_M = 1e-4
SIGMA0_S = 1.0


@dataclass(frozen=True, eq=False)
class Setup:
    fine: ForwardModel
    coarse: ForwardModel
    grid: ImageGrid
    v0: np.ndarray  # [M] reference on the fine mesh


@cache
def setup(fine_h_m: float = 0.0025, coarse_h_m: float = 0.006) -> Setup:
    protocol = build_protocol(ProtocolSpec(), 16)
    fine = ForwardModel(disk_mesh(RADIUS_M, h_m=fine_h_m), protocol, CONTACT_OHM_M)
    coarse = ForwardModel(disk_mesh(RADIUS_M, h_m=coarse_h_m), protocol, CONTACT_OHM_M)
    grid = ImageGrid.build(coarse.mesh, 64)
    return Setup(fine, coarse, grid, fine.voltages(SIGMA0_S))


def phantom(s: Setup, targets: list[tuple[float, float, float, float]]) -> np.ndarray:
    """Voltages ``[M]`` on the fine mesh for disks ``(x_m, y_m, radius_m, sigma/sigma0)``."""
    sigma = np.full(s.fine.mesh.n_triangles, SIGMA0_S)
    c = s.fine.mesh.centroids
    for x, y, r, ratio in targets:
        sigma[np.hypot(c[:, 0] - x, c[:, 1] - y) < r] = SIGMA0_S * ratio
    return s.fine.voltages(sigma)


def adc_noise_std_v(v0: np.ndarray, bits: int = 12, averages: int = 1000) -> float:
    """Quantisation noise of a ``bits`` ADC spanning +-max|v0|, averaged ``averages`` times."""
    lsb = 2 * np.abs(v0).max() / 2**bits
    return float(lsb / np.sqrt(12) / np.sqrt(averages))
