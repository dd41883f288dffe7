"""Frame -> relative change -> image: the merged single-frame product (reciprocal channels
share a column) gives the element chain to float32 rounding; frames with left-out channels
take the reduced matrices; a layer's frame images are the node's numbers."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from eit_skin.fem.image_grid import proportional_columns
from eit_skin.inverse.one_step import ReconstructionMatrix, relative_difference
from eit_skin.pipeline.frame_plan import FrameChecks, reference_step
from test.support.pressed_disc import pressed_disc
from test.support.reconstruction_phantoms import RADIUS_M, phantom, setup

R = RADIUS_M


@pytest.fixture(scope="module")
def s():
    return setup()


@pytest.fixture(scope="module")
def matrix(s):
    return ReconstructionMatrix.build(s.coarse, prior="laplace", hyperparameter=0.03)


def _chain(matrix, frame, v0, excluded=None):
    """The float64 element chain: the (reduced) matrix times the relative change."""
    keep = np.ones(matrix.n_channels, bool) if excluded is None else ~excluded
    keep &= np.isfinite(frame)
    rm = matrix if keep.all() else matrix.without_channels(~keep)
    d = relative_difference(frame, v0)[keep]
    return np.asarray(rm.matrix, dtype=np.float64) @ d


def test_one_frame_is_the_merged_product_of_the_element_chain(s, matrix):
    v = phantom(s, [(0.3 * R, -0.2 * R, 0.15 * R, 3.0)])
    got = matrix.reconstruct(v, s.v0)
    want = _chain(matrix, v, s.v0)
    assert got.dtype == np.float32 and got.shape == (matrix.n_elements,)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.abs(want).max())
    np.testing.assert_array_equal(got, matrix.merged.solve_frame(v, s.v0))
    drifted = s.v0 * 1.001  # the reference is read every frame, never cached
    assert matrix.reconstruct(v, drifted).tobytes() != got.tobytes()


def test_frames_with_left_out_channels_take_the_reduced_matrices(s, matrix):
    """NaN and Inf values and excluded channels: no warning, the reduced matrix's values."""
    v = phantom(s, [(0.1 * R, 0.4 * R, 0.15 * R, 2.0)])
    dead = s.coarse.protocol.touching([4])
    cases = [(v, dead)]
    for value in (np.nan, np.inf, -np.inf):
        bad = v.copy()
        bad[[3, 100]] = value
        cases.append((bad, None))
    for frame, excluded in cases:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got = matrix.reconstruct(frame, s.v0, excluded)
        want = _chain(matrix, frame, s.v0, excluded)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.abs(want).max())
        assert np.abs(matrix.reconstruct(v, s.v0) - got).max() > 0  # really left out
    np.testing.assert_array_equal(  # the next finite frame is imaged as before them
        matrix.reconstruct(v, s.v0), matrix.merged.solve_frame(v, s.v0)
    )


def test_proportional_columns_are_merged_and_others_kept():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 6))
    a[:, 4] = -2.5 * a[:, 1]  # a pair, negative factor
    off = rng.normal(size=40)
    a[:, 5] = 0.5 * a[:, 2] + 1e-6 * off * np.linalg.norm(a[:, 2]) / np.linalg.norm(off)
    # column 5: nearly parallel to 2 but 2e-6 off, above the tolerance: kept apart
    inputs, weights = proportional_columns(a)
    assert inputs.shape == weights.shape == (2, 5)
    np.testing.assert_array_equal(inputs[0], [0, 1, 2, 3, 5])
    np.testing.assert_array_equal(inputs[1], [6, 4, 6, 6, 6])  # 6 = M: the zero input
    np.testing.assert_allclose(weights, [[1, 1, 1, 1, 1], [0, -2.5, 0, 0, 0]], rtol=1e-12)
    x = rng.normal(size=6)
    merged = (weights * np.append(x, 0.0)[inputs]).sum(axis=0)
    np.testing.assert_allclose(a[:, inputs[0]] @ merged, a @ x, rtol=1e-12)
    # no pair among random columns, zero columns never pair
    z = rng.normal(size=(40, 4))
    z[:, [1, 3]] = 0.0
    assert proportional_columns(z)[0].shape == (2, 4)


def test_reciprocal_channels_share_a_column_weighted_or_not(s, matrix):
    """The adjacent protocol's 208 channels are 104 reciprocal pairs: the merged matrix has
    104 columns, also with per-channel noise weights (weights then differ within a pair)."""
    m = matrix.n_channels
    weighted = matrix.with_channel_scale(np.random.default_rng(0).uniform(0.5, 3.0, m))
    measurements = s.coarse.protocol.measurements
    for rm in (matrix, weighted):
        merged = rm.merged
        p = merged.matrix.shape[1]
        assert p == m // 2
        first, second = merged.index[:p], merged.index[p:]
        # each pair is a reciprocal measurement: drive and measure pairs swapped
        a, b = measurements[first], measurements[second]
        assert np.array_equal(a[:, 0], b[:, 1]) and np.array_equal(a[:, 1], b[:, 0])
    w = merged.weights[p:]
    assert w.min() < 0.5 and w.max() > 2.0  # the noise weights moved into the merge
    v = phantom(s, [(0.2 * R, 0.3 * R, 0.15 * R, 2.0)])
    want = _chain(weighted, v, s.v0)
    got = weighted.reconstruct(v, s.v0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.abs(want).max())
    with pytest.raises(ValueError, match="every channel"):
        _ = matrix.without_channels(s.coarse.protocol.touching([2])).merged


def test_layer_frame_images_match_the_three_steps(tmp_path):
    disc = pressed_disc(
        tmp_path, "{method: one_step, prior: laplace, hyperparameter: 0.05, image_pixels: 16}", 1.5
    )
    layer, imager, v0, v = disc.layer, disc.imager, disc.unloaded_v, disc.pressed_v
    imager.use_reference(v0)
    steps = imager.images(imager.physical(imager.relative_change(v, v0)))
    got = imager.frame_images(v, v0)
    np.testing.assert_array_equal(got, steps)  # bit for bit
    plan = imager.frame_plan  # and the node's planned step
    np.testing.assert_array_equal(got, reference_step(plan, v, v0, FrameChecks()).image)
    assert np.nanmax(got) > 0.2 * layer.material.pressure_scale_pa  # a real press
    batch = imager.frame_images(np.stack([v, v0]), v0)
    np.testing.assert_array_equal(
        batch, imager.images(imager.physical(imager.relative_change(np.stack([v, v0]), v0)))
    )
    # a stretch layer (non-linear unit) runs the three steps themselves
    stretch = replace(
        imager,
        layer=replace(
            layer,
            material=replace(
                layer.material, quantity="stretch", pressure_scale_pa=None, gauge_factor=2.0
            ),
        ),
    )
    np.testing.assert_array_equal(
        stretch.frame_images(v, v0),
        stretch.images(stretch.physical(stretch.relative_change(v, v0))),
    )
