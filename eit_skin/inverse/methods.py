"""The reconstruction methods a layer's ``solver.method`` can name, and their one interface.

* ``one_step``: linearised difference imaging with a smoothness prior
  (:mod:`eit_skin.inverse.one_step`, priors in :mod:`eit_skin.inverse.priors`);
* ``greit``: the one-step matrix trained on simulated targets (:mod:`eit_skin.inverse.greit`);
  it has no prior of its own;
* ``gauss_newton``: iterative regularised Gauss-Newton for large contrasts
  (:mod:`eit_skin.inverse.gauss_newton`), with a prior.

Interface (the shape of pyEIT's ``setup()`` / ``solve()``, without its faults): every method
is set up once by :func:`build_method`, which returns a ready :class:`Reconstructor` (no
half-initialised object that must be ``setup()`` before use, no keyword arguments silently
ignored by one method), and then images any number of frames with
``reconstruct(frames, reference, excluded)``: volts in, ``delta sigma / sigma0`` per element
out, one sign convention (positive = more conductive) and one data normalisation
(:func:`eit_skin.inverse.one_step.relative_difference`) for all methods, and bad channels
left out, never imaged. This module stays light (the patch schema imports :data:`METHODS`);
the implementations are imported when a method is built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from eit_skin.fem.mesh import Mesh
    from eit_skin.inverse.one_step import ReconstructionMatrix
    from eit_skin.inverse.priors import Prior

METHODS: tuple[str, ...] = ("one_step", "greit", "gauss_newton")

#: Methods that use ``solver.prior``.
METHODS_WITH_PRIOR: tuple[str, ...] = ("one_step", "gauss_newton")

#: Noise figure the hyperparameter is chosen for when neither ``h`` nor a noise figure is
#: given (:func:`eit_skin.inverse.hyperparameter.choose_by_noise_figure`), one per method:
DEFAULT_NOISE_FIGURE: dict[str, float] = {
    # the noise-figure study of docs/reconstruction.md: with the Laplace prior NF 0.3 keeps
    # the position error (2.3 % R) and resolution (0.23) of NF 0.1-0.2 at less ringing, NF 1
    # blurs (RES 0.28) and moves targets (PE 2.6 % R); the value config/elbow.yaml ships
    "one_step": 0.3,
    # config/arm.yaml and face.yaml: test_accuracy.py meets max PE <= 2 % R, ringing <= 0.2
    # and resolution <= pyEIT JAC's 0.248 at this value
    "greit": 0.13,
    # chosen on its first linearised step, which is the one_step matrix with the same prior
    "gauss_newton": 0.3,
}

#: Gauss-Newton steps per frame when not given (the patch schema's ``max_iterations``).
DEFAULT_MAX_ITERATIONS = 5


class Reconstructor(Protocol):
    """A method set up for one sheet: frames (V) -> relative conductivity change per element.

    Implemented by :class:`~eit_skin.inverse.one_step.ReconstructionMatrix` (``one_step``,
    ``greit``) and :class:`~eit_skin.inverse.gauss_newton.GaussNewtonReconstructor`.

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


def build_method(
    method: str,
    forward: Any | None = None,
    *,
    jacobian: np.ndarray | None = None,
    mesh: Mesh | None = None,
    prior: str | Prior | None = None,
    hyperparameter: float | None = None,
    noise_figure: float | None = None,
    sigma0: np.ndarray | float = 1.0,
    max_iterations: int | None = None,
) -> Reconstructor:
    """Set up ``method`` for difference imaging: the one dispatch over :data:`METHODS`.

    Args:
        method: one of :data:`METHODS`.
        forward: forward model on the forward mesh; needed by ``gauss_newton`` (solved in
            every iteration) and, without ``jacobian``, by the linear methods.
        jacobian: ``[M, N]`` relative Jacobian on the imaging mesh at ``sigma0``
            (:func:`~eit_skin.inverse.one_step.imaging_jacobian`), when already known.
        mesh: the imaging mesh (``N`` elements); default ``forward.mesh``.
        prior: ``one_step`` and ``gauss_newton`` only (default ``"laplace"``).
        hyperparameter: dimensionless ``h``; ``None`` chooses it for ``noise_figure``
            (``gauss_newton``: on its first linearised step).
        noise_figure: default :data:`DEFAULT_NOISE_FIGURE` of the method.
        sigma0: reference sheet conductance, siemens, scalar or ``[N_forward]``.
        max_iterations: ``gauss_newton`` only (default :data:`DEFAULT_MAX_ITERATIONS`).

    Raises:
        ValueError: unknown method, an argument the method does not take, or neither
            ``forward`` nor ``jacobian``.
    """
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; expected one of {METHODS}")
    if prior is not None and method not in METHODS_WITH_PRIOR:
        raise ValueError(f"method {method!r} takes no prior (got {prior!r})")
    if max_iterations is not None and method != "gauss_newton":
        raise ValueError(f"method {method!r} does not iterate (max_iterations given)")
    if forward is None and (jacobian is None or mesh is None or method == "gauss_newton"):
        raise ValueError(f"method {method!r}: needs a forward model (or a jacobian and mesh)")
    mesh = forward.mesh if mesh is None else mesh
    if noise_figure is None:
        noise_figure = DEFAULT_NOISE_FIGURE[method]
    if method == "gauss_newton":
        from eit_skin.inverse.gauss_newton import GaussNewtonReconstructor

        return GaussNewtonReconstructor.build(
            forward,
            sigma0,
            "laplace" if prior is None else prior,
            hyperparameter,
            noise_figure,
            parameter_mesh=None if mesh is forward.mesh else mesh,
            max_iterations=DEFAULT_MAX_ITERATIONS if max_iterations is None else max_iterations,
            jacobian=jacobian,
        )
    from eit_skin.inverse.one_step import ReconstructionMatrix, imaging_jacobian

    if jacobian is None:
        jacobian = imaging_jacobian(forward, sigma0, mesh)
    if method == "greit":
        return ReconstructionMatrix.greit(jacobian, mesh, hyperparameter, noise_figure)
    return ReconstructionMatrix.from_jacobian(
        jacobian,
        mesh,
        "laplace" if prior is None else prior,
        hyperparameter,
        noise_figure=noise_figure,
    )
