"""The one chain layer -> meshes -> forward model -> method, for every solver.method."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import build_mesh
from eit_skin.frames import FLAG_SATURATED
from eit_skin.inverse.gauss_newton import FitOptions, GaussNewtonSolver, WarmStart
from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import LayerImager, forward_model, with_method
from eit_skin.resources import config_path

pytestmark = pytest.mark.filterwarnings("error")

ELBOW_SOLVER = (
    "solver: {method: one_step, prior: laplace, noise_figure: 0.3, image_pixels: 64, "
    "channel_weights: measured}"
)
GN_SOLVER = (
    "solver: {method: gauss_newton, prior: laplace, noise_figure: 0.3, max_iterations: 3, "
    "image_pixels: 64}"
)
PRESS = np.array([0.010, 0.020])  # m, on the elbow sheet (90 x 160 mm)


@pytest.fixture(scope="module")
def gn_layer(tmp_path_factory):
    """The shipped elbow layer, written as a config with method: gauss_newton."""
    text = config_path("elbow").read_text()
    assert text.count(ELBOW_SOLVER) == 1
    path = tmp_path_factory.mktemp("patch") / "elbow_gn.yaml"
    path.write_text(text.replace(ELBOW_SOLVER, GN_SOLVER))
    return load_patch(path).layers[0]


@pytest.fixture(scope="module")
def data(gn_layer):
    """No-load reference and two pressed frames ``[2, M]`` V on a finer mesh."""
    model = forward_model(gn_layer, build_mesh(gn_layer, 0.6 * gn_layer.mesh.max_edge_m))
    s0 = gn_layer.material.sheet_conductance_s
    frames = []
    for ratio in (1.5, 3.0):
        sigma = np.full(model.mesh.n_triangles, s0)
        sigma[np.linalg.norm(model.mesh.centroids - PRESS, axis=1) < 0.012] *= ratio
        frames.append(model.voltages(sigma))
    return model.voltages(s0), np.stack(frames)


def test_gauss_newton_layer_images_what_its_solver_gives(gn_layer, data, tmp_path):
    layer = gn_layer
    assert (layer.solver.method, layer.solver.max_iterations) == ("gauss_newton", 3)
    imager = LayerImager.build(layer, cache_dir=tmp_path)
    assert imager.method == "gauss_newton" and not imager.from_cache
    assert isinstance(imager.reconstructor, GaussNewtonReconstructor)
    # the same chain by hand: forward mesh, inverse mesh for the unknowns, h for the layer's
    # noise figure on the one-step matrix with the layer's prior (the first GN step)
    fwd = ForwardModel(
        build_mesh(layer),
        build_protocol(layer.protocol, layer.n_electrodes),
        layer.contact_impedance_ohm_m,
        layer.current_a,
    )
    inverse = build_mesh(layer, layer.mesh.inverse_max_edge_m)
    s0 = layer.material.sheet_conductance_s
    one = ReconstructionMatrix.build(fwd, "laplace", None, s0, inverse, noise_figure=0.3)
    assert imager.reconstructor.hyperparameter == pytest.approx(one.hyperparameter, rel=1e-12)
    solver = GaussNewtonSolver(fwd, s0, "laplace", one.hyperparameter, parameter_mesh=inverse)
    reference, frames = data
    flags = np.zeros(imager.n_measurements, np.uint8)
    flags[[4, 90]] = FLAG_SATURATED
    rec = imager.reconstructor
    for mask in (None, flags):
        got = imager.relative_change(frames, reference, mask)
        assert got.dtype == np.float32 and got.shape == (2, inverse.n_triangles)
        warm = WarmStart()  # the frames are a sequence: each fit starts where the last ended
        for frame, values in zip(frames, got, strict=True):
            excluded = None if mask is None else mask != 0
            res = solver.difference(
                frame,
                reference,
                excluded,
                warm=warm,
                options=FitOptions(
                    max_iterations=3, step_tolerance=rec.step_tolerance, relinearise=rec.relinearise
                ),
            )
            np.testing.assert_allclose(values, res.parameter_change, rtol=1e-5, atol=1e-6)
            cold = solver.difference(
                frame, reference, excluded, options=FitOptions(max_iterations=3)
            )
            assert abs(values.max() / cold.parameter_change.max() - 1) < 0.05
        # the press is found, more conductive, and the larger contrast reads larger
        k = np.argmax(got, axis=1)
        assert np.linalg.norm(inverse.centroids[k] - PRESS, axis=1).max() < 0.012
        assert 0 < got[0].max() < got[1].max()
    # a restart loads h and the Jacobian from the cache and images the same
    again = LayerImager.build(layer, cache_dir=tmp_path)
    assert again.from_cache and again.method == "gauss_newton"
    rec.reset()  # both start cold
    plain = imager.relative_change(frames, reference)
    np.testing.assert_array_equal(again.relative_change(frames, reference), plain)


def test_fault_tolerant_gauss_newton_leaves_a_dead_electrode_out(gn_layer, data):
    imager = LayerImager.build(gn_layer, cache_dir=None)
    reference, frames = data
    dead = imager.protocol.touching([6])
    broken = frames.copy()
    broken[:, dead] = np.random.default_rng(1).normal(0.0, 1.0, (2, dead.sum()))
    reconstructor = imager.fault_tolerant()
    values = reconstructor.reconstruct(broken, reference)
    assert reconstructor.last_faulty.tolist() == [6]
    excluded = np.where(dead, np.uint8(FLAG_SATURATED), np.uint8(0))
    imager.reconstructor.reset()  # the same frame sequence again, from a cold start
    np.testing.assert_array_equal(values, imager.relative_change(broken, reference, excluded))


def test_with_method_keeps_a_linearisation_and_resets_a_trained_one():
    arm = load_patch(config_path("arm")).layers[0]
    elbow = load_patch(config_path("elbow")).layers[0]
    assert arm.solver.method == "greit" and elbow.solver.method == "one_step"
    gn = with_method(elbow, "gauss_newton")
    assert gn.solver.method == "gauss_newton"
    assert (gn.solver.noise_figure, gn.solver.prior) == (0.3, "laplace")
    assert with_method(elbow, "one_step") is elbow
    from dataclasses import replace

    tuned = replace(arm, solver=replace(arm.solver, hyperparameter=0.01))
    moved = with_method(tuned, "gauss_newton")  # h and NF 0.13 were chosen for the GREIT matrix
    assert (moved.solver.hyperparameter, moved.solver.noise_figure) == (None, 0.3)
    assert moved.content_hash != tuned.content_hash  # its own cache entry
    with pytest.raises(ValueError, match="unknown 'jac'"):
        with_method(arm, "jac")
