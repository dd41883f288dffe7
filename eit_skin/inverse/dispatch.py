"""A reconstructor made by method name: the one dispatch over the names of ``METHODS``.

Kept apart from :mod:`eit_skin.inverse.methods` (the names, defaults and interface), because it
imports every implementation while the implementations import those names.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.greit import greit_matrix
from eit_skin.inverse.methods import (
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_NOISE_FIGURE,
    DEFAULT_PRIOR,
    METHODS,
    METHODS_WITH_PRIOR,
    Reconstructor,
)
from eit_skin.inverse.one_step import ReconstructionMatrix, imaging_jacobian

if TYPE_CHECKING:
    from eit_skin.fem.mesh import Mesh
    from eit_skin.inverse.priors import Prior


def make_reconstructor(
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
    """``method`` set up for difference imaging: the one dispatch over :data:`METHODS`.

    Args:
        method: one of :data:`METHODS`.
        forward: forward model on the forward mesh; needed by ``gauss_newton`` (solved in
            every iteration) and, without ``jacobian``, by the linear methods.
        jacobian: ``[M, N]`` relative Jacobian on the imaging mesh at ``sigma0``
            (:func:`~eit_skin.inverse.one_step.imaging_jacobian`), when already known.
        mesh: the imaging mesh (``N`` elements); default ``forward.mesh``.
        prior: ``one_step`` and ``gauss_newton`` only (default :data:`DEFAULT_PRIOR`, the
            patch schema's).
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
        return GaussNewtonReconstructor.build(
            forward,
            sigma0,
            DEFAULT_PRIOR if prior is None else prior,
            hyperparameter,
            noise_figure,
            parameter_mesh=None if mesh is forward.mesh else mesh,
            max_iterations=DEFAULT_MAX_ITERATIONS if max_iterations is None else max_iterations,
            jacobian=jacobian,
        )
    if jacobian is None:
        jacobian = imaging_jacobian(forward, sigma0, mesh)
    if method == "greit":
        return greit_matrix(jacobian, mesh, hyperparameter, noise_figure)
    return ReconstructionMatrix.from_jacobian(
        jacobian,
        mesh,
        DEFAULT_PRIOR if prior is None else prior,
        hyperparameter,
        noise_figure=noise_figure,
    )


def build_method(*args: Any, **kwargs: Any) -> Reconstructor:
    """Deprecated name of :func:`make_reconstructor`.

    ``build`` now only names computing an object from its inputs (docs/architecture.md, "One
    word per idea"); ``make_`` names choosing an implementation by name.
    """
    warnings.warn(
        "eit_skin.inverse.build_method is deprecated: use make_reconstructor",
        DeprecationWarning,
        stacklevel=2,
    )
    return make_reconstructor(*args, **kwargs)
