"""Frame -> image in one product (issue 16 item 2): the folded pixel matrix gives the images
of the element chain (reconstruct, unit, clip, gridding, mask) to float32 rounding."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid, PixelMatrix
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.patch.loading import load_patch
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE
from eit_skin.pipeline.builder import LayerImager
from test.patch_copies import small_disc_patch
from test.reconstruction_phantoms import RADIUS_M, phantom, setup

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
