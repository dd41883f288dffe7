"""One interface for every reconstruction method: make_reconstructor and Reconstructor."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.fem.disk import disk_mesh
from eit_skin.inverse.dispatch import build_method, make_reconstructor
from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor
from eit_skin.inverse.gauss_newton import FitOptions, GaussNewtonSolver, WarmStart
from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.greit import greit_matrix
from eit_skin.inverse.hyperparameter import noise_figure
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE, DEFAULT_PRIOR, METHODS
from eit_skin.inverse.one_step import ReconstructionMatrix, imaging_jacobian
from test.support.reconstruction_phantoms import RADIUS_M, phantom, setup

pytestmark = pytest.mark.filterwarnings("error")
R = RADIUS_M


@pytest.fixture(scope="module")
def s():
    return setup()


@pytest.fixture(scope="module")
def mesh():
    return disk_mesh(R, h_m=0.011)  # the imaging mesh, coarser than the forward mesh


@pytest.fixture(scope="module")
def jacobian(s, mesh):
    return imaging_jacobian(s.coarse, 1.0, mesh)


@pytest.fixture(scope="module")
def built(s, mesh, jacobian):
    return {m: make_reconstructor(m, s.coarse, mesh=mesh, jacobian=jacobian) for m in METHODS}


def test_each_method_is_what_its_own_constructor_builds(s, mesh, jacobian, built):
    one = ReconstructionMatrix.from_jacobian(
        jacobian, mesh, DEFAULT_PRIOR, noise_figure=DEFAULT_NOISE_FIGURE["one_step"]
    )
    np.testing.assert_array_equal(built["one_step"].matrix, one.matrix)
    greit = greit_matrix(jacobian, mesh, noise_figure=0.13)
    np.testing.assert_array_equal(built["greit"].matrix, greit.matrix)
    gn = built["gauss_newton"]
    assert isinstance(gn, GaussNewtonReconstructor)
    # h by the same noise-figure rule on the first linearised step (the one-step matrix)
    first = ReconstructionMatrix.from_jacobian(
        jacobian, mesh, DEFAULT_PRIOR, noise_figure=DEFAULT_NOISE_FIGURE["gauss_newton"]
    )
    assert gn.hyperparameter == first.hyperparameter == gn.linearised.hyperparameter
    np.testing.assert_array_equal(gn.linearised.matrix, first.matrix)
    for method, rec in built.items():
        assert rec.method == method and rec.mesh is mesh
        assert (rec.n_channels, rec.n_elements) == (s.coarse.n_measurements, mesh.n_triangles)
        assert noise_figure(rec.linearised) == pytest.approx(DEFAULT_NOISE_FIGURE[method], 1e-6)
    # without a Jacobian the forward model gives the same one
    again = make_reconstructor("greit", s.coarse, mesh=mesh)
    np.testing.assert_allclose(again.matrix, greit.matrix, rtol=1e-9, atol=1e-12)


def test_one_contract_for_every_method(s, built):
    v = phantom(s, [(0.3 * R, 0.2 * R, 0.15 * R, 2.0)])
    frames = np.stack([s.v0, v])
    excluded = s.coarse.protocol.touching([2])
    for rec in built.values():
        x = rec.reconstruct(frames, s.v0)
        assert x.dtype == np.float32 and x.shape == (2, rec.n_elements)
        assert (x[0] == 0).all()  # no change, no image
        # one frame as in a batch (float32 products: BLAS may round a batch differently)
        np.testing.assert_allclose(rec.reconstruct(v, s.v0), x[1], rtol=1e-5, atol=1e-6)
        k = np.argmax(x[1])  # the conductive disc, found with its sign
        assert np.linalg.norm(rec.mesh.centroids[k] - [0.3 * R, 0.2 * R]) < 0.25 * R
        # NaN channels are left out exactly as excluded ones
        nan = v.copy()
        nan[excluded] = np.nan
        np.testing.assert_array_equal(
            rec.reconstruct(nan, s.v0), rec.reconstruct(v, s.v0, excluded=excluded)
        )


def test_gauss_newton_reconstructor_is_its_solver_per_frame(s, mesh, built):
    """Frame by frame the reconstructor runs its solver from the last frame's end point (the
    online options); a jump between very different frames still lands on the cold fit."""
    gn = built["gauss_newton"]
    gn.reset()
    solver = GaussNewtonSolver(
        s.coarse, 1.0, gn.solver.prior, gn.hyperparameter, parameter_mesh=mesh
    )
    frames = np.stack([phantom(s, [(-0.4 * R, 0.1 * R, 0.2 * R, c)]) for c in (5.0, 0.3)])
    x = gn.reconstruct(frames, s.v0)
    warm = WarmStart()
    for frame, got in zip(frames, x, strict=True):
        res = solver.difference(
            frame,
            s.v0,
            warm=warm,
            options=FitOptions(
                max_iterations=gn.max_iterations,
                step_tolerance=gn.step_tolerance,
                relinearise=gn.relinearise,
            ),
        )
        np.testing.assert_allclose(got, res.parameter_change.astype(np.float32), rtol=1e-6)
        cold = solver.difference(frame, s.v0, options=FitOptions(max_iterations=gn.max_iterations))
        assert cold.iterations == gn.max_iterations  # a large contrast takes every step
        k = np.argmax(np.abs(cold.parameter_change))
        assert abs(got[k] / cold.parameter_change[k] - 1.0) < 0.05


def test_fault_tolerance_works_for_gauss_newton(s, built):
    v = phantom(s, [(-0.4 * R, 0.3 * R, 0.1 * R, 2.0)])
    frames = np.stack([v, v])
    dead = s.coarse.protocol.touching([3])
    frames[:, dead] = np.random.default_rng(8).normal(0, 5.0, (2, dead.sum()))
    imager = FaultTolerantReconstructor(built["gauss_newton"], s.coarse.protocol)
    x = imager.reconstruct(frames, s.v0)
    assert imager.last_faulty.tolist() == [3]
    np.testing.assert_array_equal(x[0], built["gauss_newton"].reconstruct(v, s.v0, dead))


def test_arguments_a_method_does_not_take_are_refused(s, jacobian, mesh):
    with pytest.raises(ValueError, match="unknown 'jac'"):
        make_reconstructor("jac", s.coarse)
    with pytest.raises(ValueError, match="'greit' takes no prior"):
        make_reconstructor("greit", s.coarse, prior="laplace")
    with pytest.raises(ValueError, match="'one_step' does not iterate"):
        make_reconstructor("one_step", s.coarse, max_iterations=3)
    with pytest.raises(ValueError, match="needs a forward model"):
        make_reconstructor("gauss_newton", jacobian=jacobian, mesh=mesh)
    with pytest.raises(ValueError, match="expected \\[208, "):
        make_reconstructor("gauss_newton", s.coarse, mesh=mesh, jacobian=jacobian[:10])
    # a linear method needs no forward model once the Jacobian is known
    one_step = make_reconstructor("one_step", jacobian=jacobian, mesh=mesh, hyperparameter=0.1)
    assert one_step.mesh is mesh


def test_the_old_name_build_method_still_works_and_says_it_is_deprecated(mesh, jacobian):
    with pytest.warns(DeprecationWarning, match="make_reconstructor"):
        old = build_method("one_step", jacobian=jacobian, mesh=mesh, hyperparameter=0.1)
    new = make_reconstructor("one_step", jacobian=jacobian, mesh=mesh, hyperparameter=0.1)
    assert type(old) is type(new) and old.mesh is new.mesh
