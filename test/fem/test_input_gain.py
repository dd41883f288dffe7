"""The board's unequal input gains (``device.negative_input_gain``, issue 37 item 1).

A differential input whose minus side has gain ``g`` reads ``(V(plus) - V(sink)) -
g (V(minus) - V(sink))``; checked against the model's own matched readings of the pairs
(plus, sink) and (minus, sink), through the Jacobians by finite differences, as a no-op at
``g = 1``, and recovered by the device fit from one unloaded frame.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.device_fit import fit_device
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.patch.model import PatchError
from eit_skin.patch.protocol import Protocol
from eit_skin.pipeline.builder import forward_model
from test.support.patch_copies import small_disc_data

GAIN = 1.15  # the hydrogel set's OpenEIT board (docs/patch-schema.md)


def patch_with(**device):
    data = small_disc_data()
    if device:
        data["layers"][0]["device"] = device
    return patch_from_dict(data)


@pytest.fixture(scope="module")
def layers():
    """The same disc with matched inputs, the key at 1, and the minus input at GAIN."""
    return tuple(
        patch_with(**device).layers[0]
        for device in ({}, {"negative_input_gain": 1}, {"negative_input_gain": GAIN})
    )


@pytest.fixture(scope="module")
def mesh(layers):
    return build_mesh(layers[0])


def test_readings_are_the_plus_input_minus_g_times_the_minus_input_against_the_sink(layers, mesh):
    plain, _, unequal = layers
    model = forward_model(unequal, mesh)
    protocol = model.protocol
    k, plus, minus = protocol.measurements.T
    sink = protocol.injections[k, 1]
    matched = replace(protocol, negative_input_gain=1.0)

    def read(a, b):  # matched readings V(a) - V(b) of the same injections
        pairs = replace(matched, measurements=np.column_stack([k, a, b]))
        return ForwardModel(mesh, pairs, unequal.contact_impedance_ohm_m, unequal.current_a)

    sigma = unequal.material.sheet_conductance_s
    want = read(plus, sink).voltages(sigma) - GAIN * read(minus, sink).voltages(sigma)
    np.testing.assert_allclose(model.voltages(sigma), want, rtol=1e-10, atol=1e-15)
    # chiral: the pair just after the source differs from its mirror pair, unlike g = 1
    v1, vg = forward_model(plain, mesh).voltages(sigma), model.voltages(sigma)
    assert np.abs(vg - v1).max() > 0.05 * np.abs(v1).max()


def test_jacobians_match_finite_differences_at_unequal_gains(layers, mesh):
    model = forward_model(layers[2], mesh)
    rng = np.random.default_rng(3)
    s0 = layers[2].material.sheet_conductance_s
    sigma = s0 * (1 + 0.3 * rng.random(mesh.n_triangles))
    step = s0 * 1e-6 * rng.standard_normal(mesh.n_triangles)
    fd = (model.voltages(sigma + step) - model.voltages(sigma - step)) / 2
    J = model.jacobian(sigma)
    np.testing.assert_allclose(J @ step, fd, atol=1e-5 * np.abs(fd).max())
    basis = model.jacobian_basis(sigma)
    np.testing.assert_allclose(basis.combination @ basis.products, J, atol=1e-12 * np.abs(J).max())
    z = np.full(mesh.n_electrodes, layers[2].contact_impedance_ohm_m)
    dz = np.zeros_like(z)
    dz[5] = 1e-5 * z[5]
    protocol, current = model.protocol, layers[2].current_a
    fdz = (
        ForwardModel(mesh, protocol, z + dz, current).voltages(sigma)
        - ForwardModel(mesh, protocol, z - dz, current).voltages(sigma)
    ) / 2
    np.testing.assert_allclose(
        model.contact_jacobian(sigma)[:, 5] * dz[5], fdz, atol=1e-4 * np.abs(fdz).max()
    )


def test_a_gain_of_one_changes_nothing(layers, mesh):
    plain, one, unequal = layers
    assert one.content_hash == plain.content_hash != unequal.content_hash
    sigma = plain.material.sheet_conductance_s
    a, b = forward_model(plain, mesh), forward_model(one, mesh)
    assert np.array_equal(a.voltages(sigma), b.voltages(sigma))
    assert np.array_equal(a.jacobian(sigma), b.jacobian(sigma))
    assert (a.protocol.selection_matrix != b.protocol.selection_matrix).nnz == 0


@pytest.mark.parametrize(
    ("device", "protocol", "message"),
    [
        ({"negative_input_gain": 0}, None, r"device\.negative_input_gain: must be > 0"),
        ({"negative_input_gain": "high"}, None, r"device\.negative_input_gain: expected float"),
        (
            {"negative_input_gain": 1.1},
            {"drive": "trigonometric"},
            r"device\.negative_input_gain: needs a pair drive",
        ),
        (
            {"profile": "sciospec", "negative_input_gain": 1.1},
            None,
            r"device\.negative_input_gain",
        ),
    ],
)
def test_bad_gains_are_refused_naming_the_key(device, protocol, message):
    data = small_disc_data()
    data["layers"][0]["device"] = device
    if protocol:
        data["layers"][0]["protocol"] = protocol
    with pytest.raises(PatchError, match=rf"layers\[0\]\.{message}"):
        patch_from_dict(copy.deepcopy(data))


def test_a_current_pattern_protocol_refuses_a_gain():
    with pytest.raises(ValueError, match="needs a pair drive"):
        Protocol("x", 4, [[0, 1]], [[0, 2, 3]], currents=[[1, -1, 0, 0]], negative_input_gain=2)


@pytest.mark.parametrize("magnitude", [False, True])
def test_fit_device_recovers_the_gain_from_one_unloaded_frame(layers, mesh, magnitude):
    unequal = layers[2]
    protocol = replace(unequal.measured_protocol, magnitude=magnitude)
    truth = ForwardModel(mesh, protocol, unequal.contact_impedance_ohm_m, unequal.current_a)
    frame = truth.voltages(unequal.material.sheet_conductance_s)
    frame = frame * (1 + 0.002 * np.random.default_rng(4).standard_normal(frame.size))
    frame = np.abs(frame) if magnitude else frame
    start = replace(protocol, negative_input_gain=1.0)
    fit = fit_device(
        mesh,
        start,
        frame,
        2 * unequal.material.sheet_conductance_s,
        unequal.contact_impedance_ohm_m,
        unequal.current_a,
        magnitude=magnitude,
        fit_input_gain=True,
    )
    assert fit.negative_input_gain == pytest.approx(GAIN, rel=0.01)
    assert fit.residual < 0.01 < fit.initial_residual
    fixed = fit_device(
        mesh,
        start,
        frame,
        1e-4,
        unequal.contact_impedance_ohm_m,
        unequal.current_a,
        magnitude=magnitude,
    )
    assert fixed.negative_input_gain == 1.0 and fixed.residual > 5 * fit.residual


def test_fit_device_command_writes_the_gain(tmp_path, capsys, layers):
    import yaml

    data = small_disc_data()
    path = tmp_path / "disc.yaml"
    path.write_text(yaml.safe_dump(data))
    unequal = layers[2]
    frame = forward_model(unequal).voltages(unequal.material.sheet_conductance_s)
    frames = tmp_path / "ref.npz"
    np.savez(frames, reference=frame, frames=frame[None])
    args = ["fit-device", "--patch", str(path), "--frames", str(frames)]
    assert main([*args, "--fit-input-gain", "--write"]) == 0
    out = capsys.readouterr().out
    assert "negative input gain: 1.15" in out and "negative_input_gain: 1.15" in out
    written = load_patch(path).layers[0]
    assert written.device.negative_input_gain == pytest.approx(GAIN, rel=1e-3)
    assert written.content_hash != layers[0].content_hash
