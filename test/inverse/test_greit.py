"""GREIT-trained one-step matrix: training set, closed form, channel removal, caching path."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.fem.disk import disk_mesh
from eit_skin.inverse.dual_form import lambda_squared
from eit_skin.inverse.greit import GreitModel, equivalent_radius, greit_matrix, training_set
from eit_skin.inverse.one_step import ReconstructionMatrix, linear_matrix

pytestmark = pytest.mark.filterwarnings("error")
R = 0.05


@pytest.fixture(scope="module")
def mesh():
    return disk_mesh(R, h_m=0.006)


@pytest.fixture(scope="module")
def training(mesh):
    return training_set(mesh, n_targets=200)


def test_training_targets_cover_the_sheet(mesh, training):
    k = training.n_targets
    assert 150 < k < 260
    assert np.all(np.hypot(*training.centres.T) < R)
    # every target's covered area is about pi r^2 (elements sampled at 4 points each)
    area = training.targets.T @ np.abs(mesh.areas)
    inside = np.hypot(*training.centres.T) < R - 2 * training.radius_m
    np.testing.assert_allclose(area[inside], np.pi * training.radius_m**2, rtol=0.5)
    assert training.radius_m == pytest.approx(0.05 * equivalent_radius(mesh))


def test_desired_images_positive_centred_same_integral(mesh, training):
    d = training.desired
    areas = np.abs(mesh.areas)
    assert (d >= 0).all()
    np.testing.assert_allclose(areas @ d, training.targets.T @ areas, rtol=1e-12)
    # quarter-maximum centre of gravity on the target within 0.9 R, also where the edge cuts
    # the blob (outside 0.9 R the shift that would be needed is capped at the blob width)
    c = mesh.centroids
    q = d >= 0.25 * d.max(axis=0)
    w = d * q * areas[:, None]
    cog = (w.T @ c) / w.sum(axis=0)[:, None]
    err = np.linalg.norm(cog - training.centres, axis=1)
    within = np.hypot(*training.centres.T) < 0.9 * R
    assert err[within].max() < 0.015 * R


def test_closed_form_and_reduced_channels(mesh, training):
    j = np.random.default_rng(0).normal(size=(40, mesh.n_triangles))
    model = GreitModel.build(j, mesh, training)
    rm = linear_matrix(model, hyperparameter=0.2)
    assert rm.method == "greit" and rm.model is model
    y = np.asarray(training.targets.T @ j.T).T  # [M, K]
    kk = y @ y.T
    lam2 = lambda_squared(0.2, np.trace(kk), kk.shape[0])
    expected = training.desired @ y.T @ np.linalg.inv(kk + lam2 * np.eye(40))
    np.testing.assert_allclose(rm.matrix, expected, rtol=1e-8, atol=1e-12)
    excluded = np.zeros(40, dtype=bool)
    excluded[[3, 7, 30]] = True
    reduced = rm.without_channels(excluded)
    direct = linear_matrix(GreitModel.build(j[~excluded], mesh, training), hyperparameter=0.2)
    np.testing.assert_allclose(reduced.matrix, direct.matrix, rtol=1e-8, atol=1e-12)


def test_trained_matrix_is_deterministic_and_images_zero_change(mesh):
    j = np.random.default_rng(1).normal(size=(30, mesh.n_triangles))
    a = greit_matrix(j, mesh, noise_figure=0.13)
    b = greit_matrix(j, mesh, hyperparameter=a.hyperparameter)
    np.testing.assert_array_equal(a.matrix, b.matrix)
    ref = np.linspace(1.0, 2.0, 30)
    assert (a.reconstruct(ref, ref) == 0).all()


def test_greit_is_a_method_not_a_prior(mesh):
    j = np.random.default_rng(2).normal(size=(30, mesh.n_triangles))
    with pytest.raises(ValueError, match="'greit' is a method, not a prior"):
        ReconstructionMatrix.from_jacobian(j, mesh, "greit", hyperparameter=0.1)


def test_bad_training_arguments(mesh):
    with pytest.raises(ValueError, match="> 0"):
        training_set(mesh, blob_width=0.0)
    with pytest.raises(ValueError, match="n_targets"):
        training_set(mesh, n_targets=0)
