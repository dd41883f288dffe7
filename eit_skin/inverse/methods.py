"""The reconstruction methods a layer's ``solver.method`` can name, and their one interface.

* ``one_step``: linearised difference imaging with a smoothness prior
  (:mod:`eit_skin.inverse.one_step`, priors in :mod:`eit_skin.inverse.priors`);
* ``greit``: the one-step matrix trained on simulated targets (:mod:`eit_skin.inverse.greit`);
  it has no prior of its own;
* ``gauss_newton``: iterative regularised Gauss-Newton for large contrasts
  (:mod:`eit_skin.inverse.gauss_newton`), with a prior.

Interface (the shape of pyEIT's ``setup()`` / ``solve()``, without its faults): every method is
set up once by :func:`eit_skin.inverse.dispatch.make_reconstructor`, which returns a ready
:class:`Reconstructor` (no half-initialised object that must be ``setup()`` before use, no
keyword arguments silently ignored by one method), and then images any number of frames with
``reconstruct(frames, reference, excluded)``: volts in, ``delta sigma / sigma0`` per element
out, one sign convention (positive = more conductive) and one data normalisation
(:func:`eit_skin.inverse.one_step.relative_difference`) for all methods, and bad channels left
out, never imaged. The method names are the patch schema's (:data:`eit_skin.patch.model.METHODS`,
re-exported here); this module imports no implementation, so it cannot be part of an import
cycle.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

# the names belong to the patch schema (the solvers honour them; patch/ knows no solver),
# re-exported for the solvers
from eit_skin.patch.model import DEFAULT_PRIOR as DEFAULT_PRIOR
from eit_skin.patch.model import METHODS as METHODS
from eit_skin.patch.model import METHODS_WITH_PRIOR as METHODS_WITH_PRIOR

if TYPE_CHECKING:
    from eit_skin.fem.mesh import Mesh
    from eit_skin.inverse.one_step import ReconstructionMatrix

#: Noise figure the hyperparameter is chosen for when neither ``h`` nor a noise figure is
#: given (:func:`eit_skin.inverse.hyperparameter.choose_by_noise_figure`), one per method:
DEFAULT_NOISE_FIGURE: dict[str, float] = {
    # chosen with the default prior (NOSER) and model-error share by leaving one set out over
    # the five real recordings and the simulator (bench/standing/real_data.md, issue 35); the noise
    # figure study of docs/reconstruction.md had chosen 0.3 for the Laplace prior on the
    # simulator alone (config/elbow.yaml names that pair)
    "one_step": 0.13,
    # config/arm.yaml and face.yaml: test_accuracy.py meets max PE <= 2 % R, ringing <= 0.2
    # and resolution <= pyEIT JAC's 0.248 at this value
    "greit": 0.13,
    # chosen on its first linearised step, which is the one_step matrix with the same prior:
    # the noise-figure study of docs/reconstruction.md (Laplace prior, simulator); Gauss-Newton
    # was not among the real-data candidates of bench/standing/real_data.md (its frames are not
    # weighted)
    "gauss_newton": 0.3,
}

#: Gauss-Newton steps per frame when not given (the patch schema's ``max_iterations``).
DEFAULT_MAX_ITERATIONS = 5


class Reconstructor(Protocol):
    """A method set up for one sheet: frames (V) -> relative conductivity change per element.

    Implemented by :class:`~eit_skin.inverse.one_step.ReconstructionMatrix` (``one_step``,
    ``greit``) and :class:`~eit_skin.inverse.gauss_newton_method.GaussNewtonReconstructor`.

    Attributes:
        method: one of :data:`METHODS`.
        hyperparameter: the dimensionless ``h`` in use.
        n_channels: ``M``, channels in a full frame.
        n_elements: ``N``, elements of the imaging mesh.
        mesh: the imaging mesh, if known.
        linearised: the method's linear matrix (itself for ``one_step`` and ``greit``; the
            first linearised step for ``gauss_newton``).
    """

    @property
    def method(self) -> str: ...
    @property
    def hyperparameter(self) -> float: ...
    @property
    def n_channels(self) -> int: ...
    @property
    def n_elements(self) -> int: ...
    @property
    def mesh(self) -> Mesh | None: ...
    @property
    def linearised(self) -> ReconstructionMatrix: ...

    def reconstruct(
        self, frames: np.ndarray, reference: np.ndarray, excluded: np.ndarray | None = None
    ) -> np.ndarray:
        """Frames (volts) -> float32 relative conductivity change per element.

        ``frames`` ``[M]``/``[T, M]`` and ``reference`` ``[M]`` volts, ``excluded`` optional
        bool ``[M]`` channels to leave out; result ``[N]``/``[T, N]``. Channels that are
        NaN/Inf in the reference or a frame are left out of that frame, never imaged.
        """
        ...
