"""Reconstruction: relative voltage changes -> relative conductivity change per element.

Modules: ``methods`` (the list of methods, their defaults and their :class:`Reconstructor`
interface), ``dispatch`` (:func:`make_reconstructor`: a method set up by name), ``one_step``
(:class:`ReconstructionMatrix`, the precomputed difference-imaging matrix of methods one_step
and greit, and the one-step model it is assembled from), ``priors`` (Tikhonov, Laplace,
NOSER), ``greit`` (training the GREIT-style matrix), ``gauss_newton`` (iterative regularised
Gauss-Newton for large contrasts), ``gauss_newton_method`` (it as the ``gauss_newton``
method, frame by frame), ``dual_form`` (``lambda^2`` and ``(K + lambda^2 I)^-1``, shared),
``hyperparameter`` (noise figure, GCV, model error), ``figures_of_merit`` (GREIT figures),
``electrode_faults`` (detect faulty electrodes, image without them), ``channel_noise`` (check
a reference, measure the per-channel noise that weights the channels).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "FaultTolerantReconstructor": "electrode_faults",
    "GaussNewtonReconstructor": "gauss_newton_method",
    "GaussNewtonSolver": "gauss_newton",
    "ReconstructionMatrix": "one_step",
    "Reconstructor": "methods",
    "build_method": "dispatch",
    "choose_by_noise_figure": "hyperparameter",
    "faulty_electrodes": "electrode_faults",
    "figures_of_merit": "figures_of_merit",
    "imaging_jacobian": "one_step",
    "make_reconstructor": "dispatch",
    "lambda_squared": "dual_form",
    "noise_figure": "hyperparameter",
    "reference_scale": "one_step",
    "regularised_inverse": "dual_form",
    "relative_difference": "one_step",
}

__all__ = [
    "FaultTolerantReconstructor",
    "GaussNewtonReconstructor",
    "GaussNewtonSolver",
    "ReconstructionMatrix",
    "Reconstructor",
    "build_method",
    "choose_by_noise_figure",
    "faulty_electrodes",
    "figures_of_merit",
    "imaging_jacobian",
    "lambda_squared",
    "make_reconstructor",
    "noise_figure",
    "reference_scale",
    "regularised_inverse",
    "relative_difference",
]

if TYPE_CHECKING:
    from eit_skin.inverse.dispatch import build_method, make_reconstructor
    from eit_skin.inverse.dual_form import lambda_squared, regularised_inverse
    from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor, faulty_electrodes
    from eit_skin.inverse.figures_of_merit import figures_of_merit
    from eit_skin.inverse.gauss_newton import GaussNewtonSolver
    from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
    from eit_skin.inverse.hyperparameter import choose_by_noise_figure, noise_figure
    from eit_skin.inverse.methods import Reconstructor
    from eit_skin.inverse.one_step import (
        ReconstructionMatrix,
        imaging_jacobian,
        reference_scale,
        relative_difference,
    )


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
