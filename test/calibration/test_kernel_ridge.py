"""Kernel ridge regression: leave-one-out chooses the principal-component projection."""

from __future__ import annotations

import numpy as np

from eit_skin.calibration.kernel_ridge import COMPONENT_COUNTS, KernelRidge


def noisy_embedding(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points of a smooth function of 3 latent variables, seen through 100 channels
    of which 97 directions carry only noise: (inputs ``[n, 100]``, targets ``[n, 2]``)."""
    rng = np.random.default_rng(seed)
    latent = rng.uniform(-1.0, 1.0, size=(n, 3))
    mixing = rng.standard_normal((3, 100))
    inputs = latent @ mixing + 0.5 * rng.standard_normal((n, 100))
    targets = np.column_stack([np.sin(2 * latent[:, 0]), latent[:, 1] * latent[:, 2]])
    return inputs, targets


def test_noise_directions_are_projected_out_when_leave_one_out_says_so() -> None:
    inputs, targets = noisy_embedding(300)
    plain = KernelRidge.fit(inputs[:200], targets[:200])
    projected = KernelRidge.fit(inputs[:200], targets[:200], components=COMPONENT_COUNTS)
    assert plain.projection is None
    assert projected.projection is not None and projected.projection.shape == (100, 8)
    assert projected.loo_error < 0.8 * plain.loo_error  # 0.073 vs 0.101
    assert projected.inputs.shape == (200, 100)  # the raw training features are kept
    errors = [
        np.median(np.linalg.norm(m.predict(inputs[200:])[0] - targets[200:], axis=1))
        for m in (plain, projected)
    ]
    assert errors[1] < 0.9 * errors[0]  # held-out points agree with it: 0.070 vs 0.087


def test_a_projected_model_round_trips_through_its_arrays() -> None:
    inputs, targets = noisy_embedding(150, seed=1)
    model = KernelRidge.fit(inputs[:100], targets[:100], components=COMPONENT_COUNTS)
    assert model.projection is not None
    loaded = KernelRidge.from_arrays(model.arrays("position"), "position")
    for a, b in zip(model.predict(inputs[100:]), loaded.predict(inputs[100:]), strict=True):
        np.testing.assert_array_equal(a, b)
    plain = KernelRidge.fit(inputs[:100], targets[:100])
    assert not any(k.endswith("projection") for k in plain.arrays("position"))
