"""TouchClassifier.update_settings: new thresholds from the next frame, running state kept."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eit_skin.ros.parameters import WRITABLE
from eit_skin.touch.classifier import LIVE_SETTINGS, TouchClassifier
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.settings import declared_settings

X = Y = np.linspace(-0.015, 0.015, 31)
XX, YY = np.meshgrid(X, Y)
RATE_HZ = 50.0


def press(t_s: float, start_s: float, end_s: float, rng) -> np.ndarray:
    """A 400 Pa fingertip at the centre between ``start_s`` and ``end_s``, 5 Pa noise."""
    signal = 400.0 * np.exp(-(XX**2 + YY**2) / 0.004**2) if start_s <= t_s < end_s else 0.0
    return signal + rng.normal(0.0, 5.0, XX.shape)


def run(clf: TouchClassifier, k0: int, k1: int, start_s: float, end_s: float, rng) -> list:
    events = []
    for k in range(k0, k1):
        t = k / RATE_HZ
        events += clf.step(t, press(t, start_s, end_s, rng))
    return events


def raised_thresholds(config: ClassifierConfig) -> ClassifierConfig:
    """Contact and START thresholds no 400 Pa press reaches."""
    segmentation = replace(config.segmentation, k_high=1e6, k_low=1e6)
    return replace(config, segmentation=segmentation, k_detect=1e6)


def test_raised_thresholds_stop_events_from_the_next_frame_keeping_the_baseline() -> None:
    rng = np.random.default_rng(0)
    clf = TouchClassifier(X, Y)
    assert run(clf, 0, 50, 9.0, 9.0, rng) == []  # 1 s untouched: calibrated
    background, baseline = clf.background, clf.background.baseline
    pressed = run(clf, 50, 150, 1.2, 2.2, rng)
    assert [e.state for e in pressed if e.state != "update"] == ["start", "end"]

    clf.update_settings(raised_thresholds(clf.config))
    assert run(clf, 150, 250, 3.2, 4.2, rng) == []  # the same press: nothing
    # the learnt background is kept, never re-calibrated (its baseline, unaware of a touch
    # now, follows the press as it follows drift)
    assert clf.background is background and clf.background.baseline is baseline
    assert clf.detector.k == 1e6 and clf.segmenter.config.k_high == 1e6


def test_lowered_thresholds_find_the_next_press() -> None:
    """Calibrated under thresholds no press reaches, then set to the defaults: seen at once.

    (The other way round is no undo: frames a raised threshold calls untouched teach the
    baseline and noise maps, as drift would.)
    """
    rng = np.random.default_rng(2)
    clf = TouchClassifier(X, Y, raised_thresholds(ClassifierConfig()))
    assert run(clf, 0, 50, 9.0, 9.0, rng) == []
    clf.update_settings(ClassifierConfig())
    assert clf.detector.k == ClassifierConfig().k_detect
    events = run(clf, 50, 150, 1.2, 2.2, rng)
    assert [e.state for e in events if e.state != "update"] == ["start", "end"]


def test_a_touch_going_on_survives_an_update_and_derived_values_follow() -> None:
    rng = np.random.default_rng(1)
    clf = TouchClassifier(X, Y)
    run(clf, 0, 50, 9.0, 9.0, rng)
    started = run(clf, 50, 80, 1.2, 3.0, rng)
    (start,) = [e for e in started if e.state == "start"]
    assert clf.active
    config = replace(clf.config, gate_pixels=3.0, track_missed_frames=5, offset_margin=4.0)
    clf.update_settings(config)
    assert clf.active  # the touch and its track are kept
    assert clf.events.tracker.gate_m == pytest.approx(3.0 * clf.pixel_m)
    assert clf.events.tracker.max_missed == 5
    unit_px = float(np.median(clf.contact_spread_m)) / clf.pixel_m
    assert clf.background.margin_px == round(4.0 * unit_px)
    rest = run(clf, 80, 200, 1.2, 3.0, rng)
    assert [e.state for e in rest if e.state != "update"] == ["end"]
    assert {e.touch_id for e in rest} == {start.touch_id}


def test_a_setting_fixed_by_calibration_is_refused_by_name() -> None:
    clf = TouchClassifier(X, Y)
    before = clf.config
    with pytest.raises(ValueError, match="average_frames, calibration_s: cannot change"):
        clf.update_settings(replace(before, average_frames=4, calibration_s=2.0))
    assert clf.config is before


def test_every_live_setting_is_declared_and_a_writable_node_parameter() -> None:
    declared = {s.name for s in declared_settings(ClassifierConfig) if s.node}
    assert declared >= LIVE_SETTINGS
    assert set(WRITABLE["eit_classifier"]) >= LIVE_SETTINGS
    assert "calibration_s" not in WRITABLE["eit_classifier"]
