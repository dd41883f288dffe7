"""Physics prior of the press localiser (issue 37): simulated presses on the device's model."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from eit_skin.calibration.features import split_features
from eit_skin.calibration.kernel_ridge import COMPONENT_COUNTS, KernelRidge
from eit_skin.calibration.localiser import CalibrationError, PressLocaliser
from eit_skin.calibration.physics_prior import PhysicsPrior, PriorPosition
from eit_skin.calibration.session import PressSessionError, pair_probe_csv
from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.sim.press_session import calibrated_to_device, simulate_press_session

REPO = Path(__file__).resolve().parents[2]
HYDROGEL_PATCH = REPO / "data" / "real" / "hydrogel_ohmc16.yaml"
N_PRESSES = 280
TEST = np.arange(200, N_PRESSES)


@pytest.fixture(scope="module")
def patch():
    return load_patch(HYDROGEL_PATCH)


@pytest.fixture(scope="module")
def session(patch):
    """Simulated presses: up to 200 for training, the last 80 held out."""
    return simulate_press_session(patch, N_PRESSES, seed=31)


@pytest.fixture(scope="module")
def prior(patch, session):
    """The prior as `calibrate --physics-prior` builds it: model fitted to the session's frame."""
    device, _ = calibrated_to_device(patch, patch.layers[0].name, session.reference)
    return PhysicsPrior.fit(simulate_press_session(device, 200, seed=32))


def with_board_gain(patch, gain: float):
    """``patch`` read by a board whose minus input has ``gain`` times its plus input's."""
    layer = patch.layers[0]
    options = dict(layer.device.options) | {"negative_input_gain": gain}
    board = replace(layer, device=replace(layer.device, options=tuple(options.items())))
    return replace(patch, layers=(board,))


def test_a_board_with_unequal_inputs_is_calibrated_into_the_prior(patch):
    """The thinning gel read by a board with unequal inputs (g = 1.15, the hydrogel board's
    fit) that the patch does not know: the prior's device fit takes g from the unloaded
    frame. With 25 presses the localiser (with the prior: 2.0 mm; leave-one-out keeps the
    response map here, the prior with the inverse kernel ridge gives 2.3 mm) is at least
    twice as good as the inverse kernel ridge alone (6.6 mm)."""
    layer = patch.layers[0]
    session = simulate_press_session(with_board_gain(patch, 1.15), 25 + 80, seed=33)
    device, fit = calibrated_to_device(patch, layer.name, session.reference)
    assert fit.negative_input_gain == pytest.approx(1.15, rel=0.01)
    assert device.layers[0].device.negative_input_gain == fit.negative_input_gain
    assert device.layers[0].material.response == "thinning"  # the hydrogel patch's own
    prior = PhysicsPrior.fit(simulate_press_session(device, 200, seed=34))
    few, test = session.subset(np.arange(25)), session.subset(np.arange(25, 105))

    def error(model: PressLocaliser) -> float:
        located = model.locate(test.frames, test.reference, test.references)
        return float(np.median(np.linalg.norm(located.xy - test.press_xy, axis=1)))

    with_prior = PressLocaliser.fit(few, layer, prior=prior)
    without = PressLocaliser.fit(few, layer)
    train, held_out = (
        split_features(without.responses(s.frames, s.references))[0] for s in (few, test)
    )
    inverse = KernelRidge.fit(train, few.press_xy, components=COMPONENT_COUNTS).predict(held_out)[0]
    inverse_error = np.median(np.linalg.norm(inverse - test.press_xy, axis=1))
    assert error(with_prior) <= error(without) < 0.5 * inverse_error


def held_out_error(model: PressLocaliser, session) -> float:
    test = session.subset(TEST)
    located = model.locate(test.frames, test.reference, test.references)
    return float(np.median(np.linalg.norm(located.xy - test.press_xy, axis=1)))


def test_prior_helps_few_presses_and_does_not_hurt_many(patch, session, prior):
    layer = patch.layers[0]
    few = session.subset(np.arange(25))
    plain = held_out_error(PressLocaliser.fit(few, layer), session)
    with_prior = PressLocaliser.fit(few, layer, prior=prior)
    assert isinstance(with_prior.position, PriorPosition)  # leave-one-out kept it
    assert held_out_error(with_prior, session) < 0.5 * plain
    many = session.subset(np.arange(200))
    plain = held_out_error(PressLocaliser.fit(many, layer), session)
    assert held_out_error(PressLocaliser.fit(many, layer, prior=prior), session) <= 1.1 * plain


def test_a_wrong_prior_is_switched_off_or_harmless(patch, session, prior):
    """A prior trained on shuffled positions knows nothing; a mirrored one is a wrong map."""
    layer = patch.layers[0]
    inputs, xy = prior.model.inputs, prior.model.predict(prior.model.inputs)[0]
    shuffled = np.random.default_rng(0).permutation(len(xy))
    for wrong_xy, kept in ((xy[shuffled], False), (xy * [-1.0, 1.0], True)):
        wrong = PhysicsPrior(prior.scale, KernelRidge.fit(inputs, wrong_xy), prior.n_presses)
        for n in (25, 200):
            train = session.subset(np.arange(n))
            model = PressLocaliser.fit(train, layer, prior=wrong)
            plain = held_out_error(PressLocaliser.fit(train, layer), session)
            if not kept and n == 200:  # nothing to learn from it: the plain localiser
                assert isinstance(model.position, KernelRidge)
                assert held_out_error(model, session) == plain
            elif not kept:  # few presses: leave-one-out may keep it by chance, at little cost
                assert held_out_error(model, session) < 1.25 * plain
            else:  # the features mode learns the mirror from the real presses
                assert model.position.mode == "features"
                assert held_out_error(model, session) < plain


def test_calibration_with_prior_round_trips_and_old_readers_refuse_it(
    tmp_path, patch, session, prior
):
    layer = patch.layers[0]
    model = PressLocaliser.fit(
        session.subset(np.arange(25)), layer, prior=prior, prior_modes=("features",)
    )
    assert isinstance(model.position, PriorPosition) and model.position.mode == "features"
    path = tmp_path / "m.npz"
    model.save(path)
    loaded = PressLocaliser.load(path, layer)
    test = session.subset(TEST)
    a = model.locate(test.frames, test.reference, test.references)
    b = loaded.locate(test.frames, test.reference, test.references)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.confidence, b.confidence)
    with np.load(path) as data:
        arrays = dict(data)
    assert int(arrays["format_version"]) == 2  # a version-1 reader refuses it, never misreads
    plain = tmp_path / "plain.npz"
    PressLocaliser.fit(session.subset(np.arange(25)), layer).save(plain)
    with np.load(plain) as data:  # files without a prior keep the old layout, key for key
        assert int(data["format_version"]) == 1
        assert not [k for k in data.files if "prior" in k]
    np.savez(tmp_path / "bad.npz", **{**arrays, "position_prior_mode": np.str_("guess")})
    with pytest.raises(CalibrationError, match=r"bad.npz: key 'position_prior_mode': 'guess'"):
        PressLocaliser.load(tmp_path / "bad.npz", layer)
    del arrays["position_prior_scale"]
    np.savez(tmp_path / "short.npz", **arrays)
    with pytest.raises(CalibrationError, match=r"short.npz: missing key 'position_prior_scale'"):
        PressLocaliser.load(tmp_path / "short.npz", layer)


def test_calibrate_command_with_physics_prior(tmp_path, capsys, session):
    presses, model = tmp_path / "p.npz", tmp_path / "m.npz"
    session.subset(np.arange(30)).save(presses)
    argv = ["calibrate", "--patch", str(HYDROGEL_PATCH), "--presses", str(presses)]
    assert main([*argv, "--out", str(model)]) == 0  # on by default (press_calibration.md)
    out = capsys.readouterr().out
    assert "physics prior: 500 presses simulated" in out and "kept: " in out
    assert "negative input gain 1)" in out  # the simulated board's inputs are matched
    assert isinstance(PressLocaliser.load(model).position, PriorPosition)
    assert main([*argv, "--physics-prior", "-1", "--out", str(tmp_path / "no.npz")]) == 2
    assert "--physics-prior: -1 presses" in capsys.readouterr().err
    assert not (tmp_path / "no.npz").exists()


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (["0.5,0.01,,0.003"], r"row 2 column 3: empty \(a gap"),
        (["0.5,0.01,0.02", "0.5,0.0,0.0"], r"row 3: time 0.5 s is not after the row above"),
        (["0.5,0.01,0.02,0.003", "1.5,0.0,0.0"], r"row 3: 3 columns.*like the rows above \(4\)"),
    ],
)
def test_probe_logs_with_gaps_are_refused_naming_the_row(tmp_path, session, rows, message):
    probe = tmp_path / "probe.csv"
    probe.write_text("time,x,y,depth\n" + "\n".join(rows) + "\n")
    t = np.arange(4) * 0.5
    with pytest.raises(PressSessionError, match=message):
        pair_probe_csv(session.reference, session.frames[:4], t, probe)
