"""One-step reconstruction matrix and priors on synthetic Jacobians (exact algebra)."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.inverse.dual_form import lambda_squared
from eit_skin.inverse.hyperparameter import choose_by_gcv, choose_by_noise_figure, noise_figure
from eit_skin.inverse.one_step import (
    ReconstructionMatrix,
    reference_scale,
    relative_difference,
)
from eit_skin.inverse.priors import element_adjacency, laplace_matrix, make_prior
from test.fem.test_image_grid import square_with_hole

pytestmark = pytest.mark.filterwarnings("error")


def random_case(m: int = 30, seed: int = 0):
    mesh = square_with_hole()
    j = np.random.default_rng(seed).normal(size=(m, mesh.n_triangles))
    return mesh, j


def test_adjacency_and_laplace():
    mesh = square_with_hole()
    adj = element_adjacency(mesh).toarray()
    assert (adj == adj.T).all()
    # triangle 0 (lower right of square 0) shares the diagonal with 1 and the edge x=1 with 3
    # (upper left of square 1); it only touches triangle 2 at a corner
    assert adj[0, 1] == 1 and adj[0, 3] == 1 and adj[0, 2] == 0
    # shared edges: 8 square diagonals + 8 edges between neighbouring squares (hole excluded)
    assert adj.sum() / 2 == 8 + 8
    lap = laplace_matrix(mesh, 0.5).toarray()
    np.testing.assert_allclose(lap.sum(axis=1), 0.5)


@pytest.mark.parametrize("kind", ["tikhonov", "laplace", "noser"])
def test_prior_solve_is_inverse(kind):
    mesh, j = random_case()
    p = make_prior(kind, mesh, j)
    b = np.random.default_rng(1).normal(size=(mesh.n_triangles, 4))
    np.testing.assert_allclose(p.matrix @ p.solve(b), b, atol=1e-10)


@pytest.mark.parametrize("kind", ["tikhonov", "laplace", "noser"])
def test_dual_form_equals_primal(kind):
    mesh, j = random_case()
    rm = ReconstructionMatrix.from_jacobian(j, mesh, kind, hyperparameter=0.3)
    p = make_prior(kind, mesh, j).matrix.toarray()
    k = j @ np.linalg.solve(p, j.T)
    lam2 = lambda_squared(0.3, np.trace(k), k.shape[0])  # h^2 trace(K) / M
    primal = np.linalg.solve(j.T @ j + lam2 * p, j.T)
    np.testing.assert_allclose(rm.matrix, primal, rtol=1e-7, atol=1e-10)


def test_relative_difference_convention():
    ref = np.array([2.0, -4.0, 1e-6, 1.0])
    v = np.array([2.2, -4.4, 2e-6, 1.0])
    rms = np.sqrt(np.mean(ref**2))
    np.testing.assert_allclose(reference_scale(ref), [2.0, 4.0, 1e-2 * rms, 1.0])
    np.testing.assert_allclose(relative_difference(v, ref), [0.1, -0.1, 1e-6 / (1e-2 * rms), 0])


def test_zero_change_batches_and_repeatability():
    mesh, j = random_case()
    rm = ReconstructionMatrix.from_jacobian(j, mesh, "laplace", hyperparameter=0.1)
    ref = np.linspace(1.0, 2.0, 30)
    assert (rm.reconstruct(ref, ref) == 0).all()
    frames = ref * (1 + 0.01 * np.random.default_rng(2).normal(size=(7, 30)))
    batch = rm.reconstruct(frames, ref)
    assert batch.dtype == np.float32 and batch.shape == (7, mesh.n_triangles)
    np.testing.assert_allclose(batch[4], rm.reconstruct(frames[4], ref), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(batch, rm.reconstruct(frames, ref))
    expected = relative_difference(frames, ref) @ rm.matrix.T
    np.testing.assert_allclose(batch, expected, rtol=1e-4, atol=1e-5)


def test_nan_channels_dropped_with_cached_reduced_matrix():
    mesh, j = random_case()
    rm = ReconstructionMatrix.from_jacobian(j, mesh, "tikhonov", hyperparameter=0.1)
    ref = np.linspace(1.0, 2.0, 30)
    frames = ref * (1 + 0.01 * np.random.default_rng(3).normal(size=(3, 30)))
    frames[1, 5] = np.nan
    bad_ref = ref.copy()
    bad_ref[7] = np.nan
    out = rm.reconstruct(frames, bad_ref)
    assert np.isfinite(out).all()
    mask = np.zeros(30, bool)
    mask[7] = True
    reduced = rm.without_channels(mask)
    assert rm.without_channels(mask.copy()) is reduced  # cached
    keep = np.flatnonzero(~mask)
    direct = ReconstructionMatrix.from_jacobian(j[keep], mesh, "tikhonov", hyperparameter=0.1)
    # lambda is normalised by the trace of the reduced problem in both
    np.testing.assert_allclose(reduced.matrix, direct.matrix, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(
        out[0], relative_difference(frames[0], ref)[keep] @ reduced.matrix.T, rtol=1e-4, atol=1e-6
    )
    mask[5] = True
    np.testing.assert_allclose(
        out[1],
        relative_difference(frames[1], ref)[~mask] @ rm.without_channels(mask).matrix.T,
        rtol=1e-4,
        atol=1e-6,
    )


def test_noise_figure_choice_hits_target():
    mesh, j = random_case(m=40)
    rm = ReconstructionMatrix.from_jacobian(j, mesh, "laplace", hyperparameter=0.1)
    lo, hi = noise_figure(rm, 1e-3), noise_figure(rm, 1.0)
    assert lo < hi
    target = 0.5 * (lo + hi)
    h = choose_by_noise_figure(rm, target)
    assert noise_figure(rm, h) == pytest.approx(target, rel=1e-6)
    built = ReconstructionMatrix.from_jacobian(j, mesh, "laplace", noise_figure=target)
    assert built.hyperparameter == pytest.approx(h)


def test_noise_figure_is_its_definition_on_the_assembled_matrix():
    """NF = SNR_out / SNR_in computed the long way from R itself (Adler & Guardo 1996)."""
    mesh, j = random_case(m=40)
    base = ReconstructionMatrix.from_jacobian(j, mesh, "laplace", hyperparameter=0.1)
    scale = np.random.default_rng(7).uniform(0.5, 3.0, size=40)  # measured relative noise
    areas = np.abs(mesh.areas)
    c = mesh.centroids
    d = np.linalg.norm(c - (areas[:, None] * c).sum(0) / areas.sum(), axis=1)
    target = (d <= 0.05 * np.sqrt(areas.sum())).astype(float)
    if not target.any():
        target[d.argmin()] = 1.0
    dv = j @ (target * areas)  # [M] relative change of a small central target
    a = areas / areas.sum()
    for s in (np.ones(40), scale):
        weighted = base.with_channel_scale(s)
        for h in (1e-3, 0.05, 1.0):
            r = weighted.with_hyperparameter(h).matrix  # [N, M], acts on unwhitened channels
            noise_cov_diag = np.sum((r * s[None, :]) ** 2, axis=1)  # unit noise in S^-1 dv
            snr_out = (a @ np.abs(r @ dv)) / np.sqrt(a @ noise_cov_diag)
            snr_in = np.mean(np.abs(dv / s))
            assert noise_figure(weighted, h) == pytest.approx(snr_out / snr_in, rel=1e-8)
    # choosing on the Gram pair before assembly gives the matrix hitting the target
    chosen = base.with_channel_scale(scale, noise_figure=0.4)
    assert noise_figure(chosen) == pytest.approx(0.4, rel=1e-6)
    with pytest.raises(ValueError, match="not both"):
        base.with_channel_scale(scale, h=0.1, noise_figure=0.4)


def test_gcv_prefers_more_regularisation_for_noisier_data():
    mesh, j = random_case(m=40)
    rm = ReconstructionMatrix.from_jacobian(j, mesh, "tikhonov", hyperparameter=0.1)
    rng = np.random.default_rng(4)
    x = rng.normal(size=mesh.n_triangles)
    clean = j @ x
    noise = rng.normal(size=40)
    h_low = choose_by_gcv(rm, clean + 1e-3 * np.std(clean) * noise)
    h_high = choose_by_gcv(rm, clean + 0.5 * np.std(clean) * noise)
    assert h_low < h_high


def test_bad_inputs():
    mesh, j = random_case()
    with pytest.raises(ValueError, match="elements"):
        ReconstructionMatrix.from_jacobian(j[:, :5], mesh, "laplace", 0.1)
    with pytest.raises(ValueError, match="unknown prior"):
        ReconstructionMatrix.from_jacobian(j, mesh, "nope", 0.1)
    rm = ReconstructionMatrix.from_jacobian(j, mesh, "laplace", 0.1)
    with pytest.raises(ValueError, match="M=30"):
        rm.reconstruct(np.zeros(29), np.ones(30))
    with pytest.raises(ValueError, match="positive"):
        rm.with_hyperparameter(-1.0)
