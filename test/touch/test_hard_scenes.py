"""Hard scenes for the touch classifier: drift during touches, back-to-back touches, faults."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from eit_skin.resources import config_path
from eit_skin.sim.drift import NO_DRIFT
from eit_skin.sim.random_scenes import HARD_SCENES, hard_scenario
from eit_skin.sim.scenario import Scenario, SheetFrame
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Push
from eit_skin.touch.classifier import TouchClassifier, classify_stream
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.shapes import raw_patterns, single_contact_spread
from test.support.degraded_disc import degrade, pipeline_images
from test.support.patch_copies import small_disc_patch
from test.support.synthetic_touches import INSIDE, SIGMA_PA, X, Y, blobs, envelope, sequence

ELECTRODES = 0.04 * np.column_stack(
    [np.cos(np.arange(16) * np.pi / 8), np.sin(np.arange(16) * np.pi / 8)]
)


def ends(events):
    return [e for e in events if e.state == "end"]


def test_sheet_wide_drift_during_back_to_back_touches_does_not_freeze_a_touch() -> None:
    # touches 0.15 s apart for 6 s while the whole sheet drifts by 8 sigma; then silence
    def script(t):
        k = int((t - 0.8) // 1.0)
        if t < 0.8 or k >= 6:
            return [], 0.0
        start = 0.8 + k * 1.0
        where = [(0.015, 0.0), (-0.015, 0.005), (0.0, -0.015)][k % 3]
        return [where], 4000.0 * envelope(t, start, start + 0.85, 0.05)

    t, images = sequence(script, 9.0, seed=3)
    images = images + (8 * SIGMA_PA * np.clip((t - 0.6) / 6.0, 0, 1))[:, None, None]
    got = ends(classify_stream(TouchClassifier(X, Y), t, images.astype(np.float32)))
    assert len(got) == 6
    for k, e in enumerate(got):  # each ends with its contact, not seconds later
        assert e.t_end_s == pytest.approx(0.8 + k + 0.85, abs=0.08)


def test_two_pushes_separated_by_a_tenth_of_a_second_are_two_touches() -> None:
    def script(t):
        if t < 1.75:
            return [(0.02, 0.02)], 5000.0 * envelope(t, 1.0, 1.7, 0.05)
        return [(0.025, 0.01)], 5000.0 * envelope(t, 1.8, 2.6, 0.05)

    t, images = sequence(script, 3.5, seed=5)
    got = ends(classify_stream(TouchClassifier(X, Y), t, images))
    assert [e.label for e in got] == ["push", "push"]
    assert got[0].t_end_s < 1.8 <= got[1].t_start_s


def test_confidence_is_lower_next_to_a_faulty_electrode() -> None:
    t, images = sequence(
        lambda t: ([(0.032, 0.0)], 5000.0 * envelope(t, 1.0, 1.8)) if t > 0.9 else ([], 0), 2.5
    )
    healthy = TouchClassifier(X, Y, electrodes_m=ELECTRODES)
    faulty = TouchClassifier(X, Y, electrodes_m=ELECTRODES)
    faulty.set_faulty_electrodes([0])
    faulty_far = TouchClassifier(X, Y, electrodes_m=ELECTRODES)
    faulty_far.set_faulty_electrodes([8])  # the opposite side of the sheet
    got = {}
    for name, clf in (("healthy", healthy), ("faulty", faulty), ("far", faulty_far)):
        events = [e for k in range(len(t)) for e in clf.step(float(t[k]), images[k])]
        (got[name],) = ends(events + clf.finish())
    assert faulty.near_fault(got["faulty"].centroid_m)
    assert not faulty_far.near_fault(got["far"].centroid_m)
    assert got["faulty"].label == got["healthy"].label == "push"
    assert got["faulty"].confidence < got["healthy"].confidence
    assert got["far"].confidence == got["healthy"].confidence


def test_a_faulty_set_reported_during_a_touch_does_not_cut_it() -> None:
    # the pipeline's fault check may flag an electrode next to a press for a second: the
    # touch goes on as one touch, and only its confidence drops
    t, images = sequence(
        lambda t: ([(0.032, 0.0)], 5000.0 * envelope(t, 1.0, 2.4)) if t > 0.9 else ([], 0), 3.0
    )
    clf = TouchClassifier(X, Y, electrodes_m=ELECTRODES)
    events = []
    for k in range(len(t)):
        clf.set_faulty_electrodes([0] if 1.5 <= t[k] < 2.0 else [])
        events += clf.step(float(t[k]), images[k])
    updates = [e for e in events if e.state == "update"]
    (end,) = ends(events + clf.finish())
    assert end.t_start_s < 1.5 and end.t_end_s > 2.0
    lowered = [e.confidence for e in updates if 1.5 <= e.t_s < 2.0]
    normal = [e.confidence for e in updates if e.t_s >= 2.0]
    assert lowered and normal and max(lowered) < min(normal)
    with pytest.raises(ValueError, match="out of range"):
        clf.set_faulty_electrodes([16])
    with pytest.raises(ValueError, match="electrodes_m"):
        TouchClassifier(X, Y).set_faulty_electrodes([1])
    with pytest.raises(ValueError, match="fault_confidence"):
        ClassifierConfig(fault_confidence=0.0)


def test_hard_scenes_fit_the_sheet_and_are_deterministic() -> None:
    patch = load_patch(config_path("arm"))
    frame = SheetFrame.of(patch)
    for category in HARD_SCENES:
        a = hard_scenario(category, 3, 12.0, patch)
        assert a == hard_scenario(category, 3, 12.0, patch)
        assert len(a.touches) >= 3 and all(frame.fits(s) for s in a.touches)
    gaps = [
        b.t_start_s - a.t_end_s - a.settle_s
        for a, b in zip(
            hard_scenario("back_to_back", 3, 12.0, patch).touches[:-1],
            hard_scenario("back_to_back", 3, 12.0, patch).touches[1:],
            strict=True,
        )
    ]
    assert min(gaps) >= 0.1 and max(gaps) <= 0.2 + 1e-9
    pinch = hard_scenario("close_pinch", 3, 12.0, patch).touches[0]
    assert 0.014 <= pinch.start_gap_m <= 0.016 and 0.004 <= pinch.end_gap_m <= 0.006
    with pytest.raises(KeyError, match="hard scene"):
        hard_scenario("nope", 1, 10.0, patch)


# Close pinches and short rubs under a wide blur (issue 18): one finger's image 9 mm wide,
# as on the knit patches, so that two fingers closing from 15 to 5 mm make one blob that
# narrows by only ~0.3 finger spreads, and a 13 mm stroke travels ~1.45 finger spreads.
WIDE_M = 0.009


def _wide_sequence(script, duration_s: float, seed: int):
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * 50.0)) / 50.0
    frames = []
    for tk in t:
        centres, amplitude = script(tk)
        image = blobs(centres, amplitude, WIDE_M) if len(centres) else np.zeros(INSIDE.shape)
        image = image + SIGMA_PA * rng.standard_normal(image.shape)
        frames.append(np.where(INSIDE, image, np.nan))
    return t, np.array(frames, dtype=np.float32)


def _close_pinch(t):
    half = 0.0075 - 0.005 * np.clip((t - 1.15) / 0.8, 0, 1)  # 15 mm -> 5 mm apart
    return [(0.005, -half), (0.005, half)], 1500.0 * envelope(t, 1.0, 2.4)


def _labels(t, images, config=None, stretch=None):
    events = classify_stream(
        TouchClassifier(X, Y, config, contact_spread_m=WIDE_M), t, images, stretch
    )
    return [e.label for e in ends(events)]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_close_pinch_is_a_pinch_on_one_layer_and_on_two(seed) -> None:
    t, images = _wide_sequence(_close_pinch, 3.0, seed)
    assert _labels(t, images) == ["pinch"]
    # the steady-narrowing rule decides it: the relative narrowing alone says push
    assert _labels(t, images, ClassifierConfig(pinch_trend=1e9)) == ["push"]
    # a two-layer patch: the stretch layer's image (a band between the fingers) rides along
    stretch = np.stack([blobs([(0.005, 0.0)], 0.05 * envelope(tk, 1.0, 2.4), WIDE_M) for tk in t])
    stretch = np.where(
        INSIDE, stretch + 1e-4 * np.random.default_rng(seed).normal(size=stretch.shape), np.nan
    )
    assert _labels(t, images, stretch=stretch.astype(np.float32)) == ["pinch"]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_push_under_the_same_blur_stays_a_push(seed) -> None:
    t, images = _wide_sequence(
        lambda t: ([(0.005, 0.0)], 3000.0 * envelope(t, 1.0, 2.4)), 3.0, seed
    )
    assert _labels(t, images) == ["push"]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_short_rub_is_a_rub(seed) -> None:
    def rub(t):  # 13 mm in 0.5 s
        return [(-0.01 + 0.013 * np.clip((t - 1.15) / 0.5, 0, 1), 0.005)], 3000.0 * envelope(
            t, 1.0, 1.9
        )

    t, images = _wide_sequence(rub, 2.5, seed)
    assert _labels(t, images) == ["rub"]
    # the former threshold (1.5 finger spreads) read it as a push
    assert _labels(t, images, ClassifierConfig(rub_travel=1.5)) == ["push"]


#: The solver these classifier tests were written with (the package default before issue 35's
#: leave-one-set-out choice); the default's own case is the known failure below.
WRITTEN_FOR = "{method: one_step, prior: laplace, noise_figure: 0.3}"


def _degrading_electrode_images(
    tmp_path, seconds: float = 4.0, onset_s: float = 1.5, solver: str = WRITTEN_FOR
):
    """Idle small disc, 10x noise on every channel of one electrode from ``onset_s``: the
    pipeline's images, faulty-electrode sets per frame, grid, spread map, electrodes, raw
    frames ``[T, M]`` V and the channel-electrode table."""
    path = tmp_path / "small.yaml"
    path.write_text(small_disc_patch(solver))
    patch = load_patch(path)
    layer = patch.layers[0]
    sim = SkinSimulator(patch, Scenario("idle", (), seconds), 50.0, seed=7, drift=NO_DRIFT)
    rec = sim.run(duration_s=seconds)
    protocol = sim.protocol(layer.name)
    frames = degrade(rec.layers[layer.name].frames, protocol, 3, rec.t >= onset_s, seed=5)
    imager, images, faulty = pipeline_images(layer, rec.t, frames, tmp_path / "cache")
    spread = single_contact_spread(imager)
    electrodes = np.array([e.center for e in layer.electrodes])
    table = channel_electrodes(protocol)
    patterns = raw_patterns(layer, imager)
    return rec.t, images, faulty, imager.grid, spread, electrodes, frames, table, patterns


def test_a_degrading_electrode_gives_no_event(tmp_path) -> None:
    # issue 18: 10x noise on one electrode's channels, no touch; the pipeline's fault check
    # (every second) names it, but the noise of the frames before reaches the images
    t, images, faulty, grid, spread, electrodes, volts, table, patterns = (
        _degrading_electrode_images(tmp_path)
    )
    assert any(3 in f for f in faulty)  # named by the pipeline in the end ...
    assert not any(faulty[k] for k in range(len(t)) if t[k] < 2.0)  # ... not at once

    def events(config=None, raw=False, start_filter=False):
        disc, contact = patterns if start_filter else (None, None)
        clf = TouchClassifier(
            grid.x,
            grid.y,
            config,
            contact_spread_m=spread,
            electrodes_m=electrodes,
            channel_electrodes=table if raw else None,
            disc_rel=disc,
            contact_rel=contact,
        )
        out = []
        for k in range(len(t)):
            clf.set_faulty_electrodes(faulty[k])
            out += clf.step(float(t[k]), images[k], None, volts[k] if raw else None)
        return out + clf.finish()

    assert events() == []
    # with the raw frames too: they name electrode 3, so the flicker is a fault's
    assert events(raw=True) == []
    # and with their START filter, which the noisy channels reach before the pipeline
    # names the electrode: the same raw-frame test keeps it from STARTing
    assert events(raw=True, start_filter=True) == []
    # the flicker rule is what keeps it quiet: without it, the noise starts a touch
    assert ends(events(ClassifierConfig(start_roughness=0.0)))
    assert ends(events(ClassifierConfig(start_roughness=0.0), raw=True))


def test_the_package_default_solver_keeps_the_idle_small_disc_quiet(tmp_path) -> None:
    # issue 37 item 5: the package default (one-step NOSER, noise figure 0.13) gave one false
    # push right after the 0.5 s calibration: the pooled noise map, a per-pixel MAD of 24
    # smooth frames, read a pixel at a fraction of its noise (now a standard deviation)
    t, images, _, grid, spread, electrodes, _, _, _ = _degrading_electrode_images(
        tmp_path, onset_s=10.0, solver=""
    )
    clf = TouchClassifier(grid.x, grid.y, contact_spread_m=spread, electrodes_m=electrodes)
    out = []
    for k in range(len(t)):
        out += clf.step(float(t[k]), images[k], None, None)
    assert out + clf.finish() == []


def _palm_press_start_s(raw: str, config=None) -> float:
    """START time after the onset (1 s) of a palm-wide press that ramps up in 50 ms.

    ``raw``: ``"none"`` (images only) or ``"broad"`` (raw frames too, changing on every
    channel). The fault's side, raw frames that name an electrode: the degrading-electrode
    test above.
    """
    table = channel_electrodes(build_protocol(ProtocolSpec(), 16))
    rng = np.random.default_rng(11)
    pattern = 1.0 + rng.random(table.shape[0])
    clf = TouchClassifier(X, Y, config, channel_electrodes=None if raw == "none" else table)
    for tk in np.arange(150) / 50.0:
        amplitude = envelope(tk, 1.0, 2.5, 0.05)
        image = blobs([(0.0, 0.0)], 1000.0 * amplitude, 0.02)
        image = image + SIGMA_PA * rng.standard_normal(image.shape)
        volts = 1.0 + 1e-3 * (rng.standard_normal(table.shape[0]) + 30.0 * amplitude * pattern)
        for event in clf.step(float(tk), image, None, None if raw == "none" else volts):
            if event.state == "start":
                return event.t_s - 1.0
    raise AssertionError("no START")


def test_a_palm_wide_press_starts_at_once_when_its_raw_frames_name_no_electrode() -> None:
    """Its fast onset makes the whole sheet's image flicker like a fault's noise; the raw
    frames tell it apart (the change is on every channel), so START is not held back."""
    held = _palm_press_start_s("none")
    assert held >= 0.15  # the images alone: the flicker rule holds START back
    assert _palm_press_start_s("none", ClassifierConfig(start_roughness=0.0)) <= 0.06
    assert _palm_press_start_s("broad") <= 0.06


def test_a_light_push_starts_sooner_from_its_raw_frames(tmp_path) -> None:
    """A 0.05 N press in the middle of the small disc (0.25 s ramp): the pooled image alone
    STARTs it past 100 ms; the raw frames' filter (docs/classifier.md 4b) at least a frame
    sooner and within 100 ms, with the same label and END."""
    path = tmp_path / "small.yaml"
    path.write_text(small_disc_patch(WRITTEN_FOR))
    patch = load_patch(path)
    layer = patch.layers[0]
    push = Push(1.0, 1.0, (0.0, 0.0), 0.05, 0.006, 0.25)
    sim = SkinSimulator(patch, Scenario("light", (push,), 2.5), 50.0, seed=7, drift=NO_DRIFT)
    rec = sim.run(duration_s=2.5)
    frames = rec.layers[layer.name].frames
    imager = LayerImager.build(layer, cache_dir=tmp_path / "cache")
    proc = LayerProcessor(imager)
    n_ref = proc.reference_frames
    proc.set_reference(frames[:n_ref].mean(axis=0), 0.0, frames[:n_ref])
    images = [proc.step(frames[k], float(rec.t[k])).image for k in range(len(rec.t))]
    spread = single_contact_spread(imager)
    disc, contact = raw_patterns(layer, imager)

    def events(start_filter: bool):
        clf = TouchClassifier(
            imager.grid.x,
            imager.grid.y,
            contact_spread_m=spread,
            channel_electrodes=channel_electrodes(imager.protocol),
            disc_rel=disc if start_filter else None,
            contact_rel=contact if start_filter else None,
        )
        out = []
        for k in range(len(rec.t)):
            out += clf.step(float(rec.t[k]), images[k], None, frames[k])
        out = [e for e in out + clf.finish() if e.state != "update"]
        assert [e.state for e in out] == ["start", "end"], out
        return out

    image_start, image_end = events(False)
    start, end = events(True)
    assert image_start.t_s - push.t_start_s > 0.1  # the image alone: late
    assert start.t_s - push.t_start_s <= 0.1 + 1e-9  # the frame 100 ms after contact
    assert start.t_s <= image_start.t_s - 0.02 + 1e-9
    assert (end.label, end.t_s) == (image_end.label, image_end.t_s)
