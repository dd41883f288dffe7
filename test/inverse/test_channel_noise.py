"""Reference check, measured channel noise and channel weighting (inverse/channel_noise.py,
ReconstructionMatrix.with_channel_scale, LayerImager.use_reference), online and offline."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.inverse.channel_noise import (
    MAX_BAD_FRACTION,
    UnusableReferenceError,
    channel_scale,
    check_reference,
    estimate_channel_noise,
    reciprocal_partners,
)
from eit_skin.inverse.dual_form import lambda_squared
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from test.support.pressed_disc import PRESS_M, pressed_disc

SOLVER = (
    "{method: one_step, prior: laplace, noise_figure: 0.3, image_pixels: 16, reference_frames: 20, "
    "channel_weights: measured}"
)
PROTOCOL = build_protocol(ProtocolSpec(), 16)
PRESS = np.array(PRESS_M)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """(patch path, imager, no-load [M] V, pressed [M] V) of a 16-electrode disc."""
    disc = pressed_disc(tmp_path_factory.mktemp("small"), SOLVER, factor=0.5)
    return disc.path, disc.imager, disc.unloaded_v, disc.pressed_v


# --- noise estimates against a known simulated noise ------------------------------------------


def test_noise_from_repeated_frames_and_from_frame_differences():
    rng = np.random.default_rng(0)
    ref = np.linspace(1.0, 3.0, PROTOCOL.n_measurements)
    sigma = 1e-3 * (1.0 + 9.0 * (np.arange(ref.size) % 2))  # heteroscedastic, known
    repeated = ref + rng.normal(0.0, 1.0, (400, ref.size)) * sigma
    noise = estimate_channel_noise(ref, PROTOCOL, reference_frames=repeated)
    assert "400 repeated" in noise.source
    np.testing.assert_allclose(noise.sigma_v, sigma, rtol=0.2)
    # a recording with a step (an object put in) in 5 % of its steps: the median ignores it
    frames = ref + rng.normal(0.0, 1.0, (400, ref.size)) * sigma
    frames[200:] += 0.5 * ref
    noise = estimate_channel_noise(ref, PROTOCOL, frames=frames)
    assert "consecutive" in noise.source
    np.testing.assert_allclose(noise.sigma_v, sigma, rtol=0.25)
    np.testing.assert_allclose(noise.relative(ref), sigma / ref, rtol=0.25)


def test_noise_from_reciprocity_of_a_single_reference():
    partner, sign = reciprocal_partners(PROTOCOL)
    assert (partner >= 0).all() and (partner[partner] == np.arange(partner.size)).all()
    spec = ProtocolSpec(sign=-1)  # swapped pairs: still each other's partners, same sign
    assert (reciprocal_partners(build_protocol(spec, 16))[0] == partner).all()
    # a reference that obeys reciprocity, then independent noise of sd 0.01 per channel
    rng = np.random.default_rng(1)
    clean = rng.uniform(1.0, 2.0, partner.size)
    clean = np.where(np.arange(partner.size) < partner, clean, sign * clean[partner])
    sd = 0.01
    noise = estimate_channel_noise(clean + rng.normal(0.0, sd, clean.size), PROTOCOL)
    assert "reciprocity" in noise.source
    assert np.sqrt(np.mean(noise.sigma_v**2)) == pytest.approx(sd, rel=0.15)
    assert estimate_channel_noise(clean, build_protocol(ProtocolSpec(drive="opposite"), 16)) is None


def test_channel_scale_is_scale_free_and_trusts_no_channel_above_the_median():
    sigma = np.array([0.5, 1.0, 1.0, 2.0, 8.0, np.nan])
    scale = channel_scale(sigma)
    np.testing.assert_allclose(scale, [1.0, 1.0, 1.0, 2.0, 8.0, 1.0])
    np.testing.assert_allclose(channel_scale(1e-6 * sigma), scale)


# --- weighting: closed form and a known heteroscedastic case -----------------------------------


def test_weighted_matrix_is_weighted_least_squares(small):
    _, imager, _, _ = small
    rm = imager.matrix
    scale = 1.0 + np.arange(rm.n_channels) % 3
    weighted = rm.with_channel_scale(scale, h=0.1)
    k, y = rm.with_hyperparameter(0.1).gram
    sigma = np.diag(scale**2)
    whitened_trace = np.trace(k / np.outer(scale, scale))
    lam2 = lambda_squared(0.1, whitened_trace, rm.n_channels)
    expected = y @ np.linalg.inv(k + lam2 * sigma)
    np.testing.assert_allclose(
        weighted.matrix, expected, rtol=1e-8, atol=1e-10 * abs(expected).max()
    )
    assert rm.with_channel_scale(np.ones(rm.n_channels), 0.1).matrix == pytest.approx(
        rm.with_hyperparameter(0.1).matrix
    )
    with pytest.raises(ValueError, match="channel scale"):
        rm.with_channel_scale(np.zeros(rm.n_channels))


def test_weighting_by_measured_noise_images_a_heteroscedastic_recording_better(small):
    """The channels of electrode 0 (a poor contact) are 30x noisier; weighting by the measured
    noise puts the press closer to the truth than equal weights (same noise figure, frames)."""
    _, imager, v0, v1 = small
    noisy_channel = imager.protocol.touching([0])
    sd = 3e-3 * np.sqrt(np.mean(v0**2)) * np.where(noisy_channel, 30.0, 1.0)
    rng = np.random.default_rng(2)
    no_load = v0 + rng.normal(0.0, 1.0, (30, v0.size)) * sd
    pressed = v1 + rng.normal(0.0, 1.0, (40, v0.size)) * sd
    reference = no_load.mean(axis=0)
    unweighted = imager.matrix
    report = imager.use_reference(reference, no_load)
    assert report.chosen and "30 repeated" in report.noise_source
    scale = imager.matrix.channel_scale
    assert np.median(scale[noisy_channel]) > 20.0 and np.median(scale[~noisy_channel]) < 1.5
    weighted = imager.matrix

    def error(rm: ReconstructionMatrix) -> float:
        x = rm.reconstruct(pressed, reference)  # [T, N]
        peak = imager.mesh.centroids[np.argmin(x, axis=1)]  # the press lowers conductance
        return float(np.median(np.linalg.norm(peak - PRESS, axis=1)))

    assert error(weighted) < 0.5 * error(unweighted)
    assert error(weighted) < 0.008


def test_equal_channel_weights_are_the_measured_rule_fed_a_flat_noise(small):
    """``solver.channel_weights: equal`` (any measured noise) gives the matrix and ``h`` that
    the measured rule gives when every channel's relative noise is the same; the model-error
    rule acts on both alike."""
    _, imager, v0, _ = small
    built = {
        w: LayerImager.build(
            replace(imager.layer, solver=replace(imager.layer.solver, channel_weights=w)),
            cache_dir=None,
        )
        for w in ("measured", "equal")
    }
    rng = np.random.default_rng(3)
    reference = v0 * (1.0 + 0.05 * rng.normal(size=v0.size))  # a misfit to the model
    flat = reference * (1.0 + 1e-3 * rng.normal(size=(30, 1)))  # same relative noise
    uneven = reference + rng.normal(size=(30, v0.size)) * 1e-3 * abs(reference).max()
    equal = built["equal"].use_reference(reference, uneven)
    assert equal.for_model_error and equal.weighted == 0
    assert "channels weighted equally" in "\n".join(equal.lines())
    equal_matrix = built["equal"].matrix.matrix
    measured = built["measured"].use_reference(reference, flat)
    assert measured.hyperparameter == pytest.approx(equal.hyperparameter, rel=1e-9)
    np.testing.assert_allclose(built["measured"].matrix.matrix, equal_matrix, rtol=1e-7)
    # the same uneven noise, measured: other weights, another matrix
    assert built["measured"].use_reference(reference, uneven).weighted > 0
    assert not np.allclose(built["measured"].matrix.matrix, equal_matrix, rtol=1e-3)


# --- bad references: online (LayerProcessor) ---------------------------------------------------


def bad_reference(v0: np.ndarray, case: str) -> np.ndarray:
    ref = v0.copy()
    if case == "zero":
        ref[17] = 0.0
    elif case == "nan":
        ref[17] = np.nan
    elif case == "inf":
        ref[17] = np.inf
    elif case == "sign":
        ref[17] = -ref[17]
    elif case == "all_zero":
        ref[:] = 0.0
    elif case == "most_bad":
        ref[: int(MAX_BAD_FRACTION * ref.size) + 1] = np.nan
    return ref


CHANNEL_17 = "channel 17 (injection 1: 1->2, measure 7-8)"


@pytest.mark.parametrize("case", ["zero", "nan", "inf", "sign"])
def test_bad_reference_channel_is_excluded_and_named_online(small, case):
    _, imager, v0, v1 = small
    assert PROTOCOL.measurements[17].tolist() == [1, 7, 8]
    processor = LayerProcessor(imager, reference_frames=20)
    rng = np.random.default_rng(3)
    no_load = v0 + rng.normal(0.0, 1e-5 * np.abs(v0).mean(), (20, v0.size))
    processor.set_reference(bad_reference(v0, case), 0.0, no_load)
    report = processor.reference_report
    assert processor.reference_error is None
    assert np.flatnonzero(report.check.excluded).tolist() == [17]
    assert report.check.problems[0].startswith(CHANNEL_17)
    out = processor.step(v1, 0.02)
    clean = LayerProcessor(imager, reference_frames=20)
    clean.set_reference(v0, 0.0, no_load)
    expected = clean.step(v1, 0.02)
    assert out.channels_used == v0.size - 1 and np.isfinite(out.values).all()
    # one channel fewer moves the image a little, never by orders of magnitude
    ratio = np.abs(out.values).max() / np.abs(expected.values).max()
    assert 0.5 < ratio < 2.0


@pytest.mark.parametrize("case", ["all_zero", "most_bad"])
def test_unusable_reference_stops_imaging_online(small, case):
    _, imager, v0, v1 = small
    processor = LayerProcessor(imager, reference_frames=2)
    for k in range(2):
        processor.step(bad_reference(v0, case), 0.02 * k)
    assert processor.reference_ready and processor.reference_error is not None
    assert "reference" in processor.reference_error
    assert processor.step(v1, 0.1) is None and processor.frames_imaged == 0
    processor.rezero()
    assert processor.reference_error is None


def test_check_reference_rules_without_a_pipeline():
    ref = np.linspace(1.0, 2.0, PROTOCOL.n_measurements)
    assert not check_reference(ref, PROTOCOL).excluded.any()
    near = ref.copy()
    near[3] = 1e-4  # far below 1 % of the rms
    check = check_reference(near, PROTOCOL)
    assert np.flatnonzero(check.excluded).tolist() == [3] and "near zero" in check.problems[0]
    # scale-free: the same in microvolts
    assert (check_reference(1e-6 * near, PROTOCOL).excluded == check.excluded).all()
    with pytest.raises(UnusableReferenceError, match="all 208 channels"):
        check_reference(np.zeros_like(ref), PROTOCOL)
    with pytest.raises(UnusableReferenceError, match="wrong sign"):
        check_reference(-ref, PROTOCOL, model_voltages=ref)


# --- bad references: offline (eit-skin reconstruct) --------------------------------------------


@pytest.mark.parametrize("case", ["zero", "nan", "inf", "sign", "all_zero", "most_bad"])
def test_bad_reference_offline(small, tmp_path, capsys, case):
    path, _, v0, v1 = small
    frames_file = tmp_path / "in.npz"
    rng = np.random.default_rng(4)
    frames = np.vstack([v0 + rng.normal(0.0, 1e-5 * np.abs(v0).mean(), (20, v0.size)), v1])
    np.savez(frames_file, reference=bad_reference(v0, case), frames=frames)
    out = tmp_path / "out.npz"
    argv = ["reconstruct", "--patch", str(path), "--frames", str(frames_file), "--out", str(out)]
    code = main(argv)
    captured = capsys.readouterr()
    if case in ("all_zero", "most_bad"):
        assert code == 1 and not out.exists()
        assert f"{frames_file}: reference:" in captured.err
        assert [p.name for p in tmp_path.iterdir()] == ["in.npz"]
    else:
        assert code == 0, captured.err
        assert CHANNEL_17 in captured.out
        with np.load(out) as d:
            assert (
                d["imaged"].all() and np.isfinite(d["images"][-1][~np.isnan(d["images"][0])]).all()
            )


def test_tune_shows_what_was_measured_and_chosen(small, tmp_path, capsys):
    path, _, v0, _ = small
    rng = np.random.default_rng(5)
    frames_file = tmp_path / "in.npz"
    repeated = v0 + rng.normal(0.0, 1e-4 * np.abs(v0).mean(), (8, v0.size))
    reference = bad_reference(v0, "zero")
    np.savez(frames_file, reference=reference, frames=repeated, reference_frames=repeated)
    assert main(["tune", "--patch", str(path), "--frames", str(frames_file)]) == 0
    out = capsys.readouterr().out
    assert f"{frames_file}: reference: 1 of 208 channels excluded ({CHANNEL_17}" in out
    assert "8 repeated reference frames" in out and "chosen for the measured noise" in out
