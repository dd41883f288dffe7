"""Reconstruction: relative voltage changes -> relative conductivity change per element.

Modules: ``one_step`` (:class:`ReconstructionMatrix`, the precomputed difference-imaging
matrix), ``priors`` (Tikhonov, Laplace, NOSER), ``greit`` (the trained GREIT-style matrix),
``gauss_newton`` (iterative regularised Gauss-Newton for large contrasts),
``hyperparameter`` (noise figure, GCV), ``figures_of_merit`` (GREIT figures),
``electrode_faults`` (detect faulty electrodes, image without them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "FaultTolerantReconstructor": "electrode_faults",
    "GaussNewtonSolver": "gauss_newton",
    "ReconstructionMatrix": "one_step",
    "choose_by_noise_figure": "hyperparameter",
    "faulty_electrodes": "electrode_faults",
    "figures_of_merit": "figures_of_merit",
    "noise_figure": "hyperparameter",
    "reference_scale": "one_step",
    "relative_difference": "one_step",
}

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

if TYPE_CHECKING:
    from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor, faulty_electrodes
    from eit_skin.inverse.figures_of_merit import figures_of_merit
    from eit_skin.inverse.gauss_newton import GaussNewtonSolver
    from eit_skin.inverse.hyperparameter import choose_by_noise_figure, noise_figure
    from eit_skin.inverse.one_step import ReconstructionMatrix, reference_scale, relative_difference


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
