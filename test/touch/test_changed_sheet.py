"""A "touch" longer than ``sheet_change_taus`` baseline time constants is the sheet changing:
withdrawn (END, confidence 0, the reason), no touch until the sheet has stayed still, then the
classifier works again (docs/classifier.md, "Changed sheet"). Synthetic images whose timing
is known exactly; the real damage recording: test/pipeline/test_hydrogel_damage.py."""

from __future__ import annotations

import numpy as np

from eit_skin.touch.classifier import TouchClassifier, classify_stream
from eit_skin.touch.config import ClassifierConfig
from test.support.synthetic_touches import X, Y, envelope, sequence

# a 2 s bound (4 baseline time constants of 0.5 s) keeps the streams short
CONFIG = ClassifierConfig(baseline_tau_s=0.5, sheet_change_taus=4.0)
BOUND_S = 2.0


def test_a_hold_shorter_than_the_bound_stays_a_touch() -> None:
    t, images = sequence(lambda t: ([(0.01, 0.0)], 5000.0 * envelope(t, 1.0, 2.8)), 4.0)
    events = classify_stream(TouchClassifier(X, Y, CONFIG), t, images)
    ends = [e for e in events if e.state == "end"]
    assert len(ends) == 1 and ends[0].label == "push" and not ends[0].withdrawn
    assert ends[0].confidence > 0.5 and ends[0].duration_s > 0.8 * (2.8 - 1.0)


def test_an_object_left_on_the_sheet_is_withdrawn_then_the_sheet_works_again() -> None:
    """An object pressed at 1 s stays (sheet changed); once the sheet has been still for the
    bound the classifier has calibrated again and a push at 8 s is a push."""

    def script(t):
        second = [(-0.015, 0.01)] if 8.0 <= t < 9.0 else []
        return [(0.01, 0.0), *second], 5000.0 * envelope(t, 1.0, 100.0)

    t, images = sequence(script, 10.0)
    clf = TouchClassifier(X, Y, CONFIG)
    events, changed = [], []
    for k in range(len(t)):
        events += clf.step(float(t[k]), images[k])
        changed.append(clf.sheet_changed is not None)
    events += clf.finish()
    ends = [e for e in events if e.state == "end"]
    assert len(ends) == 2, [(e.state, e.t_s, e.withdrawn) for e in events]
    withdrawn, push = ends
    assert withdrawn.confidence == 0.0 and "sheet changed" in withdrawn.withdrawn
    assert BOUND_S < withdrawn.t_s - withdrawn.t_start_s <= BOUND_S + 0.05
    changed_t = t[np.array(changed)]
    assert changed_t[0] == withdrawn.t_s  # from the withdrawal ...
    assert changed_t[-1] < withdrawn.t_s + BOUND_S + 0.1  # ... for one still window
    assert not push.withdrawn and push.label == "push" and push.confidence > 0.5
    assert (
        8.0 <= push.t_start_s <= 8.2
        and np.hypot(*np.subtract(push.centroid_m, (-0.015, 0.01))) < 0.003
    )


def test_a_sheet_that_keeps_changing_is_withdrawn_once_and_then_silent() -> None:
    """A change that keeps growing at new places (damage spreading): one withdrawn touch, then
    no event at all, the sheet reported changed to the end."""
    rng = np.random.default_rng(3)
    places = rng.uniform(-0.025, 0.025, size=(40, 2))

    def script(t):
        n = int(np.clip((t - 1.0) / 0.5, 0, len(places)))  # a new spot every 0.5 s from 1 s
        return places[:n], 3000.0

    t, images = sequence(script, 20.0)
    clf = TouchClassifier(X, Y, CONFIG)
    events = classify_stream(clf, t, images)
    assert [e.state for e in events if e.state != "update"] == ["start", "end"]
    assert events[-1].withdrawn and events[-1].confidence == 0.0
    assert clf.sheet_changed is not None
