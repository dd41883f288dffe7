"""Small disc targets simulated on a data mesh: the phantom set behind every accuracy figure.

One implementation for the model choice (:mod:`eit_skin.pipeline.model_choice`), the
predicted accuracy of a design (:mod:`eit_skin.pipeline.accuracy_map`) and the
reconstruction benchmark: each target is a disc of conductance ``contrast * sigma0`` over the
data mesh's elements whose centroid it covers, solved exactly (the full nonlinear forward
model, as a low-rank update of the homogeneous sheet's factorisation:
:class:`~eit_skin.fem.forward_update.LocalForwardUpdate`), plus white noise of ``noise``
times the RMS difference signal, drawn in target order from one generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.forward_update import LocalForwardUpdate


@dataclass(frozen=True, eq=False)
class DiscPhantoms:
    """Simulated disc targets.

    Attributes:
        centres: ``[K, 2]`` target centres, m.
        frames: ``[K, M]`` noisy voltages, V.
        reference: ``[M]`` homogeneous voltages, V.
        change_integral: ``[K]`` integral of the true relative change over the sheet, m^2.
    """

    centres: np.ndarray
    frames: np.ndarray
    reference: np.ndarray
    change_integral: np.ndarray


def simulate_discs(
    model: ForwardModel,
    centres: np.ndarray,
    radius_m: float,
    contrast: float,
    noise: float,
    rng: np.random.Generator,
    sigma0_s: float = 1.0,
) -> DiscPhantoms:
    """Disc targets at ``centres`` ``[K, 2]`` (m) on ``model``'s mesh (see the module doc).

    Args:
        model: the forward model on the data mesh.
        centres: ``[K, 2]`` target centres, m.
        radius_m: target radius, m.
        contrast: target conductance over the background's.
        noise: noise standard deviation, fraction of each frame's RMS difference signal.
        rng: noise generator (one normal draw of ``[M]`` per target, in order).
        sigma0_s: background sheet conductance, S.
    """
    mesh = model.mesh
    base = np.full(mesh.n_triangles, float(sigma0_s))
    solver = LocalForwardUpdate(model, base)
    reference = solver.voltages(base)
    areas = np.abs(mesh.areas)
    frames, integrals = [], []
    for c in np.asarray(centres, dtype=np.float64).reshape(-1, 2):
        covered = np.linalg.norm(mesh.centroids - c, axis=1) < radius_m
        v = solver.voltages(np.where(covered, contrast * sigma0_s, sigma0_s))
        std = noise * np.sqrt(np.mean((v - reference) ** 2))
        frames.append(v + rng.normal(0.0, std, v.size))
        integrals.append((contrast - 1.0) * float(areas[covered].sum()))
    m = reference.size
    return DiscPhantoms(
        np.asarray(centres, dtype=np.float64).reshape(-1, 2),
        np.stack(frames) if frames else np.zeros((0, m)),
        reference,
        np.array(integrals),
    )


#: Target centres of the reconstruction benchmark on a disc of radius R: ten radii
#: 0..0.9 R, three angles (rad) at each (bench/standing/bench_reconstruction.py,
#: bench/standing/reconstruction.md).
DISC_RADII_R = tuple(float(r) for r in np.linspace(0.0, 0.9, 10))
DISC_ANGLES_RAD = (0.2, 1.3, 2.9)


def disc_centres(radius_m: float) -> np.ndarray:
    """``[30, 2]`` the benchmark's target centres on a disc of ``radius_m`` centred at 0, m."""
    r = np.repeat(DISC_RADII_R, len(DISC_ANGLES_RAD)) * radius_m
    a = np.tile(DISC_ANGLES_RAD, len(DISC_RADII_R))
    return np.column_stack([r * np.cos(a), r * np.sin(a)])
