"""Scores of touch events against simulated truth, shared by the classifier benchmarks.

One place for the matching rules, imported by ``bench/standing/bench_classifier.py`` (easy
random scenes) and ``bench/standing/bench_hard_scenes.py`` (hard scenes), so both tables count
the same thing. Depends on numpy and the package's label list only.

Matching: every true touch (``{"label", "t_start", "t_end"}``, s) takes the not yet used END
event overlapping it longest in time; END events matching no touch are false events. A row
per true touch: ``(true label, predicted label or None, START latency s or None, overrun s
or None)``: latency from the touch's first frame of force to its START event, overrun the
event's duration minus the touch's.
"""

from __future__ import annotations

import numpy as np

from eit_skin.touch.events import LABELS


def match(events, truth: list[dict]) -> list:
    """The END event matched to each true touch (``None``: missed), in the truth's order."""
    ends = [e for e in events if e.state == "end"]
    used, matched = set(), []
    for tr in truth:
        best, overlap = None, 0.0
        for e in ends:
            o = min(e.t_end_s, tr["t_end"]) - max(e.t_start_s, tr["t_start"])
            if o > overlap and e.touch_id not in used:
                best, overlap = e, o
        if best is not None:
            used.add(best.touch_id)
        matched.append(best)
    return matched


def score(events, truth: list[dict]) -> tuple[list[tuple], list]:
    """``(rows, unmatched END events)`` of one run's events against its true touches."""
    ends = [e for e in events if e.state == "end"]
    starts = {e.touch_id: e for e in events if e.state == "start"}
    used, rows = set(), []
    for tr, best in zip(truth, match(events, truth), strict=True):
        if best is None:
            rows.append((tr["label"], None, None, None))
            continue
        used.add(best.touch_id)
        start = starts.get(best.touch_id, best)
        latency = start.t_s - tr["t_start"]
        overrun = (best.t_end_s - best.t_start_s) - (tr["t_end"] - tr["t_start"])
        rows.append((tr["label"], best.label, latency, overrun))
    return rows, [e for e in ends if e.touch_id not in used]


def confusion(rows) -> np.ndarray:
    """``[4, 5]`` counts: rows the true label, columns the predicted label, then missed."""
    cm = np.zeros((len(LABELS), len(LABELS) + 1), dtype=int)
    for true, pred, *_ in rows:
        cm[LABELS.index(true), len(LABELS) if pred is None else LABELS.index(pred)] += 1
    return cm


def recalls(cm: np.ndarray) -> np.ndarray:
    """``[4]`` recall per true label (NaN for a label with no touch)."""
    with np.errstate(invalid="ignore"):
        return np.diag(cm[:, : len(LABELS)]) / cm.sum(axis=1)


def balanced_accuracy(cm: np.ndarray) -> float:
    """Mean recall over the labels that have touches (NaN if none has)."""
    rec = recalls(cm)
    rec = rec[np.isfinite(rec)]
    return float(np.mean(rec)) if rec.size else float("nan")
