"""Frame -> image in one product (issue 16 item 2): the folded pixel matrix gives the images
of the element chain (reconstruct, unit, clip, gridding, mask) to float32 rounding."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid, PixelMatrix, proportional_columns
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.patch.loading import load_patch
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE
from eit_skin.pipeline.builder import LayerImager
from test.support.patch_copies import small_disc_patch
from test.support.reconstruction_phantoms import RADIUS_M, phantom, setup

R = RADIUS_M


@pytest.fixture(scope="module")
def s():
    return setup()


@pytest.fixture(scope="module")
def matrix(s):
    return ReconstructionMatrix.build(s.coarse, prior="laplace", hyperparameter=0.03)


def _chain(matrix, grid, frames, v0, scale, floor, excluded=None):
    """The element chain in float64: reconstruct, unit, clip, then gridding."""
    x = np.asarray(matrix.reconstruct(frames, v0, excluded), dtype=np.float64)
    return grid.to_image(np.maximum(scale * x, floor))


def test_images_are_the_element_chain_in_one_product(s, matrix):
    frames = np.stack(
        [
            phantom(s, [(0.3 * R, -0.2 * R, 0.15 * R, 3.0)]),
            phantom(s, [(-0.5 * R, 0.1 * R, 0.2 * R, 0.05)]),  # deep enough to be clipped
        ]
    )
    scale, floor = 2.0e4, 2.0e4 * RELATIVE_CHANGE_RANGE[0]
    got = matrix.images(frames, s.v0, s.grid, scale, floor)
    want = _chain(matrix, s.grid, frames, s.v0, scale, floor)
    assert got.dtype == np.float32 and got.shape == (2, *s.grid.shape)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(np.isnan(got[0]), ~s.grid.inside)
    peak = np.nanmax(np.abs(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * peak)
    assert np.nanmin(got[1]) == np.float32(floor)  # the clip acts in the product path
    single = matrix.images(frames[0], s.v0, s.grid, scale, floor)
    np.testing.assert_allclose(single, got[0], rtol=0, atol=1e-6 * peak)
    # only the elements under pixels are kept
    pixels = matrix.pixel_matrix(s.grid, scale, floor)
    assert pixels.matrix.shape[0] == np.unique(pixels.elements).size <= s.coarse.mesh.n_triangles


def test_frames_with_left_out_channels_take_the_element_path(s, matrix):
    v = phantom(s, [(0.1 * R, 0.4 * R, 0.15 * R, 2.0)])
    nan = v.copy()
    nan[[5, 77]] = np.nan
    dead = s.coarse.protocol.touching([4])
    for frame, excluded in ((nan, None), (v, dead)):
        got = matrix.images(frame, s.v0, s.grid, 3.0, excluded=excluded)
        want = _chain(matrix, s.grid, frame, s.v0, 3.0, -np.inf, excluded)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7 * np.nanmax(np.abs(want)))
    # and they differ from the all-channel image (the channels really were left out)
    assert np.nanmax(np.abs(matrix.images(v, s.v0, s.grid, 3.0) - got)) > 0


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
    """The adjacent protocol's 208 channels are 104 reciprocal pairs: the folded matrix has
    104 columns, also with per-channel noise weights (weights then differ within a pair)."""
    m = matrix.n_channels
    weighted = matrix.with_channel_scale(np.random.default_rng(0).uniform(0.5, 3.0, m))
    measurements = s.coarse.protocol.measurements
    for rm in (matrix, weighted):
        pixels = rm.pixel_matrix(s.grid, 2.0)
        assert pixels.matrix.shape[1] == m // 2
        first, second = pixels.inputs
        # each pair is a reciprocal measurement: drive and measure pairs swapped
        a, b = measurements[first], measurements[second]
        assert np.array_equal(a[:, 0], b[:, 1]) and np.array_equal(a[:, 1], b[:, 0])
    w = pixels.weights[1]
    assert w.min() < 0.5 and w.max() > 2.0  # the noise weights moved into the merge
    v = phantom(s, [(0.2 * R, 0.3 * R, 0.15 * R, 2.0)])
    want = _chain(weighted, s.grid, v, s.v0, 2.0, -np.inf)
    got = weighted.images(v, s.v0, s.grid, 2.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.nanmax(np.abs(want)))


def test_single_frame_buffers_recover_from_bad_frames_and_write_into_out(s, matrix):
    """NaN and Inf frames take the element path without a warning; the next finite frame is
    imaged as before them (no NaN left in the buffers); a changed reference is used."""
    v = phantom(s, [(-0.3 * R, 0.1 * R, 0.15 * R, 3.0)])
    scale, floor, ceiling = 2.0e4, -1.8e4, 1.0e5
    before = matrix.images(v, s.v0, s.grid, scale, floor, ceiling=ceiling)
    for value in (np.nan, np.inf, -np.inf):
        bad = v.copy()
        bad[[3, 100]] = value
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got = matrix.images(bad, s.v0, s.grid, scale, floor, ceiling=ceiling)
        want = np.maximum(_chain(matrix, s.grid, bad, s.v0, scale, floor), floor)
        want = np.minimum(want, ceiling)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.nanmax(np.abs(want)))
        assert np.nanmax(np.abs(got - before)) > 0  # channels 3 and 100 were left out
        again = matrix.images(v, s.v0, s.grid, scale, floor, ceiling=ceiling)
        np.testing.assert_array_equal(again, before)
    out = np.empty(s.grid.shape, dtype=np.float32)
    assert matrix.images(v, s.v0, s.grid, scale, floor, ceiling=ceiling, out=out) is out
    np.testing.assert_array_equal(out, before)
    plan = matrix.frame_imager(s.grid, scale, floor, ceiling)
    with plan._lock:  # buffers busy (another thread): the allocating path, same image
        assert plan.image(v, s.v0) is None
        busy = matrix.images(v, s.v0, s.grid, scale, floor, ceiling=ceiling)
    np.testing.assert_allclose(busy, before, rtol=0, atol=1e-6 * np.nanmax(np.abs(before)))
    other = ImageGrid.build(s.coarse.mesh, 16)  # alternating grids keep their imagers
    small = matrix.images(v, s.v0, other, scale)
    assert matrix.frame_imager(s.grid, scale, floor, ceiling) is plan
    assert matrix.frame_imager(other, scale) is matrix.frame_imager(other, scale)
    np.testing.assert_array_equal(matrix.images(v, s.v0, other, scale), small)
    drifted = s.v0 * 1.001
    want = _chain(matrix, s.grid, v, drifted, scale, floor)
    got = matrix.images(v, drifted, s.grid, scale, floor)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.nanmax(np.abs(want)))
    assert matrix.images(v, s.v0, s.grid, scale, floor).tobytes() != got.tobytes()


def test_pixel_matrix_checks_its_input(s, matrix):
    with pytest.raises(ValueError, match="element_matrix"):
        PixelMatrix.build(s.grid, np.ones((3, 208)))
    with pytest.raises(ValueError, match="scale"):
        PixelMatrix.build(s.grid, matrix.matrix, 0.0)
    other = ImageGrid.build(s.coarse.mesh, 16)
    assert matrix.pixel_matrix(other).shape == other.shape  # cached per grid


SMALL = small_disc_patch(
    "{method: one_step, prior: laplace, hyperparameter: 0.05, image_pixels: 16}"
)


def test_layer_frame_images_match_the_three_steps(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text(SMALL)
    layer = load_patch(path).layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    forward = ForwardModel(
        imager.mesh, imager.protocol, layer.contact_impedance_ohm_m, layer.current_a
    )
    s0 = layer.material.sheet_conductance_s
    sigma = np.full(imager.mesh.n_triangles, s0)
    sigma[np.linalg.norm(imager.mesh.centroids - [0.015, 0.01], axis=1) < 0.008] *= 1.5
    v0, v = forward.voltages(s0), forward.voltages(sigma)
    imager.use_reference(v0)
    steps = imager.images(imager.physical(imager.relative_change(v, v0)))
    got = imager.frame_images(v, v0)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(steps))
    np.testing.assert_allclose(got, steps, rtol=0, atol=1e-5 * np.nanmax(np.abs(steps)))
    assert np.nanmax(got) > 0.2 * layer.material.pressure_scale_pa  # a real press
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
