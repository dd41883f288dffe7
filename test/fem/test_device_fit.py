"""Device calibration (eit_skin.fem.device_fit): contact impedance and sheet conductance.

Frames are simulated on a finer disc mesh than the one fitted, so mesh error is part of the
test; the contact-impedance sensitivity is checked against finite differences and the
scaling law ``V(c sigma, z / c) = V(sigma, z) / c``.
"""

import numpy as np
import pytest

from eit_skin.fem.device_fit import fit_device, measures_driven
from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

R = 0.05  # disc radius, m
W = 0.2  # electrode width, rad (10 mm)
SIGMA = 0.5  # S
Z = 0.01  # ohm*m: z / (sigma * width) = 2, a contact-dominated skin electrode
FULL = build_protocol(ProtocolSpec(layout="full", measure_driven=True), 16)
ADJ = build_protocol(ProtocolSpec(), 16)


def _frame(protocol, z, noise, seed=0):
    data = ForwardModel(disk_mesh(R, 16, W, R / 24, electrode_h_m=R / 128), protocol, z, 1e-3)
    v = data.voltages(SIGMA)
    rng = np.random.default_rng(seed)
    return v + noise * np.sqrt(np.mean(v**2)) * rng.standard_normal(v.size)


@pytest.fixture(scope="module")
def fit_mesh():
    return disk_mesh(R, 16, W, R / 16, electrode_h_m=R / 128)


def test_contact_jacobian_matches_finite_differences_and_the_scaling_law():
    mesh = disk_mesh(R, 16, W, R / 8)
    z = Z * np.linspace(0.3, 3, 16)
    model = ForwardModel(mesh, ADJ, z, 1e-3)
    J = model.contact_jacobian(SIGMA)
    assert J.shape == (ADJ.n_measurements, 16)
    for el in (0, 9):
        dz = np.zeros(16)
        dz[el] = 1e-4 * z[el]
        up = ForwardModel(mesh, ADJ, z + dz, 1e-3).voltages(SIGMA)
        down = ForwardModel(mesh, ADJ, z - dz, 1e-3).voltages(SIGMA)
        fd = (up - down) / (2 * dz[el])
        assert np.linalg.norm(fd - J[:, el]) < 1e-6 * np.linalg.norm(fd)
    # sigma dV/dsigma = -V + sum_l z_l dV/dz_l for a homogeneous sheet
    lhs = SIGMA * model.jacobian(SIGMA).sum(axis=1)
    rhs = -model.voltages(SIGMA) + J @ z
    np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-12 * np.abs(lhs).max())


def test_recovers_per_electrode_contact_impedance_and_flags_the_bad_contact(fit_mesh):
    rng = np.random.default_rng(1)
    z_true = Z * np.exp(rng.uniform(-0.7, 0.7, 16))
    z_true[5] *= 8.0  # a loose electrode
    v = _frame(FULL, z_true, noise=1e-3)
    assert measures_driven(FULL) and not measures_driven(ADJ)
    # start far away: a tenth of the conductance, ten times the contact impedance
    fit = fit_device(fit_mesh, FULL, v, SIGMA / 10, 10 * Z, 1e-3)
    assert fit.per_electrode
    err = np.abs(fit.contact_impedance_ohm_m / z_true - 1)
    assert err.max() < 0.05, err
    assert fit.sheet_conductance_s == pytest.approx(SIGMA, rel=0.02)
    assert fit.bad_contacts == (5,) and fit.contact_determined.all()
    # z sigma / width: the contact against the sheet under the electrode (width 10 mm)
    np.testing.assert_allclose(fit.contact_ratio, z_true * SIGMA / (W * R), rtol=0.06)
    assert fit.residual < 0.003 < fit.initial_residual  # noise is 0.1 % of the rms
    assert any("bad contact" in line and ": 5" in line for line in fit.lines())


def test_recovers_a_common_contact_impedance_from_adjacent_frames(fit_mesh):
    """Without measurements on driven electrodes z acts only through the electrodes' shunting:
    weakly determined, so the two meshes' difference shows more (measured: 5.1 % low)."""
    v = _frame(ADJ, Z, noise=1e-4)
    fit = fit_device(fit_mesh, ADJ, v, SIGMA * 3, Z / 4, 1e-3)
    assert not fit.per_electrode
    np.testing.assert_allclose(fit.contact_impedance_ohm_m, Z, rtol=0.10)
    assert fit.sheet_conductance_s == pytest.approx(SIGMA, rel=0.02)
    assert fit.bad_contacts == ()


def test_contact_impedances_the_frame_does_not_determine_are_kept_and_reported():
    """Adjacent data of contact-dominated electrodes (z sigma / width = 50), 1 % noise: a
    per-electrode fit (forced) cannot pin every z; those keep their start and are named."""
    mesh = disk_mesh(R, 16, W, R / 8)
    v = ForwardModel(mesh, ADJ, 100 * Z, 1e-3).voltages(SIGMA)
    v = v * (1 + 1e-2 * np.random.default_rng(0).standard_normal(v.size))
    fit = fit_device(mesh, ADJ, v, SIGMA, Z, 1e-3, per_electrode=True)
    undetermined = np.flatnonzero(~fit.contact_determined)
    assert 0 < undetermined.size < 16
    kept = fit.contact_impedance_ohm_m[undetermined]
    np.testing.assert_allclose(kept, kept[0])  # the common start value, untouched
    assert "not determined by this frame" in fit.lines()[1]
    assert str(int(undetermined[0])) in fit.lines()[1]


def test_gain_and_sigma_trade_off_and_sign_errors_are_refused():
    mesh = disk_mesh(R, 16, W, R / 8)
    v = ForwardModel(mesh, ADJ, Z, 1e-3).voltages(SIGMA)
    in_mv = fit_device(mesh, ADJ, 1e3 * v, SIGMA, Z, 1e-3, gain=1e3)
    assert in_mv.sheet_conductance_s == pytest.approx(SIGMA, rel=1e-4)
    as_volts = fit_device(mesh, ADJ, 1e3 * v, SIGMA, Z, 1e-3)
    assert as_volts.sheet_conductance_s == pytest.approx(SIGMA / 1e3, rel=1e-4)
    assert as_volts.gain_at(SIGMA) == pytest.approx(1e3, rel=1e-4)
    magnitudes = fit_device(mesh, ADJ, np.abs(v), SIGMA, Z, 1e-3, magnitude=True)
    assert magnitudes.sheet_conductance_s == pytest.approx(SIGMA, rel=1e-4)
    with pytest.raises(ValueError, match="sign is opposite"):
        fit_device(mesh, ADJ, -v, SIGMA, Z, 1e-3)
    with pytest.raises(ValueError, match=r"reference: expected \[208\]"):
        fit_device(mesh, ADJ, v[:100], SIGMA, Z, 1e-3)


PATCH = """# calibration test patch (comments are kept)
name: cal
frame_id: skin_link
layers:
  - name: skin
    outline: {type: circle, radius: 0.05}
    electrodes: {count: 16, width: 0.01, contact_impedance: 0.01}
    material: {quantity: pressure, sheet_conductance: 1.0, pressure_scale: 1.0e4}
    protocol: {layout: full, measure_driven: true}
    mesh: {max_edge: 0.006, inverse_max_edge: 0.012}
"""


def test_fit_device_command_writes_the_fit_and_the_matrix_follows(tmp_path, capsys):
    from eit_skin.cli.main import main
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.patch.loading import load_patch
    from eit_skin.pipeline.builder import LayerImager, cache_key

    path = tmp_path / "cal.yaml"
    path.write_text(PATCH)
    layer = load_patch(path).layers[0]
    protocol = build_protocol(layer.protocol, 16)
    z_true = 0.02 * np.exp(np.random.default_rng(2).uniform(-0.5, 0.5, 16))
    z_true[3] *= 10
    data = ForwardModel(build_mesh(layer, 0.003), protocol, z_true, layer.current_a)
    full = protocol.device_frame(data.voltages(0.3))  # the board's 256 numbers
    assert full.shape == (256,)
    np.savez(tmp_path / "noload.npz", reference=full, frames=full[None])
    args = ["fit-device", "--patch", str(path), "--frames", str(tmp_path / "noload.npz")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "bad contact (> 3 x median z or channel residual): 3" in out
    assert "not written" in out and path.read_text() == PATCH
    assert main([*args, "--write"]) == 0
    calibrated = load_patch(path).layers[0]
    assert path.read_text().startswith("# calibration test patch (comments are kept)")
    z = np.asarray(calibrated.contact_impedance_ohm_m)
    np.testing.assert_allclose(z, z_true, rtol=0.05)
    assert calibrated.material.sheet_conductance_s == pytest.approx(0.3, rel=0.03)
    assert cache_key(calibrated) != cache_key(layer)
    # the reconstruction is built on the calibrated model: its homogeneous voltages fit the frame
    imager = LayerImager.build(calibrated, cache_dir=tmp_path / "cache")
    v = protocol.select(full)
    assert np.linalg.norm(imager.model_voltages - v) < 0.03 * np.linalg.norm(v)
    assert np.linalg.norm(LayerImager.build(layer, cache_dir=None).model_voltages - v) > 0.2 * (
        np.linalg.norm(v)
    )
    # a bad frame: one line naming the file and key, nothing written
    np.savez(tmp_path / "bad.npz", reference=full[:200], frames=full[None, :200])
    before = path.read_text()
    bad = ["fit-device", "--patch", str(path), "--frames", str(tmp_path / "bad.npz")]
    assert main([*bad, "--write"]) == 1
    err = capsys.readouterr().err
    assert "bad.npz: 'reference'" in err and "expects 256" in err and err.count("\n") == 1
    assert path.read_text() == before
    # the former name still runs the command, after one deprecation line
    assert main(["calibrate-device", *bad[1:], "--write"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "eit-skin: 'calibrate-device' is deprecated, use 'fit-device'"
    assert "bad.npz: 'reference'" in err[1] and len(err) == 2


def test_former_command_names_are_the_new_commands(capsys):
    from eit_skin.cli.main import COMMANDS, DEPRECATED, main

    for old, new in DEPRECATED.items():
        assert new in COMMANDS and old not in COMMANDS
        with pytest.raises(SystemExit) as stop:
            main([old, "--help"])
        assert stop.value.code == 0
        captured = capsys.readouterr()
        assert captured.err == f"eit-skin: '{old}' is deprecated, use '{new}'\n"
        assert captured.out.startswith(f"usage: eit-skin {new} ")


def test_fit_device_command_fits_a_tank_at_its_depth_and_refuses_fit_depth_on_a_stretch_layer(
    tmp_path, capsys
):
    from eit_skin.cli.main import main
    from eit_skin.fem.elements import TankDepth
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.patch.loading import load_patch

    tank = PATCH.replace("    protocol:", "    depth: 0.05\n    protocol:").replace(
        "layout: full, measure_driven: true", "drive: adjacent, measure: adjacent"
    )
    path = tmp_path / "tank.yaml"
    path.write_text(tank)
    layer = load_patch(path).layers[0]
    data = ForwardModel(
        build_mesh(layer), layer.measured_protocol, 0.02, 1e-3, TankDepth(0.05, 0.01, 0.3)
    )
    frame = layer.measured_protocol.device_frame(data.voltages(0.3))
    np.savez(tmp_path / "noload.npz", reference=frame, frames=frame[None])
    args = ["fit-device", "--patch", str(path), "--frames", str(tmp_path / "noload.npz")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "sheet conductance: 0.3 S" in out and "fit residual: 0.000%" in out, out
    stretch = tank.replace("    depth: 0.05\n", "").replace(
        "pressure_scale: 1.0e4", "gauge_factor: 2.0"
    )
    stretch = stretch.replace("quantity: pressure", "quantity: stretch")
    path.write_text(stretch)
    assert main([*args, "--fit-depth"]) == 1
    assert "--fit-depth needs a tank" in capsys.readouterr().err
