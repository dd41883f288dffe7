"""Hard scenes for the touch classifier: drift during touches, back-to-back touches, faults."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.scenario import HARD_SCENES, SheetFrame, hard_scenario
from eit_skin.touch.classifier import classify_stream
from test.synthetic_touches import SIGMA_PA, X, Y, envelope, sequence


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
    got = ends(classify_stream(t, images.astype(np.float32), X, Y))
    assert len(got) == 6
    for k, e in enumerate(got):  # each ends with its contact, not seconds later
        assert e.t_end_s == pytest.approx(0.8 + k + 0.85, abs=0.08)


def test_two_pushes_separated_by_a_tenth_of_a_second_are_two_touches() -> None:
    def script(t):
        if t < 1.75:
            return [(0.02, 0.02)], 5000.0 * envelope(t, 1.0, 1.7, 0.05)
        return [(0.025, 0.01)], 5000.0 * envelope(t, 1.8, 2.6, 0.05)

    t, images = sequence(script, 3.5, seed=5)
    got = ends(classify_stream(t, images, X, Y))
    assert [e.label for e in got] == ["push", "push"]
    assert got[0].t_end_s < 1.8 <= got[1].t_start_s


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
