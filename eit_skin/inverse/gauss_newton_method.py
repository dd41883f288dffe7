"""Method ``gauss_newton`` behind the shared reconstructor interface: the online fit per frame.

:class:`GaussNewtonReconstructor` runs the prepared :class:`~eit_skin.inverse.gauss_newton.\
GaussNewtonSolver` (the iterative solver and its maths: :mod:`eit_skin.inverse.gauss_newton`)
on every frame, warm-started from the previous one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.gauss_newton import (
    DEFAULT_RELINEARISE,
    DEFAULT_STEP_TOLERANCE,
    FitOptions,
    GaussNewtonSolver,
    WarmStart,
)
from eit_skin.inverse.methods import DEFAULT_MAX_ITERATIONS, DEFAULT_NOISE_FIGURE
from eit_skin.inverse.one_step import ReconstructionMatrix, checked_frames, imaging_jacobian
from eit_skin.inverse.priors import Prior, make_prior


@dataclass(frozen=True, eq=False)
class GaussNewtonReconstructor:
    """Method ``gauss_newton`` behind the shared reconstructor interface.

    Set up once per layer (:meth:`build`); :meth:`reconstruct` then runs the prepared
    :class:`GaussNewtonSolver` on every frame. Values are ``sigma / sigma0 - 1`` per element
    of the imaging (parameter) mesh, the one-step output convention.

    Online (frame by frame, as the node and ``eit-skin reconstruct`` call it) every fit starts
    where the previous frame's ended (:class:`WarmStart`, kept here; :meth:`reset` on a new
    reference), stops on the step-size convergence test and reuses a linearisation while
    the solution stays near it (quasi-Newton steps, one forward solve each): a frame like
    the last costs no forward solve, a moving touch one or two. Frames arrive at 50-100 Hz,
    so the previous solution is close; where it is not, the fit simply takes more steps
    (at most ``max_iterations``). ``step_tolerance = 0`` and ``relinearise = 0`` with
    :meth:`reset` before every frame give the plain cold Gauss-Newton fit.

    Attributes:
        solver: the prepared solver; its unknowns live on the imaging mesh.
        linearised: the one-step matrix of its first step (same Jacobian, prior and ``h``):
            where the hyperparameter was chosen, and the linear stand-in for callers that
            need a matrix (e.g. the single-contact spread of :mod:`eit_skin.touch.shapes`).
        max_iterations: Gauss-Newton steps per frame (>= 1).
        tolerance: stop when the residual is this fraction of the measured change.
        step_tolerance: convergence test, max ``|ln sigma|`` change of the next step over
            the image's max ``|ln sigma|`` (:meth:`GaussNewtonSolver.difference`).
        relinearise: max ``|ln sigma|`` distance before a kept linearisation is renewed.
        warm: the last frame's end point (mutable state of an otherwise fixed operator).
    """

    solver: GaussNewtonSolver
    linearised: ReconstructionMatrix
    max_iterations: int = DEFAULT_MAX_ITERATIONS
    tolerance: float = 1e-3
    step_tolerance: float = DEFAULT_STEP_TOLERANCE
    relinearise: float = DEFAULT_RELINEARISE
    warm: WarmStart = field(default_factory=WarmStart, compare=False)

    method: ClassVar[str] = "gauss_newton"

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations: must be >= 1, got {self.max_iterations}")

    @classmethod
    def build(
        cls,
        forward: Any,
        sigma0: np.ndarray | float = 1.0,
        prior: str | Prior = "laplace",
        hyperparameter: float | None = None,
        noise_figure: float | None = None,
        parameter_mesh: Mesh | None = None,
        max_iterations: int = DEFAULT_MAX_ITERATIONS,
        jacobian: np.ndarray | None = None,
    ) -> GaussNewtonReconstructor:
        """Prepare the solver and its first linearisation.

        Args:
            forward: forward model (solved in every iteration).
            sigma0: reference sheet conductance, siemens, scalar or ``[N_forward]``.
            prior: kind or a built prior on the imaging mesh.
            hyperparameter: ``h``; ``None`` chooses it by ``noise_figure`` on the first
                linearised step (the one-step matrix with the same prior), default the
                method's :data:`~eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`.
            noise_figure: see ``hyperparameter``.
            parameter_mesh: imaging mesh carrying the unknowns (default: the forward mesh).
            max_iterations: Gauss-Newton steps per frame.
            jacobian: ``[M, N]`` relative Jacobian on the imaging mesh at ``sigma0`` when
                already known (:func:`~eit_skin.inverse.one_step.imaging_jacobian`, e.g. from
                a disk cache).
        """
        mesh = forward.mesh if parameter_mesh is None else parameter_mesh
        if jacobian is None:
            jacobian = imaging_jacobian(forward, sigma0, parameter_mesh)
        elif np.shape(jacobian) != (forward.n_measurements, mesh.n_triangles):
            raise ValueError(
                f"jacobian: expected [{forward.n_measurements}, {mesh.n_triangles}], "
                f"got {np.shape(jacobian)}"
            )
        p = prior if isinstance(prior, Prior) else make_prior(prior, mesh, jacobian)
        if noise_figure is None:
            noise_figure = DEFAULT_NOISE_FIGURE[cls.method]
        linear = ReconstructionMatrix.from_jacobian(
            jacobian, mesh, p, hyperparameter, noise_figure=noise_figure
        )
        solver = GaussNewtonSolver(forward, sigma0, p, linear.hyperparameter, parameter_mesh)
        return cls(solver, linear, int(max_iterations))

    @property
    def hyperparameter(self) -> float:
        return self.solver.hyperparameter

    def reset(self) -> None:
        """Forget the last frame's solution (a new reference): the next fit starts cold."""
        self.warm.reset()

    @property
    def n_channels(self) -> int:
        return int(self.solver.v0.size)

    @property
    def n_elements(self) -> int:
        return int(self.solver.n_parameters)

    @property
    def mesh(self) -> Mesh | None:
        return self.linearised.mesh

    def reconstruct(
        self,
        frames: np.ndarray,
        reference: np.ndarray,
        excluded: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (volts) -> relative conductivity change per element, one fit per frame.

        Frames are taken as a time sequence: each fit starts from the previous one's end.

        Args:
            frames: ``[M]`` or ``[T, M]`` volts, in the protocol's measurement order.
            reference: ``[M]`` volts.
            excluded: optional bool ``[M]`` channels to leave out (faulty electrodes).

        Returns:
            float32 ``[N]`` or ``[T, N]``; channels that are NaN/Inf in the reference or in a
            frame are left out of that frame's fit, never imaged.
        """
        v, ref = checked_frames(frames, reference, self.n_channels)
        mask = None if excluded is None else np.asarray(excluded, dtype=bool)
        v2 = v[None] if v.ndim == 1 else v
        out = np.empty((v2.shape[0], self.n_elements), dtype=np.float32)
        options = FitOptions(
            self.max_iterations,
            self.tolerance,
            step_tolerance=self.step_tolerance,
            relinearise=self.relinearise,
        )
        for t, frame in enumerate(v2):
            out[t] = self.solver.difference(frame, ref, mask, options, self.warm).parameter_change
        return out[0] if v.ndim == 1 else out
