"""Shape-change evidence from raw frames: its null distribution, its power, and its wiring."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import eit_skin.touch.start_gates as start_gates_module
from eit_skin.inverse.channel_noise import difference_noise
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.touch.classifier import TouchClassifier
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.frame_evidence import (
    FrameEvidence,
    TouchFilter,
    channel_electrodes,
    electrode_roughness,
    shape_change_z,
    whiteness,
)
from eit_skin.touch.shapes import fingertip_discs, raw_patterns
from eit_skin.touch.start_gates import ELECTRODE_FLICKER, WHITE
from test.support.synthetic_touches import INSIDE, X, Y, envelope, sequence

M = 208
RATE_HZ = 50.0
DATA = Path(__file__).resolve().parents[2] / "data" / "real"


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class Sheet:
    """Random whitened patterns of one simulated sheet: channel noise, reference, a push's
    pattern, its change per metre of centroid motion, and a closing pinch's extra pattern."""

    def __init__(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.rng = rng
        self.sigma = 1e-5 * (1.0 + rng.random(M))  # V, each channel its own
        self.reference = 0.01 + 0.05 * rng.random(M)  # V
        self.push = 400.0 * unit(rng.normal(size=M))  # noise units at full force
        self.per_m = 2e4 * rng.normal(size=(2, M))  # noise units per metre of motion
        self.closing = unit(rng.normal(size=M))

    def volts(self, x: np.ndarray) -> np.ndarray:
        """``[T, M]`` V of whitened changes ``x`` ``[T, M]`` plus unit noise."""
        noise = self.rng.normal(size=x.shape)
        return self.reference + self.sigma * (x + noise)

    def touch(self, n: int, closing: float = 0.0, move_m: float = 0.0, drift: float = 0.0):
        """``(x [n, M] whitened, t [n], xy [n, 2])`` of a touch held for ``n`` frames:
        amplitude 0.9..1 with a quadratic response, a centroid wandering by ``move_m``, a
        closing pattern growing linearly to ``closing`` noise units, a sheet-wide drift
        growing to ``drift`` times the reference."""
        t = np.arange(n) / RATE_HZ
        a = 0.9 + 0.1 * np.sin(np.linspace(0.0, 3.0, n)) ** 2
        xy = move_m * np.column_stack([np.sin(3 * t), np.cos(2 * t)])
        x = np.outer(a + 0.3 * a**2, self.push) + xy @ self.per_m
        x += np.outer(np.linspace(0.0, closing, n), self.closing)
        x += np.outer(np.linspace(0.0, drift, n), self.reference / self.sigma)
        return x, t, xy

    def calibrated(self, frames: int = 400) -> FrameEvidence:
        evidence = FrameEvidence()
        evidence.learn_noise(self.volts(np.zeros((frames, M))))
        return evidence


def z_of(sheet: Sheet, evidence: FrameEvidence, **touch) -> float:
    x, t, xy = sheet.touch(60, **touch)
    whitened = np.stack([evidence.whiten(v) for v in sheet.volts(x)])
    return shape_change_z(whitened, t, xy, evidence.drift_pattern())


@pytest.mark.parametrize(
    "nuisance", [{}, {"move_m": 1e-3}, {"drift": 2e-3}], ids=["still", "rolls", "drifts"]
)
def test_a_touch_that_keeps_its_shape_gives_a_standard_normal_z(nuisance) -> None:
    """Amplitude (with a quadratic response), centroid motion and sheet-wide drift are all
    explained: over 200 touches z has mean ~0 and standard deviation ~1."""
    sheet = Sheet(0)
    evidence = sheet.calibrated()
    z = np.array([z_of(sheet, evidence, **nuisance) for _ in range(200)])
    assert abs(z.mean()) < 0.3
    assert 0.75 < z.std() < 1.35


@pytest.mark.parametrize("closing", [4.0, 8.0])
def test_a_steady_closing_gives_the_z_of_its_noncentral_chi_square(closing) -> None:
    """A pattern growing linearly to ``c`` noise units over the hold adds a time coefficient
    ``slope * closing``; less its part along the drift pattern, its noncentrality is
    ``lambda = slope^2 |closing_perp|^2 / var_t`` (``var_t`` of the noise-free design), and
    E[z] = lambda / sqrt(2 (M - 1)). The mean over 40 touches is within 15 % of it."""
    sheet = Sheet(2)
    evidence = sheet.calibrated(2000)
    clean, t, _ = sheet.touch(60, closing=closing)
    a = clean @ unit(clean.mean(axis=0))
    design = np.column_stack([np.ones(t.size), a, a * a, t - t.mean()])
    var_t = np.linalg.inv(design.T @ design)[-1, -1]
    slope = closing / (t[-1] - t[0])
    d = unit(sheet.reference / sheet.sigma)
    perp = sheet.closing - d * (d @ sheet.closing)
    expected = slope**2 * float(perp @ perp) / var_t / math.sqrt(2 * (M - 1))
    z = np.array([z_of(sheet, evidence, closing=closing) for _ in range(40)])
    assert expected > 3
    assert z.mean() == pytest.approx(expected, rel=0.15)


def test_calibration_learns_each_channels_noise_not_its_drift() -> None:
    sheet = Sheet(3)
    ramp = np.outer(np.linspace(0.0, 30.0, 400), np.ones(M))  # 30 sigma of slow drift
    frames = sheet.volts(ramp)
    frames[:, 7] = np.nan  # a channel that never came
    evidence = FrameEvidence()
    evidence.learn_noise(frames)
    ok = np.arange(M) != 7
    np.testing.assert_allclose(evidence.sigma[ok], sheet.sigma[ok], rtol=0.3)
    assert np.median(np.abs(evidence.sigma[ok] / sheet.sigma[ok] - 1)) < 0.06
    assert not evidence.usable(())[7] and evidence.usable(())[ok].all()
    with pytest.raises(ValueError, match="channels"):
        evidence.whiten(np.zeros(M + 1))


def test_a_faulty_electrodes_channels_are_left_out() -> None:
    layer = load_patch(config_path("arm")).layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    table = channel_electrodes(protocol)
    assert table.shape == (protocol.n_measurements, protocol.n_electrodes)
    evidence = FrameEvidence(table)
    evidence.learn_noise(np.random.default_rng(0).normal(1.0, 1e-3, (10, protocol.n_measurements)))
    np.testing.assert_array_equal(evidence.usable((5,)), ~protocol.touching([5]))
    # adjacent drive: electrode 5 drives 2 of 16 injections and is measured in the rest
    assert np.count_nonzero(~evidence.usable((5,))) == 2 * 13 + 14 * 2 - 2


def test_electrode_roughness_names_one_rough_electrode_and_nothing_spread() -> None:
    """Noise and a change over every channel stay near 1; g times the noise on one electrode's
    channels gives about g**2 (the median over its channels of chi-square 1 ratios)."""
    protocol = build_protocol(load_patch(config_path("arm")).layers[0].protocol, 16)
    table = channel_electrodes(protocol)
    rng = np.random.default_rng(3)
    noise = [electrode_roughness(rng.normal(size=M) * np.sqrt(6.0), table) for _ in range(300)]
    assert np.percentile(noise, 99) < 5.0 and max(noise) < ELECTRODE_FLICKER
    broad = 50.0 * (1.0 + rng.random(M)) + rng.normal(size=M)  # a palm's onset, every channel
    assert electrode_roughness(broad, table) < 3.0
    for g in (5.0, 10.0):
        rough = [
            electrode_roughness(rng.normal(size=M) * np.where(table[:, 7], g, 1.0), table)
            for _ in range(50)
        ]
        assert 0.5 * g**2 < np.median(rough) < 2.0 * g**2
    assert min(rough) > ELECTRODE_FLICKER  # 10x: always named
    left_out = rng.normal(size=M) * np.where(table[:, 7], 10.0, 1.0)
    left_out[table[:, 7]] = np.nan  # that electrode's channels out (faulty): nothing left
    assert electrode_roughness(left_out, table) < 5.0
    assert math.isnan(electrode_roughness(np.full(M, np.nan), table))


def test_whiteness_tells_a_failing_electrodes_noise_from_a_press_onset_on_its_channels() -> None:
    """10x white noise on one electrode's channels: second over first difference energy
    about 3 (2.5 in the noise's second frame), at least :data:`WHITE` in most frames; those
    channels bending as a press's onset next to that electrode does (the corner of a ramp,
    an accelerating rise), as rough as the noise to :func:`electrode_roughness`: about 1
    and 0.4, always under it."""
    protocol = build_protocol(load_patch(config_path("arm")).layers[0].protocol, 16)
    table = channel_electrodes(protocol)
    rng = np.random.default_rng(4)
    own = table[:, 7]

    def white(extra):  # three whitened frames [3, M]: unit noise plus ``extra``
        w = rng.normal(size=(3, M)) + extra
        return whiteness(w[2] - 2.0 * w[1] + w[0], w[2] - w[1], table)

    def fault(frames):  # 10x noise on electrode 7's channels in the last ``frames`` frames
        return 10.0 * rng.normal(size=(3, M)) * own * (np.arange(3) >= 3 - frames)[:, None]

    noisy = np.array([white(fault(3)) for _ in range(200)])
    started = np.array([white(fault(2)) for _ in range(200)])
    assert 2.5 < np.median(noisy) < 3.5 and np.mean(noisy >= WHITE) > 0.8
    assert 2.0 < np.median(started) < 3.0 and np.mean(started >= WHITE) > 0.7
    corner = 30.0 * np.array([0.0, 0.0, 1.0])[:, None] * own
    rising = 30.0 * np.array([0.0, 1.0, 4.0])[:, None] * own
    for onset in (corner, rising):
        bend = onset[2] - 2.0 * onset[1] + onset[0] + np.sqrt(6.0) * rng.normal(size=M)
        assert electrode_roughness(bend, table) > ELECTRODE_FLICKER
        assert max(white(onset) for _ in range(200)) < 1.5
    assert math.isnan(whiteness(np.full(M, np.nan), np.zeros(M), table))


def test_electrode_roughness_stays_low_on_a_real_devices_frames() -> None:
    """Sciospec EIT32 (data/real/README.md): its 20 object-free frames, whose noise is
    correlated in time and across channels, and a target moving through a saline tank stay
    well under ELECTRODE_FLICKER (measured 1.5-3.8 and at most 5.7)."""
    data = np.load(DATA / "sciospec_adjacent.npz")
    layer = load_patch(DATA / "sciospec_adjacent.yaml").layers[0]
    table = channel_electrodes(build_protocol(layer.protocol, layer.n_electrodes))
    sigma = difference_noise(data["reference_frames"].astype(float))
    for frames in (data["reference_frames"], data["frames"][:60]):
        w = frames.astype(float) / sigma
        bends = w[2:] - 2.0 * w[1:-1] + w[:-2]
        rough = [electrode_roughness(b, table) for b in bends]
        assert max(rough) < 0.7 * ELECTRODE_FLICKER, rough


def test_a_still_touch_on_a_real_devices_noise_is_no_shape_change() -> None:
    """Sciospec EIT32: its 20 object-free frames (noise correlated in time and across
    channels, data/real/README.md) plus the patch model's pattern of a still disc at 40
    places stay well under the pinch bar (measured at most 2.4; the channel noise and
    reference are learnt from the same 20 frames, the only object-free ones there are)."""
    data = np.load(DATA / "sciospec_adjacent.npz")
    frames = data["reference_frames"].astype(float)
    layer = load_patch(DATA / "sciospec_adjacent.yaml").layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    jacobian = imager.matrix.jacobian
    if imager.signs is not None:  # a magnitude device: the frames carry the model's signs
        jacobian = jacobian * imager.signs[:, None]
    evidence = FrameEvidence()
    evidence.learn_noise(frames)
    radius = float(np.linalg.norm(layer.outline, axis=1).max())
    places = np.random.default_rng(5).uniform(-0.6 * radius, 0.6 * radius, size=(40, 2))
    patterns = fingertip_discs(places, imager.mesh, 0.1 * radius) @ jacobian.T  # [40, M] V
    t = np.arange(len(frames)) / RATE_HZ
    still = np.zeros((len(frames), 2))
    z = []
    for pattern in patterns:
        pattern = pattern * 30.0 / np.sqrt(np.mean((pattern / evidence.sigma) ** 2))
        whitened = (frames + pattern - evidence.reference) / evidence.sigma
        z.append(shape_change_z(whitened, t, still, evidence.drift_pattern()))
    assert np.all(np.isfinite(z))
    assert max(z) < 0.7 * ClassifierConfig().pinch_shape_z, z


# ---------------------------------------------------------------- in the classifier
ONSET_S, RELEASE_S = 1.0, 2.4
CHANNEL_ELECTRODES = np.zeros((M, 16), dtype=bool)
CHANNEL_ELECTRODES[np.arange(M), np.arange(M) % 16] = True
ELECTRODES_M = 0.04 * np.column_stack(
    [np.cos(np.arange(16) * np.pi / 8), np.sin(np.arange(16) * np.pi / 8)]
)


def _scene(closing_channels: np.ndarray | None, seed: int = 0):
    """A still push in the images; its raw frames close like a pinch on ``closing_channels``
    (noise units growing to 40 over the hold), or keep their shape (None)."""
    t, images = sequence(
        lambda t: ([(0.01, -0.005)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)), 3.0, seed=seed
    )
    sheet = Sheet(seed)
    a = np.array([envelope(tk, ONSET_S, RELEASE_S) for tk in t])
    x = np.outer(a, sheet.push)
    if closing_channels is not None:
        grow = np.clip((t - ONSET_S - 0.1) / (RELEASE_S - ONSET_S - 0.2), 0, 1) * (a > 0)
        pattern = np.where(closing_channels, sheet.closing, 0.0)
        x += np.outer(grow * 40.0, unit(pattern))
    return t, images, sheet.volts(x)


def _ends(t, images, volts, faulty=()):
    clf = TouchClassifier(X, Y, electrodes_m=ELECTRODES_M, channel_electrodes=CHANNEL_ELECTRODES)
    clf.set_faulty_electrodes(faulty)
    events = []
    for k in range(len(t)):
        events += clf.step(float(t[k]), images[k], None, None if volts is None else volts[k])
    events += clf.finish()
    return [e for e in events if e.state == "end"], clf


@pytest.mark.parametrize("seed", [0, 1])
def test_a_still_blob_whose_frames_close_is_a_pinch_and_its_frames_decide(seed) -> None:
    everywhere = np.ones(M, dtype=bool)
    t, images, volts = _scene(everywhere, seed)
    ends, clf = _ends(t, images, volts)
    assert [e.label for e in ends] == ["pinch"]
    assert clf.last_features.shape_z > ClassifierConfig().pinch_shape_z
    # the images alone (no raw frames) say push; so do frames that keep their shape
    assert [e.label for e in _ends(t, images, None)[0]] == ["push"]
    t, images, volts = _scene(None, seed)
    ends, clf = _ends(t, images, volts)
    assert [e.label for e in ends] == ["push"]
    assert abs(clf.last_features.shape_z) < 4


def test_a_closing_seen_only_on_a_faulty_electrodes_channels_is_no_pinch() -> None:
    electrode = 3
    t, images, volts = _scene(CHANNEL_ELECTRODES[:, electrode])
    assert [e.label for e in _ends(t, images, volts)[0]] == ["pinch"]
    ends, clf = _ends(t, images, volts, faulty=(electrode,))
    assert [e.label for e in ends] == ["push"]
    assert abs(clf.last_features.shape_z) < 4


def test_pinch_shape_z_is_a_validated_switch() -> None:
    with pytest.raises(ValueError, match="pinch_shape_z"):
        ClassifierConfig(pinch_shape_z=-1.0)
    t, images, volts = _scene(np.ones(M, dtype=bool))
    clf = TouchClassifier(X, Y, ClassifierConfig(pinch_shape_z=0.0))
    events = [e for k in range(len(t)) for e in clf.step(t[k], images[k], None, volts[k])]
    assert [e.label for e in events + clf.finish() if e.state == "end"] == ["push"]
    assert np.isnan(clf.last_features.shape_z)


# ---------------------------------------------------------------- the raw frames' START filter
def _sciospec_filter(contacts: bool):
    """The START filter of the sciospec tank's patch (a real device, data/real/), its 20
    object-free frames' reference and noise, and the patterns it was built from."""
    data = np.load(DATA / "sciospec_adjacent.npz")
    frames = data["reference_frames"].astype(float)
    layer = load_patch(DATA / "sciospec_adjacent.yaml").layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    disc, contact = raw_patterns(layer, imager, 0.1 * float(np.abs(layer.outline).max()))
    evidence = FrameEvidence()
    evidence.learn_noise(frames)
    inside = np.asarray(imager.grid.inside, dtype=bool)
    start = TouchFilter(disc, inside, contact if contacts else None)
    return start, evidence, frames, disc, contact, inside


def test_the_start_filter_reads_white_noise_as_unit_normal_and_drift_as_nothing() -> None:
    start, evidence, _, disc, _, inside = _sciospec_filter(contacts=True)
    rng = np.random.default_rng(3)
    white = rng.standard_normal((400, evidence.reference.size))
    z = start.statistic(white, evidence.sigma, evidence.reference)[:, inside]
    spread = np.std(z, axis=0)  # per pixel, from 400 frames: standard error 0.035
    assert np.mean(spread) == pytest.approx(1.0, abs=0.01)
    assert np.all(np.abs(spread - 1.0) < 0.2)
    # a sheet-wide change of the conductivity (every channel by the same fraction)
    drift = 0.01 * evidence.reference / evidence.sigma
    assert np.nanmax(np.abs(start.statistic(drift, evidence.sigma, evidence.reference))) < 1e-6 * (
        np.linalg.norm(drift)
    )
    # a fingertip at a pixel reads highest at that pixel (or next to it)
    rows, cols = np.nonzero(inside)
    for i in rng.choice(len(rows), 5, replace=False):
        r, c = rows[i], cols[i]
        change = disc[r, c] * np.abs(evidence.reference) / evidence.sigma
        peak = np.unravel_index(
            np.nanargmax(start.statistic(change, evidence.sigma, evidence.reference)), inside.shape
        )
        assert abs(peak[0] - r) <= 1 and abs(peak[1] - c) <= 1


def test_an_electrode_contact_change_on_a_real_device_starts_nothing() -> None:
    """Sciospec EIT32's object-free frames (noise correlated in time and across channels),
    one electrode's contact impedance changing by as much as 30 noise sigmas along its
    pattern: with the contact patterns projected out the filter stays under the START bar;
    without them the same change reads as a touch at the boundary."""
    for contacts in (True, False):
        start, evidence, frames, _, contact, inside = _sciospec_filter(contacts)
        white = (frames - evidence.reference) / evidence.sigma
        # each pixel's statistic in units of its RMS over the object-free frames
        rms = np.sqrt(
            np.mean(
                start.statistic(white, evidence.sigma, evidence.reference)[:, inside] ** 2, axis=0
            )
        )
        worst = 0.0
        for electrode in range(contact.shape[1]):
            pattern = contact[:, electrode] * np.abs(evidence.reference) / evidence.sigma
            step = 30.0 * pattern / np.sqrt(np.mean(pattern**2))
            z = start.statistic(white + step, evidence.sigma, evidence.reference)[:, inside]
            worst = max(worst, float(np.max(z / rms)))
        if contacts:
            assert worst < ClassifierConfig().k_detect, worst
        else:
            assert worst > 2 * ClassifierConfig().k_detect, worst


def _noisy_electrode_events(monkeypatch=None) -> list:
    """No touch; from 1 s the channels of electrode 3 get 10x their noise (a degrading
    electrode before the pipeline names it). Images of noise only; the START filter built
    from arbitrary fingertip patterns (every one of them sees those channels)."""
    if monkeypatch is not None:  # the raw frames' electrode test off
        monkeypatch.setattr(start_gates_module, "ELECTRODE_FLICKER", np.inf)
    t, images = sequence(lambda t: ([], 0.0), 3.0, seed=2)
    rng = np.random.default_rng(4)
    disc = rng.standard_normal((*images.shape[1:], M)).astype(np.float32)
    disc[~INSIDE] = np.nan
    clf = TouchClassifier(X, Y, channel_electrodes=CHANNEL_ELECTRODES, disc_rel=disc)
    noisy = CHANNEL_ELECTRODES[:, 3]
    events = []
    for tk, image in zip(t, images, strict=True):
        volts = 1.0 + 1e-3 * rng.standard_normal(M) * np.where(noisy & (tk >= 1.0), 10.0, 1.0)
        events += clf.step(float(tk), image, None, volts)
    assert clf.start_detector is not None  # the filter was in use
    return events + clf.finish()


def test_an_electrodes_noise_starts_nothing_from_the_raw_frames_filter(monkeypatch) -> None:
    assert _noisy_electrode_events() == []
    # it is the raw frames' electrode test that holds it: without it the noise STARTs
    assert [e for e in _noisy_electrode_events(monkeypatch) if e.state == "start"]
