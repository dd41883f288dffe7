"""The model-error rule of the hyperparameter (issue 35, :mod:`eit_skin.inverse.hyperparameter`).

A reference the homogeneous model cannot explain asks for more regularisation than its measured
noise: ``h`` is the larger of the noise-figure choice and the one whose fit leaves
``MODEL_ERROR_SHARE`` of the reference's misfit unexplained; a fixed ``solver.hyperparameter``
still overrides both, and a reference the model explains changes nothing.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eit_skin.inverse.hyperparameter import (
    H_RANGE,
    MODEL_ERROR_SHARE,
    choose_for_model_error,
    reference_misfit,
    unexplained_fraction,
)
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from test.support.patch_copies import small_disc_patch

SMALL = small_disc_patch("{method: one_step, prior: laplace, noise_figure: 0.3, image_pixels: 16}")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """(layer, imager, homogeneous model voltages [M])."""
    path = tmp_path_factory.mktemp("model_error") / "small.yaml"
    path.write_text(SMALL)
    layer = load_patch(path).layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    return layer, imager, np.asarray(imager.model_voltages)


def test_reference_misfit_is_the_typical_relative_residual_and_ignores_faults() -> None:
    m = np.linspace(1.0, 2.0, 21) * np.where(np.arange(21) % 2, 1.0, -1.0)
    v = 3.0 * m * (1.0 + 0.1 * np.random.default_rng(0).normal(size=21))  # 10 % channel gains
    eps = reference_misfit(v, m)
    assert 0.02 < eps < 0.2
    assert reference_misfit(1e-6 * v, 7.0 * m) == pytest.approx(eps)  # scale-free
    assert reference_misfit(5.0 * m, m) == pytest.approx(0.0, abs=1e-15)
    faulty = 5.0 * m
    faulty[:4] = [0.0, 1e3, -1e3, 0.0]  # a dead electrode and saturated channels: not model error
    assert reference_misfit(faulty, m) == pytest.approx(0.0, abs=1e-15)
    used = np.arange(21) >= 4
    assert reference_misfit(v, m, used) == pytest.approx(reference_misfit(v[4:], m[4:]))
    assert np.isnan(reference_misfit(np.zeros(21), m))


def test_chosen_h_leaves_the_asked_fraction_unexplained(small) -> None:
    _, imager, _ = small
    k = imager.matrix.gram[0]
    for fraction in (0.001, 0.01, 0.05):
        h = choose_for_model_error(k, fraction)
        assert H_RANGE[0] < h < H_RANGE[1]
        assert unexplained_fraction(k, h) == pytest.approx(fraction, rel=1e-6)
    hs = [choose_for_model_error(k, f) for f in (0.001, 0.01, 0.05)]
    assert hs == sorted(hs)  # more model error, more regularisation
    assert choose_for_model_error(k, 0.0) == H_RANGE[0]
    assert choose_for_model_error(k, float("nan")) == H_RANGE[0]
    assert choose_for_model_error(k, 1.0) == H_RANGE[1]


def test_a_reference_the_model_explains_keeps_the_noise_figure_choice(small) -> None:
    _, imager, v0 = small
    frames = v0 + np.random.default_rng(1).normal(0.0, 1e-4 * np.abs(v0).mean(), (10, v0.size))
    report = imager.use_reference(v0, frames)
    assert report.model_misfit < 1e-9 and not report.for_model_error
    by_noise = imager.matrix
    imager.use_reference(v0, frames, model_error_share=0.0)
    np.testing.assert_array_equal(by_noise.matrix, imager.matrix.matrix)  # bit for bit


def test_a_reference_the_model_misses_is_regularised_for_its_model_error(small) -> None:
    layer, imager, v0 = small
    rng = np.random.default_rng(2)
    reference = v0 * (1.0 + 0.2 * rng.normal(size=v0.size))  # 20 % channel gains: model error
    frames = reference + rng.normal(0.0, 1e-4 * np.abs(v0).mean(), (10, v0.size))
    noise_only = imager.use_reference(reference, frames, model_error_share=0.0)
    report = imager.use_reference(reference, frames)
    assert report.model_misfit == pytest.approx(reference_misfit(reference, v0))
    assert report.model_misfit > 0.1
    assert report.chosen and report.for_model_error
    assert report.hyperparameter > 2 * noise_only.hyperparameter
    k = imager.matrix.gram[0]
    assert unexplained_fraction(k, report.hyperparameter) == pytest.approx(
        MODEL_ERROR_SHARE * report.model_misfit, rel=1e-6
    )
    assert "hyperparameter" in report.lines()[-1] and "model error" in report.lines()[-1]
    # a fixed value in the patch still overrides both rules
    fixed = LayerImager.build(replace(layer, solver=replace(layer.solver, hyperparameter=0.02)))
    held = fixed.use_reference(reference, frames)
    assert not held.chosen and held.hyperparameter == 0.02
    assert fixed.matrix.hyperparameter == 0.02
