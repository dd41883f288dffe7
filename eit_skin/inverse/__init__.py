"""Reconstruction: relative voltage changes -> relative conductivity change per element.

Modules: ``one_step`` (:class:`ReconstructionMatrix`, the precomputed difference-imaging
matrix), ``priors`` (Tikhonov, Laplace, NOSER), ``greit`` (the trained GREIT-style matrix),
``gauss_newton`` (iterative regularised Gauss-Newton for large contrasts),
``hyperparameter`` (noise figure, GCV), ``figures_of_merit`` (GREIT figures),
``electrode_faults`` (detect faulty electrodes, image without them).
"""

from __future__ import annotations

from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor, faulty_electrodes
from eit_skin.inverse.figures_of_merit import figures_of_merit
from eit_skin.inverse.gauss_newton import GaussNewtonSolver
from eit_skin.inverse.hyperparameter import choose_by_noise_figure, noise_figure
from eit_skin.inverse.one_step import ReconstructionMatrix, reference_scale, relative_difference

__all__ = [
    "FaultTolerantReconstructor",
    "GaussNewtonSolver",
    "ReconstructionMatrix",
    "choose_by_noise_figure",
    "faulty_electrodes",
    "figures_of_merit",
    "noise_figure",
    "reference_scale",
    "relative_difference",
]
