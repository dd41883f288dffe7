"""Event assembly's records: labels, events, per-frame blob shapes, features and the rules.

:func:`decide` turns a touch's :class:`TouchFeatures` into a label and a confidence by these
rules, in this order (thresholds of :class:`~eit_skin.touch.config.ClassifierConfig`; why each
exists: docs/classifier.md):

* ``closing >= pinch_closing`` -> pinch; ``spread >= grab_spread`` -> grab;
  ``travel >= rub_travel`` -> rub;
* a steady narrowing (``trend >= pinch_trend`` and ``narrowing >= pinch_narrowing``) -> pinch;
* ``major >= grab_major`` (a long blob: fingers along an arc) -> grab;
* with the pressure layer's raw frames, a pattern that changes steadily while the touch holds
  (``shape_z >= pinch_shape_z``: a close pinch) -> pinch;
* with a stretch layer, ``stretch_ratio >= stretch_ratio_rub`` -> pinch; else push.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import Contact

LABELS = ("push", "rub", "pinch", "grab")
"""Touch labels, in the order of ``eit_skin_msgs/TouchEvent`` (PUSH=0 ... GRAB=3)."""
STATES = ("start", "update", "end")
"""Event states, in the order of ``eit_skin_msgs/TouchEvent`` (START=0, UPDATE=1, END=2)."""


@dataclass(frozen=True)
class TouchEvent:
    """One event of one touch.

    Attributes:
        touch_id: id shared by the START, UPDATEs and END of a touch (from 1).
        state: ``"start" | "update" | "end"``.
        label: ``"push" | "rub" | "pinch" | "grab"``.
        confidence: 0..1.
        t_s: time of the frame that produced the event, s.
        t_start_s: first frame of the touch, s.
        t_end_s: last frame with contact (END), else ``t_s``, s.
        centroid_m: ``(x, y)`` centroid of the whole touch's blob in the latest frame pressed at
            full strength (at least ``strong_fraction`` of the touch's peak), m.
        area_m2: total contact area, m^2.
        peak_pa: largest pressure of the current contacts, Pa.
        n_contacts: contacts in the frame.
        withdrawn: why an END is no touch after all (the sheet changed under it; its
            confidence is 0), empty for a touch.
    """

    touch_id: int
    state: str
    label: str
    confidence: float
    t_s: float
    t_start_s: float
    t_end_s: float
    centroid_m: tuple[float, float]
    area_m2: float
    peak_pa: float
    n_contacts: int
    withdrawn: str = ""

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s

    def to_dict(self) -> dict:
        """JSON-ready summary (the ``eit-skin classify`` line)."""
        return {
            "label": self.label,
            "t_start": round(self.t_start_s, 4),
            "t_end": round(self.t_end_s, 4),
            "confidence": round(self.confidence, 3),
            "centroid": [round(self.centroid_m[0], 5), round(self.centroid_m[1], 5)],
        }


@dataclass(frozen=True)
class TouchFeatures:
    """What the rules look at (see module docstring).

    Attributes:
        count: most separate contacts seen together in ``count_frames`` frames.
        travel: largest distance of the blob centroid from where it settled, in single-finger
            spreads.
        closing: largest relative narrowing of the blob's major axis (0..1).
        spread: median blob spread ``sqrt(major * minor)``, in single-finger spreads.
        elongation: median ratio of the blob's major to minor spread (>= 1).
        stretch_ratio: largest stretch over largest pressure, 1/Pa (stretch layer only).
        frames: strong frames the shape features were computed from.
        trend: t-statistic of the narrowing of the blob's major axis (in single-finger
            spreads) over the strong frames: least-squares slope over its standard error,
            positive when the blob narrows (0 with fewer than 4 frames).
        narrowing: that fitted narrowing from the first to the last strong frame, in
            single-finger spreads.
        major: median major spread of the blob, in single-finger spreads.
        shape_z: still-touch shape-change z-score of the raw frames over the plateau
            (:func:`~eit_skin.touch.frame_evidence.shape_change_z`); NaN without raw frames
            or with too few plateau frames.
    """

    count: int
    travel: float
    closing: float
    spread: float
    elongation: float
    stretch_ratio: float | None = None
    frames: int = 0
    trend: float = 0.0
    narrowing: float = 0.0
    major: float = 1.0
    shape_z: float = math.nan


def decide(features: TouchFeatures, config: ClassifierConfig) -> tuple[str, float]:
    """``(label, confidence)`` from the features by the rules of the module docstring.

    The confidence grows with the relative distance of the deciding feature(s) from their
    thresholds (0.5 on a threshold, towards 1 far from it).
    """

    def margin(value: float, threshold: float) -> float:
        return 0.5 + 0.5 * math.tanh(config.confidence_gain * abs(value - threshold) / threshold)

    f, c = features, config
    if f.closing >= c.pinch_closing:
        return "pinch", margin(f.closing, c.pinch_closing)
    if f.spread >= c.grab_spread:
        return "grab", margin(f.spread, c.grab_spread)
    if f.travel >= c.rub_travel:
        return "rub", min(margin(f.travel, c.rub_travel), margin(f.closing, c.pinch_closing))
    if f.trend >= c.pinch_trend and f.narrowing >= c.pinch_narrowing:
        return "pinch", margin(f.trend, c.pinch_trend)
    if f.major >= c.grab_major:
        return "grab", margin(f.major, c.grab_major)
    shape_z = f.shape_z if c.pinch_shape_z > 0 and math.isfinite(f.shape_z) else None
    if shape_z is not None and shape_z >= c.pinch_shape_z:
        return "pinch", margin(shape_z, c.pinch_shape_z)
    ratio = f.stretch_ratio
    if ratio is not None and c.stretch_ratio_rub > 0 and ratio >= c.stretch_ratio_rub:
        return "pinch", 0.5 * margin(ratio, c.stretch_ratio_rub)
    conf = min(
        margin(f.travel, c.rub_travel),
        margin(f.closing, c.pinch_closing),
        margin(f.spread, c.grab_spread),
        margin(max(f.trend, 0.0), c.pinch_trend),
        margin(f.major, c.grab_major),
        1.0 if shape_z is None else margin(shape_z, c.pinch_shape_z),
    )
    return "push", conf


SHAPE_DTYPE = np.dtype(
    [
        ("t_s", np.float64),
        ("peak", np.float64),
        ("x_m", np.float64),
        ("y_m", np.float64),
        ("major_m", np.float64),
        ("minor_m", np.float64),
        ("finger_m", np.float64),
    ]
)
"""One frame's blob shape (a record of :class:`ShapeHistory`): frame time ``t_s`` (s), image
``peak`` (Pa), blob centroid ``x_m``, ``y_m`` (m), principal spreads ``major_m >= minor_m``
(m) and one finger's spread at the centroid ``finger_m`` (m); NaN where undefined."""


class ShapeHistory:
    """Blob shapes of a touch's frames: a growing ``[T]`` record array of :data:`SHAPE_DTYPE`.

    Appending copies one record into spare capacity (doubled when full: amortised O(1));
    :attr:`rows` is a view of the records so far, not a copy.
    """

    def __init__(self, rows: np.ndarray | None = None) -> None:
        rows = np.zeros(0, SHAPE_DTYPE) if rows is None else np.asarray(rows, SHAPE_DTYPE)
        self._data = np.empty(max(64, 2 * rows.size), SHAPE_DTYPE)
        self._data[: rows.size] = rows
        self._n = rows.size

    def __len__(self) -> int:
        return self._n

    def append(self, shape: np.ndarray) -> None:
        """Add one record (a 0-d :data:`SHAPE_DTYPE` array)."""
        if self._n == self._data.size:
            self._data = np.concatenate([self._data, np.empty_like(self._data)])
        self._data[self._n] = shape
        self._n += 1

    @property
    def rows(self) -> np.ndarray:
        """``[T]`` records, oldest first (a view)."""
        return self._data[: self._n]


class OngoingTouch:
    """Evidence collected over one touch."""

    def __init__(self, touch_id: int, t_s: float) -> None:
        self.id = touch_id
        self.t_start_s = t_s
        self.t_last_s = t_s
        self.t_contact_s = t_s  # the latest frame with a segmented contact
        self.t_last_update_s = t_s
        self.counts: list[int] = []
        self.shapes = ShapeHistory()
        self.max_pressure = 0.0
        self.max_stretch: float | None = None
        self.last_contacts: list[Contact] = []
        self.missing = 0
        self.label = "push"
        self.confidence = 0.5
        self.early = None  # EarlyEstimate while no contact is segmented (pooled START)
        self.changes: list[np.ndarray | None] = []  # whitened raw frame per shape record
        self.faulty: list[tuple[int, ...]] = []  # electrodes named faulty, per shape record

    def count(self, min_frames: int) -> int:
        if not self.counts:
            return 0
        counts = np.sort(np.asarray(self.counts))[::-1]
        return int(counts[min(min_frames, counts.size) - 1])


def shape_features(shapes: np.ndarray, config: ClassifierConfig) -> dict[str, float]:
    """Shape features of a touch's per-frame blob shapes (see :class:`TouchFeatures`).

    Args:
        shapes: ``[T]`` records of :data:`SHAPE_DTYPE`; records with a NaN field are ignored.
        config: ``strong_fraction`` (frames with a peak below this fraction of the largest
            are ignored by every feature but ``travel``), ``travel_fraction`` (likewise for
            ``travel``), ``closing_window`` (rolling median against single noisy frames).

    Returns:
        ``travel``, ``closing``, ``spread``, ``elongation``, ``trend``, ``narrowing``,
        ``major`` and ``frames`` (strong frames used).
    """
    finite = np.ones(shapes.size, dtype=bool)
    for name in SHAPE_DTYPE.names:
        finite &= np.isfinite(shapes[name])
    s = shapes[finite]
    out = {
        "travel": 0.0,
        "closing": 0.0,
        "spread": 1.0,
        "elongation": 1.0,
        "trend": 0.0,
        "narrowing": 0.0,
        "major": 1.0,
    }
    if s.size == 0:
        return {**out, "frames": 0}
    top = s["peak"].max()
    out["travel"] = _travel(s[s["peak"] >= config.travel_fraction * top], config.closing_window)
    s = s[s["peak"] >= config.strong_fraction * top]
    finger = np.maximum(s["finger_m"], 1e-6)
    major = s["major_m"] / finger
    out["spread"] = float(np.median(np.sqrt(s["major_m"] * s["minor_m"]) / finger))
    out["major"] = float(np.median(major))
    out["elongation"] = float(np.median(s["major_m"] / np.maximum(s["minor_m"], 1e-9)))
    n = s.size
    w = min(config.closing_window, n)  # rolling median against noisy frames
    smooth = np.median(np.lib.stride_tricks.sliding_window_view(major, w), axis=1)
    out["closing"] = float(np.max(1.0 - smooth / np.maximum.accumulate(smooth)))
    out["trend"], out["narrowing"] = _narrowing_trend(s["t_s"], major)
    return {**out, "frames": n}


def _travel(s: np.ndarray, window: int) -> float:
    """How far the blob centroid went over ``s`` (``[T]`` shapes), in single-finger spreads.

    The centroid path is smoothed by a rolling median of ``window`` frames (one noisy frame of
    a weak press moves it by half a finger spread); the travel is the largest distance of a
    smoothed point from either end of the path: a stroke's whole length, however it began.
    """
    if s.size == 0:
        return 0.0
    xy = np.column_stack([s["x_m"], s["y_m"]])
    w = min(window, len(xy))
    xy = np.median(np.lib.stride_tricks.sliding_window_view(xy, w, axis=0), axis=-1)
    far = max(np.linalg.norm(xy - xy[0], axis=1).max(), np.linalg.norm(xy - xy[-1], axis=1).max())
    return float(far) / float(np.median(np.maximum(s["finger_m"], 1e-6)))


def _narrowing_trend(t_s: np.ndarray, major: np.ndarray) -> tuple[float, float]:
    """``(t, narrowing)``: least-squares narrowing of ``major`` ``[T]`` over time ``t_s`` ``[T]``.

    ``t`` is minus the fitted slope over its standard error (residual scatter of the frames);
    ``narrowing`` the fitted decrease from the first to the last frame, in the unit of
    ``major``. Both 0 with fewer than 4 frames or no time span.
    """
    n = major.size
    if n < 4:
        return 0.0, 0.0
    tc = t_s - t_s.mean()
    sxx = float(np.dot(tc, tc))
    if sxx <= 0:
        return 0.0, 0.0
    slope = float(np.dot(tc, major - major.mean())) / sxx
    resid = major - major.mean() - slope * tc
    stderr = math.sqrt(float(np.dot(resid, resid)) / (n - 2) / sxx)
    span = float(t_s[-1] - t_s[0])
    return -slope / max(stderr, 1e-12), -slope * span
