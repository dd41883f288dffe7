"""TouchClassifier on synthetic blob sequences whose labels and timing are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.touch_classifier import ClassifierConfig, TouchClassifier, classify_stream
from test.synthetic_touches import INSIDE, SIGMA_PA, X, Y, envelope, sequence

ONSET_S, RELEASE_S = 1.0, 2.2


def run(script, duration_s=3.0, seed=0):
    t, images = sequence(script, duration_s, seed=seed)
    return classify_stream(t, images, X, Y)


def one_touch(events):
    ids = {e.touch_id for e in events}
    assert len(ids) == 1, events
    states = [e.state for e in events]
    assert states[0] == "start" and states[-1] == "end"
    assert set(states[1:-1]) <= {"update"}
    return events[0], events[1:-1], events[-1]


def test_push_gives_start_updates_end_with_its_centroid_and_timing() -> None:
    events = run(lambda t: ([(0.01, -0.005)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)))
    start, updates, end = one_touch(events)
    assert ONSET_S < start.t_s <= ONSET_S + 0.15  # START within 150 ms of onset
    assert start.t_start_s >= ONSET_S
    assert end.label == "push"
    assert end.t_end_s == pytest.approx(RELEASE_S, abs=0.05)
    assert end.duration_s == pytest.approx(end.t_end_s - start.t_start_s)
    np.testing.assert_allclose(updates[len(updates) // 2].centroid_m, (0.01, -0.005), atol=5e-4)
    gaps = np.diff([e.t_s for e in updates])
    assert gaps.min() >= 0.1 - 1e-9 and len(updates) >= 8
    assert 0.5 < end.confidence <= 1.0


def test_rub_is_a_contact_that_travels() -> None:
    def script(t):
        x = -0.015 + 0.02 * np.clip((t - ONSET_S - 0.1) / 1.0, 0, 1)  # 20 mm sideways
        return [(x, 0.0)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)

    start, _, end = one_touch(run(script))
    assert start.label == "push"  # provisional: it has not moved yet
    assert end.label == "rub"
    assert end.centroid_m[0] == pytest.approx(0.005, abs=1e-3)


def test_pinch_is_two_contacts_closing() -> None:
    def script(t):
        half = 0.02 - 0.013 * np.clip((t - ONSET_S - 0.1) / 1.0, 0, 1)  # gap 40 -> 14 mm
        return [(0.0, -half), (0.0, half)], 4000.0 * envelope(t, ONSET_S, RELEASE_S)

    _, _, end = one_touch(run(script))
    assert end.label == "pinch"


@pytest.mark.parametrize("n", [2, 4])
def test_grab_is_several_still_contacts(n) -> None:
    angles = 2 * np.pi * np.arange(n) / n
    centres = 0.02 * np.column_stack([np.cos(angles), np.sin(angles)])
    start, _, end = one_touch(run(lambda t: (centres, 4000.0 * envelope(t, ONSET_S, RELEASE_S))))
    assert start.label == "grab" and end.label == "grab"
    np.testing.assert_allclose(start.centroid_m, (0.0, 0.0), atol=1e-3)


def test_two_touches_get_two_ids() -> None:
    def script(t):
        if t < 2.0:
            return [(0.01, 0.0)], 5000.0 * envelope(t, 0.8, 1.6)
        return [(-0.01, 0.0)], 5000.0 * envelope(t, 2.2, 3.0)

    events = run(script, duration_s=3.5)
    ends = [e for e in events if e.state == "end"]
    assert [e.touch_id for e in ends] == [1, 2]
    assert ends[0].centroid_m[0] > 0 > ends[1].centroid_m[0]


def test_no_touch_with_slow_drift_gives_no_event() -> None:
    # a uniform offset drifting by 8 sigma over 30 s: the baseline follows it
    t, images = sequence(lambda t: ([], 0.0), 30.0, seed=4)
    images = images + (8 * SIGMA_PA * t / 30.0)[:, None, None].astype(np.float32)
    assert classify_stream(t, images, X, Y) == []


def test_calibration_frames_never_produce_events_and_noise_is_estimated() -> None:
    clf = TouchClassifier(X, Y, ClassifierConfig(calibration_s=0.5))
    t, images = sequence(lambda t: ([(0.0, 0.0)], 5000.0 * (t > 0.3)), 1.0)
    events = [e for k in range(len(t)) for e in clf.step(t[k], images[k])]
    assert all(e.t_s > 0.5 for e in events)
    assert clf.calibrated


def test_noise_from_calibration_matches_the_image_noise() -> None:
    clf = TouchClassifier(X, Y)
    t, images = sequence(lambda t: ([], 0.0), 1.0, seed=2)
    for k in range(len(t)):
        clf.step(t[k], images[k])
    assert clf.pressure_noise_pa == pytest.approx(SIGMA_PA, rel=0.05)
    assert np.isnan(images[0][~INSIDE]).all()


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="pinch_closing"):
        ClassifierConfig(pinch_closing=1.5)
    with pytest.raises(ValueError, match="start_frames"):
        ClassifierConfig(start_frames=0)
