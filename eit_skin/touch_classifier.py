"""Touches from a stream of reconstructed images: START / UPDATE / END events, labelled.

:class:`TouchClassifier` takes frames ``(t_s, pressure [H, W] Pa, stretch [H, W] strain or
None)`` and returns :class:`TouchEvent` records. Method (explainable rules on a few features,
see docs/classifier.md):

* calibration: the first ``calibration_s`` of frames are taken as no-touch; they give the
  image noise ``sigma`` (:func:`~eit_skin.contacts.estimate_noise`) and a per-pixel baseline
  that then follows slow drift (time constant ``baseline_tau_s``) while nothing touches;
* contacts: hysteresis segmentation of ``pressure - baseline`` at multiples of ``sigma``
  (:class:`~eit_skin.contacts.ContactSegmenter`), tracked with a gate in metres;
* a touch starts after contacts were seen in ``start_frames`` consecutive frames and ends
  after ``end_hold_s`` without contact (hysteresis in time); all contacts on the patch
  belong to the one current touch;
* features of the touch so far: ``count`` (most contacts seen at once for ``count_frames``
  frames), ``travel`` (largest distance of the strongest contact from where it started, m),
  ``closing`` (how much the distance between two contacts shrank, 0..1; two contacts merging
  into one counts as 1), ``stretch_ratio`` (largest stretch over largest pressure, 1/Pa);
* rules: ``count >= 3`` -> grab; ``count == 2`` -> pinch if closing, else grab; one contact ->
  rub if it travels (or, with a stretch layer, stretches the sheet strongly), else push;
  a single contact that does not travel but stretches the sheet strongly -> pinch (fingers too
  close to be told apart).

The label of START is provisional (evidence of the first frames); UPDATEs carry the label on
the evidence so far and may revise it; END carries the final label.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from eit_skin.contacts import (
    Contact,
    ContactSegmenter,
    ContactTracker,
    SegmentationConfig,
    estimate_noise,
    estimate_noise_map,
)

LABELS = ("push", "rub", "pinch", "grab")
"""Touch labels, in the order of ``eit_skin_msgs/TouchEvent`` (PUSH=0 ... GRAB=3)."""
STATES = ("start", "update", "end")
"""Event states, in the order of ``eit_skin_msgs/TouchEvent`` (START=0, UPDATE=1, END=2)."""


@dataclass(frozen=True)
class ClassifierConfig:
    """Thresholds and timing of the touch classifier.

    Attributes:
        segmentation: contact thresholds in noise units (see :class:`SegmentationConfig`).
        calibration_s: initial no-touch time used to estimate noise and baseline, s.
        baseline_tau_s: time constant of the drift-following baseline (idle frames only), s.
        start_frames: consecutive frames with a contact before START.
        end_hold_s: time without contact before END, s.
        update_period_s: shortest time between UPDATEs of one touch, s.
        count_frames: frames a contact count must be seen to count.
        gate_pixels: tracking gate in pixels of the pressure grid (converted to metres).
        rub_travel_pixels: travel of a rub in pixels of the pressure grid.
        pinch_closing: fraction by which two contacts' distance must shrink for a pinch.
        stretch_ratio_rub: stretch per pascal above which a single contact stretches the sheet
            like a rub or a pinch (only with a stretch layer), 1/Pa.
    """

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    calibration_s: float = 0.5
    baseline_tau_s: float = 5.0
    start_frames: int = 2
    end_hold_s: float = 0.1
    update_period_s: float = 0.1
    count_frames: int = 3
    gate_pixels: float = 8.0
    rub_travel_pixels: float = 4.0
    pinch_closing: float = 0.3
    stretch_ratio_rub: float = 3.0e-6

    def __post_init__(self) -> None:
        for name in ("calibration_s", "baseline_tau_s", "gate_pixels", "rub_travel_pixels"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("end_hold_s", "update_period_s", "stretch_ratio_rub"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.start_frames < 1 or self.count_frames < 1:
            raise ValueError("start_frames and count_frames must be >= 1")
        if not 0 < self.pinch_closing < 1:
            raise ValueError(f"pinch_closing must be in (0, 1), got {self.pinch_closing}")


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
        centroid_m: ``(x, y)`` mean of the current contact centroids (END: of the last ones), m.
        area_m2: total contact area, m^2.
        peak_pa: largest pressure of the current contacts, Pa.
        n_contacts: contacts in the frame.
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
    """What the rules look at (see module docstring); units m, 1/Pa."""

    count: int
    travel_m: float
    closing: float
    stretch_ratio: float | None


def decide(features: TouchFeatures, config: ClassifierConfig, pixel_m: float):
    """``(label, confidence)`` from the features by the rules of the module docstring.

    The confidence grows with the distance of the deciding feature from its threshold.
    """
    travel_threshold = config.rub_travel_pixels * pixel_m

    def margin(value: float, threshold: float) -> float:
        return 0.5 + 0.5 * math.tanh(abs(value - threshold) / max(threshold, 1e-12))

    if features.count >= 3:
        return "grab", min(1.0, 0.7 + 0.1 * (features.count - 2))
    if features.count == 2:
        if features.closing >= config.pinch_closing:
            return "pinch", margin(features.closing, config.pinch_closing)
        return "grab", margin(features.closing, config.pinch_closing)
    if features.travel_m >= travel_threshold:
        return "rub", margin(features.travel_m, travel_threshold)
    ratio = features.stretch_ratio
    if ratio is not None and config.stretch_ratio_rub > 0 and ratio >= config.stretch_ratio_rub:
        return "pinch", 0.5 * margin(ratio, config.stretch_ratio_rub)
    conf = margin(features.travel_m, travel_threshold)
    if ratio is not None and config.stretch_ratio_rub > 0:
        conf = min(conf, margin(ratio, config.stretch_ratio_rub))
    return "push", conf


class _Touch:
    """Evidence collected over one touch."""

    def __init__(self, touch_id: int, t_s: float) -> None:
        self.id = touch_id
        self.t_start_s = t_s
        self.t_last_s = t_s
        self.t_last_update_s = t_s
        self.counts: list[int] = []
        self.pair_first_m: float | None = None
        self.pair_min_m = math.inf
        self.pair_frames = 0
        self.merged = False
        self.max_pressure = 0.0
        self.max_stretch: float | None = None
        self.travel_m = 0.0
        self.last_contacts: list[Contact] = []
        self.missing = 0
        self.label = "push"
        self.confidence = 0.5

    def count(self, min_frames: int) -> int:
        if not self.counts:
            return 0
        counts = np.sort(np.asarray(self.counts))[::-1]
        return int(counts[min(min_frames, counts.size) - 1])


class TouchClassifier:
    """Stream of images -> touch events (see module docstring).

    Args:
        x: ``[W]`` pressure pixel-centre x, m.  y: ``[H]`` pixel-centre y, m.
        config: thresholds and timing.
        pressure_noise_pa: image noise; ``None``: estimated from the calibration frames.
        stretch_noise: stretch image noise (strain); ``None``: estimated likewise.
    """

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        config: ClassifierConfig | None = None,
        pressure_noise_pa: float | None = None,
        stretch_noise: float | None = None,
    ) -> None:
        self.x = np.asarray(x, dtype=np.float64)
        self.y = np.asarray(y, dtype=np.float64)
        self.config = config or ClassifierConfig()
        self.pixel_m = float(abs(self.x[1] - self.x[0]))
        self.pressure_noise_pa = pressure_noise_pa
        self.stretch_noise = stretch_noise
        self.segmenter: ContactSegmenter | None = None
        self.tracker = ContactTracker(self.config.gate_pixels * self.pixel_m, max_missed=2)
        self._calibration: list[np.ndarray] = []
        self._calibration_stretch: list[np.ndarray] = []
        self._t0: float | None = None
        self._t_prev: float | None = None
        self.baseline: np.ndarray | None = None
        self.stretch_baseline: np.ndarray | None = None
        self._run = 0
        self._run_start_s = 0.0
        self._touch: _Touch | None = None
        self._next_id = 1
        self.last_contacts: list[Contact] = []
        self.last_features: TouchFeatures | None = None
        self.frames = 0

    @property
    def calibrated(self) -> bool:
        return self.segmenter is not None

    @property
    def active(self) -> bool:
        """True while a touch is going on (between its START and END)."""
        return self._touch is not None

    # ------------------------------------------------------------------ calibration
    def _calibrate(self, t_s: float, pressure: np.ndarray, stretch: np.ndarray | None) -> None:
        if self._t0 is None:
            self._t0 = t_s
        self._calibration.append(pressure)
        if stretch is not None:
            self._calibration_stretch.append(stretch)
        if t_s - self._t0 + 1e-9 < self.config.calibration_s and len(self._calibration) < 10_000:
            return
        stack = np.stack(self._calibration)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels outside the sheet
            self.baseline = np.nanmedian(stack, axis=0)
        self.baseline = np.where(np.isfinite(self.baseline), self.baseline, 0.0)
        if self.pressure_noise_pa:
            sigma = self.pressure_noise_pa
        else:
            sigma = estimate_noise_map(stack) if len(stack) >= 3 else estimate_noise(stack)
            self.pressure_noise_pa = estimate_noise(stack)
        if self._calibration_stretch:
            s_stack = np.stack(self._calibration_stretch)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                s_base = np.nanmedian(s_stack, axis=0)
            self.stretch_baseline = np.where(np.isfinite(s_base), s_base, 0.0)
            if self.stretch_noise is None:
                self.stretch_noise = estimate_noise(s_stack)
        self.segmenter = ContactSegmenter(self.x, self.y, sigma, self.config.segmentation)
        self._calibration = []
        self._calibration_stretch = []

    # ------------------------------------------------------------------ stream
    def step(
        self, t_s: float, pressure: np.ndarray, stretch: np.ndarray | None = None
    ) -> list[TouchEvent]:
        """Process one frame (``pressure`` [H, W] Pa, ``stretch`` [H, W] or None); events."""
        pressure = np.asarray(pressure, dtype=np.float64)
        pressure = np.where(np.isfinite(pressure), pressure, np.nan)
        if stretch is not None:
            stretch = np.asarray(stretch, dtype=np.float64)
            stretch = np.where(np.isfinite(stretch), stretch, np.nan)
        self.frames += 1
        if self.segmenter is None:
            self._calibrate(t_s, pressure, stretch)
            self._t_prev = t_s
            self.last_contacts = []
            return []
        dt = max(t_s - (self._t_prev if self._t_prev is not None else t_s), 0.0)
        self._t_prev = t_s
        signal = pressure - self.baseline
        contacts = self.segmenter.segment(signal)
        self.last_contacts = contacts
        stretch_peak = None
        if stretch is not None and self.stretch_baseline is not None:
            s = stretch - self.stretch_baseline
            stretch_peak = float(np.nanmax(s)) if np.isfinite(s).any() else None
        if self._touch is None and not contacts:
            self._follow_baseline(dt, pressure, stretch)
        return self._advance(t_s, contacts, stretch_peak)

    def _follow_baseline(self, dt: float, pressure, stretch) -> None:
        alpha = 1.0 - math.exp(-dt / self.config.baseline_tau_s)
        ok = np.isfinite(pressure)
        self.baseline[ok] += alpha * (pressure[ok] - self.baseline[ok])
        if stretch is not None and self.stretch_baseline is not None:
            ok = np.isfinite(stretch)
            self.stretch_baseline[ok] += alpha * (stretch[ok] - self.stretch_baseline[ok])

    def _advance(self, t_s: float, contacts: list[Contact], stretch_peak) -> list[TouchEvent]:
        cfg = self.config
        touch = self._touch
        if touch is None:
            if not contacts:
                self._run = 0
                return []
            if self._run == 0:
                self._run_start_s = t_s
                self.tracker.reset()
            self._run += 1
            self._observe_contacts(None, t_s, contacts, stretch_peak)
            if self._run < cfg.start_frames:
                return []
            touch = self._touch = _Touch(self._next_id, self._run_start_s)
            self._next_id += 1
            self._run = 0
            self._observe_contacts(touch, t_s, contacts, stretch_peak, track=False)
            self._relabel(touch)
            return [self._event(touch, "start", t_s)]
        if not contacts:
            touch.missing += 1
            self.tracker.update(t_s, [])
            if t_s - touch.t_last_s >= cfg.end_hold_s - 1e-9:
                self._touch = None
                self._relabel(touch)
                return [self._event(touch, "end", t_s)]
            return []
        touch.missing = 0
        self._observe_contacts(touch, t_s, contacts, stretch_peak)
        if t_s - touch.t_last_update_s >= cfg.update_period_s - 1e-9:
            self._relabel(touch)
            touch.t_last_update_s = t_s
            return [self._event(touch, "update", t_s)]
        return []

    def finish(self, t_s: float | None = None) -> list[TouchEvent]:
        """End a touch still going on at the end of a stream (END at its last contact)."""
        touch = self._touch
        if touch is None:
            return []
        self._touch = None
        self._relabel(touch)
        return [self._event(touch, "end", touch.t_last_s if t_s is None else t_s)]

    # ------------------------------------------------------------------ features
    def _observe_contacts(self, touch, t_s, contacts, stretch_peak, track: bool = True) -> None:
        if track:
            self.tracker.update(t_s, contacts)
        if touch is None:
            return
        for tr in self.tracker.tracks:
            if tr.missed == 0 and tr.frames >= self.config.count_frames:
                path = np.asarray(tr.path)[:, 1:]
                anchor = np.median(path[: self.config.count_frames], axis=0)
                moved = float(np.linalg.norm(path[-1] - anchor))
                touch.travel_m = max(touch.travel_m, moved)
        touch.t_last_s = t_s
        touch.last_contacts = contacts
        touch.counts.append(len(contacts))
        top = max(c.peak for c in contacts)
        touch.max_pressure = max(touch.max_pressure, top)
        if stretch_peak is not None:
            touch.max_stretch = max(touch.max_stretch or 0.0, stretch_peak)
        if len(contacts) >= 2:
            a, b = np.asarray(contacts[0].centroid_m), np.asarray(contacts[1].centroid_m)
            d = float(np.linalg.norm(a - b))
            touch.pair_frames += 1
            if touch.pair_first_m is None:
                touch.pair_first_m = d
            touch.pair_min_m = min(touch.pair_min_m, d)
        elif touch.pair_frames >= self.config.count_frames and len(contacts) == 1:
            touch.merged = True

    def features(self, touch: _Touch) -> TouchFeatures:
        count = touch.count(self.config.count_frames)
        closing = 0.0
        if touch.pair_first_m:
            closing = 1.0 - touch.pair_min_m / touch.pair_first_m
            if touch.merged:
                closing = 1.0
        travel = touch.travel_m
        ratio = None
        if touch.max_stretch is not None and touch.max_pressure > 0:
            ratio = touch.max_stretch / touch.max_pressure
        if count >= 2 or touch.merged:
            count = max(count, 2)
        return TouchFeatures(max(count, 1), travel, closing, ratio)

    def _relabel(self, touch: _Touch) -> None:
        features = self.features(touch)
        self.last_features = features
        touch.label, touch.confidence = decide(features, self.config, self.pixel_m)

    def _event(self, touch: _Touch, state: str, t_s: float) -> TouchEvent:
        contacts = touch.last_contacts
        centroid = np.mean([c.centroid_m for c in contacts], axis=0) if contacts else np.zeros(2)
        return TouchEvent(
            touch_id=touch.id,
            state=state,
            label=touch.label,
            confidence=float(touch.confidence),
            t_s=float(t_s),
            t_start_s=float(touch.t_start_s),
            t_end_s=float(touch.t_last_s if state == "end" else t_s),
            centroid_m=(float(centroid[0]), float(centroid[1])),
            area_m2=float(sum(c.area_m2 for c in contacts)),
            peak_pa=float(max((c.peak for c in contacts), default=0.0)),
            n_contacts=len(contacts),
        )


def classify_stream(
    t_s: np.ndarray,
    pressure: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    stretch: np.ndarray | None = None,
    config: ClassifierConfig | None = None,
) -> list[TouchEvent]:
    """Every event of a whole recording: ``pressure`` ``[T, H, W]`` Pa, ``stretch`` likewise."""
    classifier = TouchClassifier(x, y, config)
    events: list[TouchEvent] = []
    for k in range(len(t_s)):
        events += classifier.step(
            float(t_s[k]), pressure[k], None if stretch is None else stretch[k]
        )
    events += classifier.finish()
    return events


def with_config(config: ClassifierConfig, **changes) -> ClassifierConfig:
    """A copy of ``config`` with top-level or ``segmentation`` fields changed by name."""
    seg_fields = set(SegmentationConfig.__dataclass_fields__)
    seg = {k: v for k, v in changes.items() if k in seg_fields}
    top = {k: v for k, v in changes.items() if k not in seg_fields}
    return replace(config, segmentation=replace(config.segmentation, **seg), **top)
