from __future__ import annotations

import numpy as np
import pytest

from eit_skin.inverse.gauss_newton import (
    FitOptions,
    GaussNewtonSolver,
    WarmStart,
)
from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.inverse.priors import make_prior
from test.support.reconstruction_phantoms import RADIUS_M, phantom, setup

pytestmark = pytest.mark.filterwarnings("error")
R = RADIUS_M


@pytest.fixture(scope="module")
def s():
    return setup()


@pytest.mark.parametrize("contrast", [1e4, 1e-4])
def test_silver_mesh_contrast_bounded_and_located(s, contrast):
    c = np.array([0.5 * R, 0.2 * R])
    v = phantom(s, [(c[0], c[1], 0.15 * R, contrast)])
    prior = make_prior("laplace", s.coarse.mesh)
    res = GaussNewtonSolver(s.coarse, 1.0, prior, 0.03).difference(v, s.v0)
    x = res.relative_change
    assert np.isfinite(x).all() and np.isfinite(res.sigma).all() and (res.sigma > 0).all()
    assert x.max() < 1e5 and x.min() > -1
    # the data misfit falls by an order of magnitude (the rest is the coarse-model error)
    r = res.relative_residuals
    assert r[1] < r[0] and r[-1] < 0.1 * r[0] and res.iterations <= 10
    k = np.argmax(np.abs(x))
    assert np.sign(x[k]) == np.sign(contrast - 1)
    assert np.linalg.norm(s.coarse.mesh.centroids[k] - c) < 0.3 * R


def test_small_contrast_agrees_with_one_step(s):
    v = phantom(s, [(0.3 * R, -0.2 * R, 0.1 * R, 1.05)])
    one = ReconstructionMatrix.build(s.coarse, prior="laplace", hyperparameter=0.03)
    x1 = one.reconstruct(v, s.v0)
    res = GaussNewtonSolver(s.coarse, 1.0, "laplace", 0.03).difference(
        v, s.v0, options=FitOptions(max_iterations=3)
    )
    corr = np.corrcoef(x1, res.relative_change)[0, 1]
    assert corr > 0.95


def test_exact_data_converges_and_bad_target_rejected(s):
    sigma0 = 2.0
    v = s.coarse.voltages(sigma0)
    solver = GaussNewtonSolver(s.coarse, sigma0)  # v = F(sigma0): no change to fit
    res = solver.fit(v)
    assert res.iterations == 0 and res.converged
    np.testing.assert_array_equal(res.relative_change, 0.0)
    with pytest.raises(ValueError, match="finite"):
        solver.fit(np.full(v.size, np.nan))


def test_jacobian_basis_reproduces_jacobian(s):
    sigma = np.random.default_rng(3).uniform(0.2, 5.0, s.coarse.mesh.n_triangles)
    basis = s.coarse.jacobian_basis(sigma)
    j = s.coarse.jacobian(sigma)
    assert basis.products.shape[0] == 15 * 16 // 2 < j.shape[0]
    np.testing.assert_allclose(basis.combination @ basis.products, j, atol=1e-12 * abs(j).max())


@pytest.mark.parametrize("prior", ["noser", "laplace"])
def test_large_contrast_runs_five_decreasing_iterations(s, prior):
    """A x20 target: the residual keeps dropping, so all 5 requested steps are taken."""
    c = np.array([-0.3 * R, 0.4 * R])
    v = phantom(s, [(c[0], c[1], 0.2 * R, 20.0)])
    res = GaussNewtonSolver(s.coarse, 1.0, prior, 0.01).difference(
        v, s.v0, options=FitOptions(max_iterations=5, tolerance=0.0)
    )
    r = res.relative_residuals
    assert res.iterations == 5 and r.size == 6
    # the data misfit falls (the objective, which includes the prior term, always does)
    assert np.all(r[1:] <= r[:-1] * 1.01) and r[3] < r[2] < r[1] < r[0] and r[-1] < 0.01 * r[0]
    k = np.argmax(res.relative_change)
    assert res.relative_change[k] > 2.0
    assert np.linalg.norm(s.coarse.mesh.centroids[k] - c) < 0.2 * R


@pytest.fixture(scope="module")
def parameter_mesh():
    from eit_skin.fem.disk import disk_mesh

    return disk_mesh(R, h_m=0.011)  # ~230 unknowns over the 784-triangle forward mesh


@pytest.mark.parametrize("contrast", [1e4, 1e-4])
def test_coarse_parameter_mesh_large_contrast_bounded_and_located(s, parameter_mesh, contrast):
    c = np.array([0.5 * R, 0.2 * R])
    v = phantom(s, [(c[0], c[1], 0.15 * R, contrast)])
    res = GaussNewtonSolver(s.coarse, 1.0, "laplace", 0.03, parameter_mesh).difference(v, s.v0)
    x = res.parameter_change
    assert x.shape == (parameter_mesh.n_triangles,)
    assert np.isfinite(x).all() and np.isfinite(res.sigma).all() and (res.sigma > 0).all()
    assert x.max() < 1e5 and x.min() > -1
    r = res.relative_residuals
    assert r[1] < r[0] and r[-1] < 0.1 * r[0]
    k = np.argmax(np.abs(x))
    assert np.sign(x[k]) == np.sign(contrast - 1)
    assert np.linalg.norm(parameter_mesh.centroids[k] - c) < 0.3 * R


@pytest.mark.parametrize("prior", ["noser", "laplace"])
def test_coarse_parameter_mesh_runs_five_decreasing_iterations(s, parameter_mesh, prior):
    c = np.array([-0.3 * R, 0.4 * R])
    v = phantom(s, [(c[0], c[1], 0.2 * R, 20.0)])
    solver = GaussNewtonSolver(s.coarse, 1.0, prior, 0.01, parameter_mesh=parameter_mesh)
    res = solver.difference(v, s.v0, options=FitOptions(max_iterations=5, tolerance=0.0))
    r = res.relative_residuals
    assert res.iterations == 5 and r.size == 6 and res.forward_solves >= 5
    # the misfit falls to the coarse model's floor and stays there (the objective, which
    # includes the prior term, falls at every step)
    assert r[3] < r[2] < r[1] < r[0] and r[-1] < 0.01 * r[0] and r[-1] <= 1.05 * r.min()
    k = np.argmax(res.parameter_change)
    assert res.parameter_change[k] > 2.0
    assert np.linalg.norm(parameter_mesh.centroids[k] - c) < 0.2 * R


def test_parameter_mesh_maps_onto_forward_mesh(s, parameter_mesh):
    """Each forward element takes the value of the parameter element holding its centroid."""
    from eit_skin.inverse.one_step import coarse_to_fine

    v = phantom(s, [(0.2 * R, 0.1 * R, 0.2 * R, 3.0)])
    res = GaussNewtonSolver(s.coarse, 1.0, "laplace", parameter_mesh=parameter_mesh).difference(
        v, s.v0, options=FitOptions(max_iterations=2)
    )
    owner = coarse_to_fine(s.coarse.mesh, parameter_mesh).indices
    np.testing.assert_allclose(res.relative_change, res.parameter_change[owner], rtol=1e-12)
    np.testing.assert_allclose(res.sigma, 1.0 + res.relative_change, rtol=1e-12)


def test_solver_reuse_is_repeatable_and_matches_one_off(s, parameter_mesh):
    v = phantom(s, [(0.1 * R, -0.4 * R, 0.15 * R, 5.0)])
    prior = make_prior("laplace", parameter_mesh)
    solver = GaussNewtonSolver(s.coarse, 1.0, prior, 0.02, parameter_mesh=parameter_mesh)
    a = solver.difference(v, s.v0, options=FitOptions(max_iterations=4))
    other = phantom(s, [(-0.5 * R, 0.0, 0.1 * R, 0.2)])
    solver.difference(
        other, s.v0, options=FitOptions(max_iterations=4)
    )  # a different frame in between
    b = solver.difference(v, s.v0, options=FitOptions(max_iterations=4))
    np.testing.assert_array_equal(a.sigma, b.sigma)
    np.testing.assert_array_equal(a.relative_residuals, b.relative_residuals)
    c = GaussNewtonSolver(s.coarse, 1.0, prior, 0.02, parameter_mesh).difference(
        v, s.v0, options=FitOptions(max_iterations=4)
    )
    np.testing.assert_allclose(c.sigma, a.sigma, rtol=1e-9)


def test_prior_on_the_wrong_mesh_is_rejected(s, parameter_mesh):
    with pytest.raises(ValueError, match="parameter mesh"):
        GaussNewtonSolver(s.coarse, 1.0, make_prior("laplace", s.coarse.mesh), 0.03, parameter_mesh)


def test_first_step_is_the_one_step_image_on_the_channels_used(s, parameter_mesh):
    """One step from sigma0 = the one-step matrix with the same prior and h, also without
    channels: what the hyperparameter rule and the channel handling rest on."""
    from eit_skin.inverse.one_step import imaging_jacobian

    v = phantom(s, [(0.2 * R, -0.3 * R, 0.1 * R, 1.02)])
    prior = make_prior("laplace", parameter_mesh)
    solver = GaussNewtonSolver(s.coarse, 1.0, prior, 0.05, parameter_mesh=parameter_mesh)
    j = imaging_jacobian(s.coarse, 1.0, parameter_mesh)
    one = ReconstructionMatrix.from_jacobian(j, parameter_mesh, prior, 0.05)
    excluded = s.coarse.protocol.touching([5])
    for mask in (None, excluded):
        gn = solver.difference(
            v, s.v0, excluded=mask, options=FitOptions(max_iterations=1, tolerance=0.0)
        )
        x = one.reconstruct(v, s.v0, excluded=mask)
        assert gn.iterations == 1
        np.testing.assert_allclose(np.log1p(gn.parameter_change), x, rtol=1e-4, atol=1e-6)


def test_excluded_and_nan_channels_are_left_out(s, parameter_mesh):
    v = phantom(s, [(-0.2 * R, 0.3 * R, 0.15 * R, 4.0)])
    solver = GaussNewtonSolver(s.coarse, 1.0, "laplace", 0.03, parameter_mesh=parameter_mesh)
    dead = s.coarse.protocol.touching([9])
    clean = solver.difference(v, s.v0, excluded=dead, options=FitOptions(max_iterations=4))
    garbage = v.copy()
    garbage[dead] = np.random.default_rng(4).normal(0.0, 5.0, dead.sum())
    # the left-out channels' values do not matter at all ...
    left_out = solver.difference(garbage, s.v0, excluded=dead, options=FitOptions(max_iterations=4))
    np.testing.assert_array_equal(left_out.parameter_change, clean.parameter_change)
    # ... NaN channels are left out the same way ...
    nan = garbage.copy()
    nan[dead] = np.nan
    np.testing.assert_array_equal(
        solver.difference(nan, s.v0, options=FitOptions(max_iterations=4)).parameter_change,
        clean.parameter_change,
    )
    # ... and used, the garbage would have wrecked the image
    used = solver.difference(garbage, s.v0, options=FitOptions(max_iterations=4))
    assert np.abs(used.parameter_change - clean.parameter_change).max() > 0.5
    with pytest.raises(ValueError, match="all channels excluded"):
        solver.difference(v, s.v0, excluded=np.ones(v.size, dtype=bool))


def test_difference_tolerance_is_relative_to_the_change(s, parameter_mesh):
    """A small change is iterated like a large one; no change takes no step."""
    solver = GaussNewtonSolver(s.coarse, 1.0, "laplace", 0.03, parameter_mesh=parameter_mesh)
    small = phantom(s, [(0.1 * R, 0.1 * R, 0.1 * R, 1.002)])  # rms relative change ~1e-4
    res = solver.difference(small, s.v0, options=FitOptions(max_iterations=3))
    assert res.iterations >= 1 and res.relative_residuals[0] == 1.0
    assert res.parameter_change.max() > 0
    none = solver.difference(s.v0, s.v0, options=FitOptions(max_iterations=3))
    assert none.iterations == 0 and none.converged
    np.testing.assert_array_equal(none.parameter_change, 0.0)


def _peak_and_centre(x: np.ndarray, mesh) -> tuple[float, np.ndarray]:
    """Largest value and the area-weighted centre of gravity of the quarter-max set, m."""
    big = x >= 0.25 * x.max()
    w = x[big] * mesh.areas[big]
    return float(x.max()), (mesh.centroids[big] * w[:, None]).sum(axis=0) / w.sum()


def _moving_press(s, frames: int) -> list[np.ndarray]:
    """A 0.2 R disk pressed in (x1 -> x20 over 5 frames) while it slides 0.25 R, 1 % noise."""
    rng = np.random.default_rng(11)
    out = []
    for t in range(frames):
        c = np.array([-0.3 + 0.025 * t, 0.4 - 0.012 * t]) * R
        v = phantom(s, [(c[0], c[1], 0.2 * R, 1.0 + 19.0 * min(1.0, (t + 1) / 5))])
        out.append(v + rng.normal(0.0, 0.01 * np.sqrt(np.mean((v - s.v0) ** 2)), v.size))
    return out


def test_online_fit_agrees_with_five_cold_iterations_on_a_moving_press(s, parameter_mesh):
    """The reconstructor's online path (warm start, step test, kept linearisations) images a
    sequence of large-contrast frames like five full Gauss-Newton iterations from sigma0,
    frame by frame: peak and quarter-max centre within 5 % (of the peak, of R)."""
    rec = GaussNewtonReconstructor.build(
        s.coarse, 1.0, "laplace", parameter_mesh=parameter_mesh, max_iterations=5
    )
    frames = _moving_press(s, 12)
    online = rec.reconstruct(np.stack(frames), s.v0)  # one time sequence, warm-started
    warm, solves, cold_solves = WarmStart(), 0, 0
    for frame, x in zip(frames, online, strict=True):
        cold = rec.solver.difference(frame, s.v0, options=FitOptions(max_iterations=5))
        cold_solves += cold.forward_solves
        peak, centre = _peak_and_centre(cold.parameter_change, parameter_mesh)
        assert peak > 2.0  # a large contrast, far from the linear regime
        got_peak, got_centre = _peak_and_centre(x.astype(np.float64), parameter_mesh)
        assert abs(got_peak / peak - 1.0) < 0.05
        assert np.linalg.norm(got_centre - centre) < 0.05 * R
        fast = rec.solver.difference(
            frame,
            s.v0,
            warm=warm,
            options=FitOptions(
                max_iterations=5, step_tolerance=rec.step_tolerance, relinearise=rec.relinearise
            ),
        )
        np.testing.assert_allclose(fast.parameter_change, x, rtol=1e-5, atol=1e-6)
        solves += fast.forward_solves
    assert solves < 0.5 * cold_solves  # what makes it fast


def test_converged_frame_stops_at_once_and_reset_starts_cold(s, parameter_mesh):
    solver = GaussNewtonSolver(s.coarse, 1.0, "laplace", 0.03, parameter_mesh=parameter_mesh)
    v = _moving_press(s, 5)[-1]
    warm = WarmStart()
    first = solver.difference(
        v, s.v0, warm=warm, options=FitOptions(max_iterations=10, step_tolerance=0.01)
    )
    assert first.converged and 1 <= first.iterations < 10
    again = solver.difference(
        v,
        s.v0,
        warm=warm,
        options=FitOptions(max_iterations=10, step_tolerance=0.01, relinearise=0.5),
    )
    # the same frame again: the step test passes at the warm start, no forward solve
    assert again.converged and again.iterations == 0 and again.forward_solves == 0
    np.testing.assert_array_equal(again.parameter_change, first.parameter_change)
    # other channels: the warm start does not apply, the fit starts from sigma0
    dead = s.coarse.protocol.touching([3])
    other = solver.difference(
        v, s.v0, dead, warm=warm, options=FitOptions(max_iterations=10, step_tolerance=0.01)
    )
    cold = solver.difference(
        v, s.v0, dead, options=FitOptions(max_iterations=10, step_tolerance=0.01)
    )
    np.testing.assert_array_equal(other.parameter_change, cold.parameter_change)
    warm.reset()
    assert warm.d is None
