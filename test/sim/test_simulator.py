"""Physics simulator: ground truth vs frames, signs, reproducibility, ADC, faults, drift."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.forward_update import LocalForwardUpdate
from eit_skin.frames import FLAG_SATURATED
from eit_skin.io.npz import load_frames_npz
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.adc import AdcConfig, AdcModel
from eit_skin.sim.drift import NO_DRIFT, DriftModel
from eit_skin.sim.faults import FAULT_KINDS, Fault, fault_help, parse_faults
from eit_skin.sim.scripts import builtin_scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Push

RATE = 10.0


@pytest.fixture(scope="module")
def arm():
    return load_patch(config_path("arm"))


@pytest.fixture(scope="module")
def demo(arm):
    sim = SkinSimulator(arm, "demo", rate_hz=RATE, seed=3, drift=NO_DRIFT)
    return sim, sim.run()


def test_local_update_matches_a_direct_solve(arm) -> None:
    sim = SkinSimulator(arm, "idle", rate_hz=RATE)
    model = sim.forward_model("pressure")
    c = sim.mesh("pressure").centroids
    base = np.full(len(c), arm.layer("pressure").material.sheet_conductance_s)
    update = LocalForwardUpdate(model, base)
    for x, amp in ((0.0, 2.0), (0.025, -0.5), (0.025, 0.7)):
        d = np.hypot(c[:, 0] - x, c[:, 1] - 0.01)
        sigma = base * (1 + amp * np.clip(1 - (d / 0.008) ** 2, 0, None))
        direct = model.voltages(sigma)
        fast = update.voltages(sigma)
        assert update.direct_solves == 0
        np.testing.assert_allclose(fast, direct, rtol=0, atol=1e-10 * np.abs(direct).max())
    np.testing.assert_allclose(update.voltages(base), model.voltages(base), rtol=1e-10)


def _change_rms(sim, rec, layer):
    dv = rec.layers[layer].frames - sim.reference(layer)[None]
    return np.sqrt(np.mean(dv**2, axis=1))


@pytest.mark.parametrize("layer", ["pressure", "stretch"])
def test_frames_change_exactly_while_a_touch_is_active(demo, layer: str) -> None:
    sim, rec = demo
    noise = sim.adc(layer).noise_v
    rms = _change_rms(sim, rec, layer)
    during = np.zeros(len(rec.t), dtype=bool)
    quiet = np.ones(len(rec.t), dtype=bool)
    for truth in rec.truth:
        mid = 0.5 * (truth.t_start_s + truth.t_end_s)
        during |= np.abs(rec.t - mid) < 0.2 * (truth.t_end_s - truth.t_start_s)
        quiet &= (rec.t <= truth.t_start_s) | (rec.t >= truth.t_end_s + truth.settle_s)
    assert during.sum() >= 8 and quiet.sum() >= 50
    # quantisation of the reference adds <= lsb/2000 per value: at noise level outside touches
    assert rms[quiet].max() < 1.6 * noise
    assert rms[quiet].mean() == pytest.approx(noise, rel=0.25)
    assert rms[during].min() > 20 * noise


def test_pressure_and_strain_move_the_voltages_the_way_the_jacobian_says(demo) -> None:
    sim, rec = demo
    push, rub = rec.truth[0], rec.truth[1]
    for layer, truth in (("pressure", push), ("stretch", rub)):
        k = int(np.argmin(np.abs(rec.t - 0.5 * (truth.t_start_s + truth.t_end_s))))
        base, sigma = sim.fields(layer, float(rec.t[k]))
        dsigma = sigma - base
        if layer == "pressure":
            assert (dsigma >= 0).all() and dsigma.max() > 0  # pressure raises conductance
        else:
            assert (dsigma <= 0).all() and dsigma.min() < 0  # stretch lowers it
        jac = sim.forward_model(layer).jacobian(base)
        predicted = jac @ dsigma
        measured = rec.layers[layer].frames[k] - sim.reference(layer)
        big = np.abs(predicted) > 0.2 * np.abs(predicted).max()
        assert big.sum() >= 5
        assert (np.sign(measured[big]) == np.sign(predicted[big])).all()
        assert np.corrcoef(measured, predicted)[0, 1] > 0.9


def test_truth_is_consistent_and_saved(demo, tmp_path: Path) -> None:
    _sim, rec = demo
    paths = rec.save(tmp_path)
    assert {p.name for p in paths} == {"pressure.npz", "stretch.npz", "truth.json"}
    ref, frames, _t = load_frames_npz(tmp_path / "pressure.npz", 208)
    np.testing.assert_array_equal(frames, rec.layers["pressure"].frames)
    pre = rec.t < rec.truth[0].t_start_s
    np.testing.assert_allclose(ref, rec.layers["pressure"].frames[pre].mean(axis=0))
    doc = json.loads((tmp_path / "truth.json").read_text())
    assert [d["label"] for d in doc["touches"]] == ["push", "rub", "pinch", "grab"]
    assert doc["layers"]["pressure"]["reference"].startswith("pre-touch mean")
    rub = doc["touches"][1]
    xs = [p[1] for p in rub["track"]]
    assert xs[-1] - xs[0] > 0.01  # the rub's centroid moves


def test_frames_are_reproducible_and_random_access(arm) -> None:
    a = SkinSimulator(arm, "push", rate_hz=RATE, seed=5)
    b = SkinSimulator(arm, "push", rate_hz=RATE, seed=5)
    c = SkinSimulator(arm, "push", rate_hz=RATE, seed=6)
    k = 15  # mid-push
    fb = b.frame(k)["pressure"]
    ra = a.run(n_frames=k + 1)
    np.testing.assert_array_equal(ra.layers["pressure"].frames[k], fb.voltages_v)
    assert fb.t_s == pytest.approx(k / RATE)
    assert not np.array_equal(c.frame(k)["pressure"].voltages_v, fb.voltages_v)


def test_adc_quantises_to_the_sum_step_and_flags_the_rails() -> None:
    ref = np.array([0.1, -0.05, 0.02])
    adc = AdcModel(AdcConfig(), ref)
    # auto gain: largest PGA gain with the largest value under 40 % of full scale
    assert 0.1 <= 0.4 * adc.full_scale_v < 0.2
    v, flags = adc.convert(np.array([0.0123456, -0.5 * adc.full_scale_v, 2.0, -2.0]), None)
    steps = v / adc.volts_per_count
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert abs(v[0] - 0.0123456) <= 0.5 * adc.volts_per_count + 1e-15
    assert flags.tolist() == [0, 0, FLAG_SATURATED, FLAG_SATURATED]
    assert v[2] == pytest.approx(adc.rail_v(True)) and v[3] == pytest.approx(adc.rail_v(False))
    noisy, _ = adc.convert(np.zeros(20000), np.random.default_rng(0))
    assert noisy.std() == pytest.approx(adc.noise_v, rel=0.05)
    assert adc.noise_v == pytest.approx(adc.lsb_v * np.sqrt((1 + 1 / 12) / 1000))


def test_dead_electrode_shows_up_in_exactly_the_measurements_touching_it(arm) -> None:
    good = SkinSimulator(arm, "idle", rate_hz=RATE, seed=2)
    bad = SkinSimulator(arm, "idle", rate_hz=RATE, seed=2, faults=["dead-electrode:5@pressure"])
    touching = good.protocol("pressure").touching([5])
    for k in (0, 7):
        g, b = good.frame(k), bad.frame(k)
        differs = g["pressure"].voltages_v != b["pressure"].voltages_v
        np.testing.assert_array_equal(differs, touching)
        np.testing.assert_array_equal(g["stretch"].voltages_v, b["stretch"].voltages_v)
        inj = good.protocol("pressure").injections[good.protocol("pressure").measurements[:, 0]]
        driven = (inj == 5).any(axis=1)
        assert (b["pressure"].flags[driven] == FLAG_SATURATED).all()
        assert not g["pressure"].flags.any()


def test_saturated_channel_fault_pins_one_channel(arm) -> None:
    sim = SkinSimulator(arm, "idle", rate_hz=RATE, faults=[Fault("saturated-channel", 17)])
    f = sim.frame(3)["stretch"]
    assert np.flatnonzero(f.flags).tolist() == [17]
    assert f.voltages_v[17] == pytest.approx(sim.adc("stretch").rail_v(True))
    with pytest.raises(ValueError, match="KIND:INDEX"):
        Fault.parse("dead-electrode")
    with pytest.raises(ValueError, match="only 16"):
        SkinSimulator(arm, "idle", faults=["dead-electrode:16"])


def test_fault_help_names_every_kind_and_its_examples_run(arm) -> None:
    text = fault_help(",")
    listed = parse_faults(text.rsplit(" ", 1)[-1])
    assert [f.kind for f in listed] == list(FAULT_KINDS)
    assert [str(f) for f in listed] == text.rsplit(" ", 1)[-1].split(",")
    sim = SkinSimulator(arm, "idle", rate_hz=RATE, faults=listed)
    assert sim.frame(0)["pressure"].flags.any()
    with pytest.raises(ValueError, match="saturated-channel"):
        parse_faults("saturated:17")  # the old help's spelling names the valid kinds


def test_drift_is_slow_smooth_and_follows_the_model(arm) -> None:
    drift = DriftModel(rate_per_min=0.005, wobble=0.0005, period_s=20.0, phase=0.3)
    sim = SkinSimulator(arm, "idle", rate_hz=5.0, seed=1, drift=drift)
    rec = sim.run(duration_s=10.0)
    ref = sim.reference("pressure")
    frames = rec.layers["pressure"].frames
    gain = frames @ ref / (ref @ ref)  # least-squares gain of each frame
    expected = 1.0 / (1.0 + np.array([drift.offset(t) for t in rec.t]))
    assert np.abs(gain - expected).max() < 2e-5
    # smooth: no frame-to-frame jumps beyond the noise of the gain (a 0.1 % step would fail)
    assert np.abs(np.diff(gain, 2)).max() < 1.5e-4
    assert abs(gain[-1] - gain[0]) > 5e-4  # but it does drift (~0.1 % in 10 s here)


def test_bent_elbow_changes_the_no_load_map_and_a_push_still_shows(tmp_path: Path) -> None:
    elbow = load_patch(config_path("elbow"))
    sim = SkinSimulator(elbow, "elbow_bend", rate_hz=2.0, seed=0, drift=NO_DRIFT)
    rec = sim.run()
    ref = sim.reference("pressure")
    frames = rec.layers["pressure"].frames
    bent = np.flatnonzero((rec.t >= 4.0) & (rec.t <= 5.0))
    push = rec.truth[0]
    pushing = np.flatnonzero(np.abs(rec.t - 0.5 * (push.t_start_s + push.t_end_s)) < 0.3)
    # the stretched knit conducts less: voltages rise across the crease
    assert np.mean(np.abs(frames[bent[0]])) > 1.2 * np.mean(np.abs(ref))
    dv = frames[pushing[0]] - frames[bent[-1]]
    assert np.sqrt(np.mean(dv**2)) > 20 * sim.adc("pressure").noise_v
    assert rec.layers["pressure"].reference_kind.startswith("pre-touch mean")


def test_simulate_command_writes_frames_and_truth(tmp_path: Path, capsys) -> None:
    rc = main(
        [
            "simulate",
            "--patch",
            "arm",
            "--scenario",
            "push",
            "--rate",
            "5",
            "--seed",
            "1",
            "--duration",
            "4",
            "--fault",
            "dead-electrode:3",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "push" in out and "wrote" in out
    _, frames, t = load_frames_npz(tmp_path / "stretch.npz", 208)
    assert frames.shape == (20, 208) and t[1] == pytest.approx(0.2)
    doc = json.loads((tmp_path / "truth.json").read_text())
    assert doc["faults"] == ["dead-electrode:3"] and doc["touches"][0]["label"] == "push"
    assert main(["simulate", "--scenario", "nope", "--out", str(tmp_path)]) == 1
    assert "unknown scenario" in capsys.readouterr().err


def test_scenario_object_and_positions(arm) -> None:
    scenario = builtin_scenario("push", arm)
    sim = SkinSimulator(arm, scenario, rate_hz=RATE)
    assert sim.scenario is scenario
    assert isinstance(scenario.touches[0], Push)
