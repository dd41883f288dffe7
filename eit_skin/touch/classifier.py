"""Touches from a stream of reconstructed images: START / UPDATE / END events, labelled.

:class:`TouchClassifier` takes frames ``(t_s, pressure [H, W] Pa, stretch [H, W] strain or
None)`` and returns :class:`TouchEvent` records. Method (explainable rules on a few features,
see docs/classifier.md):

* calibration: the first ``calibration_s`` of frames are taken as no-touch; they give a
  per-pixel baseline and noise map, which then keep following slow drift and the noise
  (time constants ``baseline_tau_s``, ``noise_tau_s``) while nothing touches;
* contacts: hysteresis segmentation of the mean of the latest ``average_frames`` frames minus
  the baseline, at multiples of the noise (:class:`~eit_skin.touch.contacts.ContactSegmenter`);
* a touch starts once a contact stayed in place (one track) for ``start_frames`` frames, or
  earlier, once the image pooled over a fingertip-sized Gaussian kernel (``detect_kernel``
  single-finger spreads) stays above ``k_detect`` sigmas of ITS noise for ``start_frames``
  frames in the same place (:class:`~eit_skin.touch.contacts.PooledDetector`: a matched filter
  that sees weak, slowly pressed touches 50-100 ms before single pixels cross ``k_high``);
  it ends after ``end_hold_s`` without contact (a touch the pooled detector started ends
  after ``end_hold_s`` of silent pooled image, or after ``confirm_s`` if no contact has been
  segmented by then); all contacts on the patch belong to it;
* per frame, the blob's centroid and principal spreads (:func:`~eit_skin.touch.shapes.blob_moments`)
  over the contact pixels, in units of one fingertip's spread at that place
  (:func:`~eit_skin.touch.shapes.single_contact_spread`);
* features over the touch's strong frames: ``spread`` (median blob size), ``closing`` (largest
  relative narrowing of the major axis), ``travel`` (centroid travel);
* rules: ``closing >= pinch_closing`` -> pinch; ``spread >= grab_spread`` -> grab;
  ``travel >= rub_travel`` -> rub; a significant steady narrowing (``trend >= pinch_trend``
  and ``narrowing >= pinch_narrowing``) -> pinch; ``major >= grab_major`` (a long blob:
  fingers along an arc) -> grab; with the raw frames of the pressure layer, a pattern that
  changes steadily while the touch holds (``shape_z >= pinch_shape_z``,
  :mod:`~eit_skin.touch.frame_evidence`: a close pinch) -> pinch; else push.

The label of START is provisional (evidence of the first frames); UPDATEs carry the label on
the evidence so far and may revise it; END carries the final label.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from eit_skin.patch.model import Layer, Patch, PatchError
from eit_skin.touch.contacts import (
    LEARN_FRACTION,
    Contact,
    ContactSegmenter,
    ContactTracker,
    PooledDetector,
    SegmentationConfig,
    estimate_noise,
    estimate_noise_map,
    noise_sample_frames,
)
from eit_skin.touch.frame_evidence import (
    FrameEvidence,
    TouchFilter,
    electrode_roughness,
    shape_change_z,
)
from eit_skin.touch.shapes import BLOB_FRACTION, FINGER_RADIUS_M, blob_moments

_MAX_CALIBRATION_FRAMES = 10_000
"""Calibration ends after this many frames even if ``calibration_s`` has not passed (a
memory bound against stamps that do not advance)."""

FLICKER = 2.0
"""A sheet flickers when the median over its pixels of the raw image's second difference in
time, squared, exceeds this many times its noise variance (6 v for a pixel of raw noise
variance v): noise alone gives about 0.45 (the median of a chi-square with one degree of
freedom), smooth touches 0.4-1 (a ramp has no second difference), a degrading electrode's
channels 2-8 (median 6-7.5 over its first second on every patch, tuning seed)."""

ELECTRODE_FLICKER = 10.0
"""With raw frames, a flickering sheet counts as a fault's flicker only if, in that frame,
one electrode's channels are this much rougher than the others
(:func:`~eit_skin.touch.frame_evidence.electrode_roughness`: the ratio of median squared
second differences): sqrt(10) = 3.2 times in amplitude, the pipeline's own rule for a noisy
electrode (:func:`~eit_skin.inverse.electrode_faults.faulty_electrodes`). A degrading
electrode loud enough to make the sheet flicker (about 5x its noise and more) gives 19-106
(tuning seed, every patch); noise and touches spread over the sheet 1-4, a palm's onset up to
7 on the arm; the onset of a touch next to an electrode can exceed it, and then waits as
before. Otherwise the flicker is the touch's own and delays nothing (issue 18: an arm palm
grab's START 100 -> 40 ms)."""

LABELS = ("push", "rub", "pinch", "grab")
"""Touch labels, in the order of ``eit_skin_msgs/TouchEvent`` (PUSH=0 ... GRAB=3)."""
STATES = ("start", "update", "end")
"""Event states, in the order of ``eit_skin_msgs/TouchEvent`` (START=0, UPDATE=1, END=2)."""


def classifier_layers(patch: Patch) -> tuple[Layer, Layer | None]:
    """The layers the classifier reads: ``(pressure layer, stretch layer or None)``.

    Chosen by material quantity, whatever the layers are called: the first layer (in the
    patch file's order) that measures pressure, and the first that measures stretch, if any.
    Further layers of the same quantity are not classified.

    Raises:
        PatchError: no layer measures pressure (naming the file and every layer's quantity).
    """
    first = {}
    for layer in patch.layers:
        first.setdefault(layer.material.quantity, layer)
    if "pressure" not in first:
        quantities = ", ".join(f"{ly.name}: {ly.material.quantity}" for ly in patch.layers)
        raise PatchError(
            patch.source,
            "layers",
            f"no layer measures pressure ({quantities}); the touch classifier needs one",
        )
    return first["pressure"], first.get("stretch")


@dataclass(frozen=True)
class ClassifierConfig:
    """Thresholds and timing of the touch classifier.

    Spreads are measured in units of the spread one fingertip gives at the same place
    (:func:`~eit_skin.touch.shapes.single_contact_spread`), so the rules do not depend on the
    patch's size, electrode layout or reconstruction prior.

    Attributes:
        segmentation: contact thresholds in noise units (see :class:`SegmentationConfig`).
        calibration_s: initial no-touch time used to estimate noise and baseline, s.
        baseline_tau_s: time constant of the drift-following baseline (idle frames only), s.
        start_frames: consecutive frames with a contact (or a pooled detection) in the same
            place before START.
        average_frames: contacts are found in the mean of the latest this many frames (noise
            down by its square root, at half a frame period of delay per extra frame).
        noise_tau_s: time constant of the per-pixel noise estimate, which keeps learning from
            no-touch frames after calibration, s (0: keep the calibration estimate).
        end_hold_s: time without contact before END, s.
        update_period_s: shortest time between UPDATEs of one touch, s.
        count_frames: frames a contact count must be seen to count.
        gate_pixels: tracking gate in pixels of the pressure grid (converted to metres).
        strong_fraction: frames whose peak is below this fraction of the touch's largest peak
            (press and release ramps) do not enter the shape features.
        rub_travel: centroid travel that makes a rub, in single-finger spreads.
        pinch_closing: relative narrowing of the blob's major axis that makes a pinch (0..1).
        pinch_trend: a still touch (not a grab, not a rub) whose major axis shrinks with a
            least-squares slope this many standard errors from zero (a t-statistic, i.e. in
            units of the frame-to-frame scatter of the shape) is a pinch too: a close pinch
            narrows its blob by only 5-15 % of a finger spread, too little for
            ``pinch_closing`` but steadily over its closing (issue 18).
        pinch_narrowing: ... and only if that fitted narrowing over the strong frames is at
            least this many single-finger spreads (a long press's negligible creep is no pinch).
        pinch_shape_z: a still touch (after every grab and rub rule) whose raw boundary
            frames change their pattern steadily over its plateau, beyond what its
            amplitude, its centroid's motion and a sheet-wide drift explain, with a
            z-score of at least this (noise standard units,
            :func:`~eit_skin.touch.frame_evidence.shape_change_z`) is a pinch: a close
            pinch's closing, too small for the image shape (issue 18). Needs the raw
            frames of the pressure layer (``volts`` in :meth:`TouchClassifier.step`);
            0 disables.
        travel_fraction: frames whose peak is at least this fraction of the touch's largest
            enter ``travel`` (a quarter: the whole stroke, press and release included).
        grab_spread: blob spread (geometric mean of the principal spreads) that makes a grab,
            in single-finger spreads.
        grab_major: a still touch (not a pinch or rub by the rules before) whose blob's major
            spread (median) is at least this many single-finger spreads is a grab too: 3-5
            fingers bunched along an arc make a long, narrow blob whose geometric-mean
            ``spread`` stays under ``grab_spread`` (issue 18: uneven grabs).
        contact_spread_m: spread of one fingertip's image, m, used when the classifier is
            given no per-pixel map.
        stretch_ratio_rub: stretch per pascal above which a single still contact is a pinch
            whose fingers cannot be told apart (only with a stretch layer), 1/Pa; 0 disables.
        detect_kernel: standard deviation of the Gaussian kernel of the early START detector
            (:class:`~eit_skin.touch.contacts.PooledDetector`), in single-finger spreads (median of
            the map over the sheet); about the width of one fingertip's whole reconstructed
            blob. 0 disables it (START on segmented contacts only).
        k_detect: threshold of the pooled image, multiples of the pooled image's own noise
            (estimated like the image noise from the calibration frames, then learnt).
        confirm_s: a touch started by the pooled detector with no segmented contact after
            this time ends (then the detector waits for a silent pooled image), s.
        learn_fraction: pooled images with a z-score above ``learn_fraction * k_detect``
            anywhere (a touch building up) teach neither noise map (0..1].
        noise_window: side, in pixels, of the neighbourhood mean in the calibration noise
            map; each pixel takes the larger of that mean and its own estimate.
        noise_floor_fraction: the learnt per-pixel noise never drops below this fraction of
            the calibration frames' overall noise.
        track_missed_frames: frames a contact track may go unseen before it is dropped.
        lookback_frames: frame times and blob shapes kept while no touch goes on: a START
            is dated, and its shape evidence collected, at most this many frames back.
        blob_fraction: pixels weigh in the blob moments by how far they exceed this fraction
            of the frame's peak (:func:`~eit_skin.touch.shapes.blob_moments`); the
            single-finger spread map must be computed with the same value.
        finger_radius_m: radius of the fingertip-sized disc whose reconstructed image defines
            the single-finger spread (:func:`~eit_skin.touch.shapes.single_contact_spread`;
            used where that map is computed), m.
        closing_window: frames of the rolling median over the blob's major axis before its
            narrowing (``closing``) is measured, and over its centroid path before ``travel``
            is (against single noisy frames).
        confidence_gain: slope of the confidence ``0.5 + 0.5 tanh(gain |f - t| / t)`` of a
            feature ``f`` deciding against its threshold ``t``.
        offset_margin: pixels within this many single-finger spreads (median over the sheet)
            of the previous frame's contacts are left out of the sheet-wide offset (the median
            of the baseline-free image over the rest of the sheet, removed from every image
            after calibration before segmentation).
        offset_deadband: only the part of that offset beyond this many noise sigmas (median
            of the noise map) is removed: a smaller one moves no pixel across the contact
            thresholds by itself, and is mostly the touch's own tails and ringing.
        fault_radius: an event whose centroid lies within this many single-finger spreads of a
            faulty electrode has its confidence multiplied by ``fault_confidence``.
        fault_confidence: confidence factor near a faulty electrode, (0, 1].
        start_roughness: while the whole sheet flickers (:data:`FLICKER`, in any of a touch
            candidate's frames: a degrading electrode's noise before the pipeline's
            fault check names it), a candidate STARTs only if its raw image changes by less
            than this fraction of itself (:meth:`TouchClassifier._follow_roughness`). Noise
            gives at least 1, a press, release or stroke a fraction. 0 disables the check
            (issue 18).
    """

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    calibration_s: float = 0.5
    baseline_tau_s: float = 5.0
    start_frames: int = 2
    average_frames: int = 2
    noise_tau_s: float = 10.0
    end_hold_s: float = 0.1
    update_period_s: float = 0.1
    count_frames: int = 3
    gate_pixels: float = 8.0
    strong_fraction: float = 0.5
    rub_travel: float = 1.15
    pinch_closing: float = 0.3
    pinch_trend: float = 3.0
    pinch_narrowing: float = 0.05
    pinch_shape_z: float = 5.0
    travel_fraction: float = 0.25
    grab_spread: float = 1.35
    grab_major: float = 1.45
    contact_spread_m: float = 0.005
    stretch_ratio_rub: float = 0.0
    detect_kernel: float = 2.5
    k_detect: float = 5.5
    confirm_s: float = 0.5
    learn_fraction: float = LEARN_FRACTION
    noise_window: int = 3
    noise_floor_fraction: float = 0.5
    track_missed_frames: int = 2
    lookback_frames: int = 50
    blob_fraction: float = BLOB_FRACTION
    finger_radius_m: float = FINGER_RADIUS_M
    closing_window: int = 5
    confidence_gain: float = 2.0
    offset_margin: float = 2.0
    offset_deadband: float = 1.0
    fault_radius: float = 2.0
    fault_confidence: float = 0.5
    start_roughness: float = 0.5

    def __post_init__(self) -> None:
        for name in (
            "calibration_s",
            "baseline_tau_s",
            "gate_pixels",
            "rub_travel",
            "grab_spread",
            "grab_major",
            "pinch_trend",
            "contact_spread_m",
            "k_detect",
            "confirm_s",
            "finger_radius_m",
            "confidence_gain",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in (
            "end_hold_s",
            "update_period_s",
            "stretch_ratio_rub",
            "noise_tau_s",
            "detect_kernel",
            "noise_floor_fraction",
            "track_missed_frames",
            "offset_margin",
            "offset_deadband",
            "fault_radius",
            "pinch_narrowing",
            "pinch_shape_z",
            "start_roughness",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in (
            "start_frames",
            "count_frames",
            "average_frames",
            "noise_window",
            "lookback_frames",
            "closing_window",
        ):
            if not getattr(self, name) >= 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 < self.pinch_closing < 1:
            raise ValueError(f"pinch_closing must be in (0, 1), got {self.pinch_closing}")
        if not 0 <= self.strong_fraction < 1:
            raise ValueError(f"strong_fraction must be in [0, 1), got {self.strong_fraction}")
        if not 0 <= self.travel_fraction < 1:
            raise ValueError(f"travel_fraction must be in [0, 1), got {self.travel_fraction}")
        if not 0 <= self.blob_fraction < 1:
            raise ValueError(f"blob_fraction must be in [0, 1), got {self.blob_fraction}")
        if not 0 < self.learn_fraction <= 1:
            raise ValueError(f"learn_fraction must be in (0, 1], got {self.learn_fraction}")
        if not 0 < self.fault_confidence <= 1:
            raise ValueError(f"fault_confidence must be in (0, 1], got {self.fault_confidence}")


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


class _Touch:
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
        self.detect_centroid_m = (0.0, 0.0)
        self.changes: list[np.ndarray | None] = []  # whitened raw frame per shape record

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


class TouchClassifier:
    """Stream of images -> touch events (see module docstring).

    Args:
        x: ``[W]`` pressure pixel-centre x, m.  y: ``[H]`` pixel-centre y, m.
        config: thresholds and timing.
        pressure_noise_pa: image noise; ``None``: estimated from the calibration frames.
        stretch_noise: stretch image noise (strain); ``None``: estimated likewise.
        contact_spread_m: spread of one fingertip's image, m: a ``[H, W]`` map
            (:func:`~eit_skin.touch.shapes.single_contact_spread`) or a scalar; ``None``:
            ``config.contact_spread_m``.
        electrodes_m: ``[E, 2]`` electrode centres of the pressure layer, m (patch frame), so
            that :meth:`set_faulty_electrodes` can place them; ``None``: no fault handling.
        channel_electrodes: ``[M, E]`` bool, the electrodes each raw channel of the pressure
            layer uses (:func:`~eit_skin.touch.frame_evidence.channel_electrodes`), so that a
            faulty electrode's channels stay out of ``shape_z``; ``None``: all channels stay.
        disc_rel: ``[H, W, M]`` relative change of every raw channel for a fingertip on
            each pixel (:func:`~eit_skin.touch.shapes.disc_patterns`). With it, a raw frame
            with every calibration frame and ``channel_electrodes`` (its fault test needs
            them), a touch also STARTs from the raw frames' filter
            (:class:`~eit_skin.touch.frame_evidence.TouchFilter`, in its own
            :class:`~eit_skin.touch.contacts.PooledDetector`: :attr:`start_detector`);
            ``None``: from the pooled image alone.
        contact_rel: ``[M, E]`` relative change of every raw channel per change of each
            electrode's contact impedance (:func:`~eit_skin.pipeline.builder.contact_patterns`),
            projected out of that filter; ``None``: only the drift is.
    """

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        config: ClassifierConfig | None = None,
        pressure_noise_pa: float | None = None,
        stretch_noise: float | None = None,
        contact_spread_m: float | np.ndarray | None = None,
        electrodes_m: np.ndarray | None = None,
        channel_electrodes: np.ndarray | None = None,
        disc_rel: np.ndarray | None = None,
        contact_rel: np.ndarray | None = None,
    ) -> None:
        self.x = np.asarray(x, dtype=np.float64)
        self.y = np.asarray(y, dtype=np.float64)
        self.config = config or ClassifierConfig()
        self.pixel_m = float(abs(self.x[1] - self.x[0]))
        self.pressure_noise_pa = pressure_noise_pa
        self.stretch_noise = stretch_noise
        self.segmenter: ContactSegmenter | None = None
        self._xx, self._yy = np.meshgrid(self.x, self.y)
        spread = self.config.contact_spread_m if contact_spread_m is None else contact_spread_m
        spread = np.broadcast_to(np.asarray(spread, dtype=np.float64), self._xx.shape)
        if not (np.all(np.isfinite(spread)) and np.all(spread > 0)):
            raise ValueError(
                f"contact_spread_m: a finite, positive scalar or [H, W] = {self._xx.shape} map"
            )
        self.contact_spread_m = spread
        self.tracker = ContactTracker(
            self.config.gate_pixels * self.pixel_m, max_missed=self.config.track_missed_frames
        )
        self._calibration: list[np.ndarray] = []
        self._calibration_stretch: list[np.ndarray] = []
        self._calibration_volts: list[np.ndarray] = []
        self.evidence = FrameEvidence(channel_electrodes)
        if disc_rel is not None and np.shape(disc_rel)[:2] != self._xx.shape:
            raise ValueError(
                f"disc_rel: [H, W, M] with [H, W] = {self._xx.shape}, got {np.shape(disc_rel)}"
            )
        self._disc_rel = disc_rel
        self._contact_rel = contact_rel
        self.touch_filter: TouchFilter | None = None  # set at calibration (raw frames given)
        self._change: np.ndarray | None = None  # the latest frame's whitened raw change
        self._run_changes: list[np.ndarray | None] = []  # beside _run_shapes
        self._t0: float | None = None
        self._t_prev: float | None = None
        self.baseline: np.ndarray | None = None
        self.stretch_baseline: np.ndarray | None = None
        self._run = 0
        self._run_shapes: list[np.ndarray] = []  # 0-d SHAPE_DTYPE records before a START
        self._recent: list[np.ndarray] = []
        self._noise_var: np.ndarray | None = None
        self._noise_floor = 0.0
        self._touch: _Touch | None = None
        self.detector: PooledDetector | None = None
        # START from the raw frames' filter (``disc_rel`` and raw frames given), else None
        self.start_detector: PooledDetector | None = None
        self._armed = True
        self._start_armed = True
        self._start_fresh = False  # the filter's map is of this frame
        self._times: list[float] = []
        self._next_id = 1
        self.last_contacts: list[Contact] = []
        self.last_features: TouchFeatures | None = None
        self.frames = 0
        self._touched = np.zeros(self._xx.shape, dtype=bool)  # last contacts, grown
        unit_px = float(np.median(spread)) / self.pixel_m
        self._margin_px = max(round(self.config.offset_margin * unit_px), 0)
        self.electrodes_m = None if electrodes_m is None else np.asarray(electrodes_m, float)
        if self.electrodes_m is not None and (
            self.electrodes_m.ndim != 2 or self.electrodes_m.shape[1] != 2
        ):
            raise ValueError(f"electrodes_m: [E, 2] m, got shape {self.electrodes_m.shape}")
        self.faulty: tuple[int, ...] = ()
        self._noise_samples = 1.0  # independent frames behind the noise map
        self._sample_frames = float(self.config.average_frames)  # frames per such sample
        self._strong = False  # a contact of the latest frame stands out of the noise estimate
        self._raws: list[np.ndarray] = []  # the latest average_frames + 1 raw frames
        self._whites: list[np.ndarray] = []  # the latest 3 whitened raw frames (volts given)
        self._rough: list[tuple[float, float, float]] = []  # per candidate frame
        self._flicker = 0.0  # the sheet's flicker in the latest frame it was computed for

    # ------------------------------------------------------------------ electrode faults
    def set_faulty_electrodes(self, electrodes) -> None:
        """The electrodes the imaging now leaves out (``LayerProcessor.faulty_electrodes``).

        Events whose centroid lies within ``fault_radius`` single-finger spreads of a faulty
        electrode carry ``fault_confidence`` times their confidence. Nothing else changes:
        calibrating again on a change (and ending the touch going on) was tried and made
        things worse on the tuning scenes: the pipeline's fault check also flags, for a
        second, an electrode next to which a touch presses, and a calibration taken during
        a touch learns the touch into the baseline (a stuck touch); the sheet-wide offset
        removal already absorbs most of the image's offset change.

        Raises:
            ValueError: an index out of range, or faulty electrodes without ``electrodes_m``.
        """
        faulty = tuple(sorted({int(e) for e in np.atleast_1d(electrodes).tolist()}))
        if faulty and self.electrodes_m is None:
            raise ValueError("faulty electrodes given, but the classifier has no electrodes_m")
        if faulty and not (faulty[0] >= 0 and faulty[-1] < len(self.electrodes_m)):
            raise ValueError(f"faulty electrodes out of range 0..{len(self.electrodes_m) - 1}")
        self.faulty = faulty

    def near_fault(self, point_m) -> bool:
        """Whether ``(x, y)`` m is within ``fault_radius`` finger spreads of a faulty electrode."""
        if not self.faulty or self.electrodes_m is None:
            return False
        d = np.linalg.norm(self.electrodes_m[list(self.faulty)] - np.asarray(point_m), axis=1)
        unit = float(np.median(self.contact_spread_m))
        return bool(d.min() <= self.config.fault_radius * unit)

    @property
    def calibrated(self) -> bool:
        return self.segmenter is not None

    @property
    def active(self) -> bool:
        """True while a touch is going on (between its START and END)."""
        return self._touch is not None

    # ------------------------------------------------------------------ calibration
    def _calibrate(
        self, t_s: float, pressure: np.ndarray, stretch: np.ndarray | None, volts=None
    ) -> None:
        if self._t0 is None:
            self._t0 = t_s
        self._calibration.append(pressure)
        if stretch is not None:
            self._calibration_stretch.append(stretch)
        if volts is not None:
            self._calibration_volts.append(volts)
        if (
            t_s - self._t0 + 1e-9 < self.config.calibration_s
            and len(self._calibration) < _MAX_CALIBRATION_FRAMES
        ):
            return
        stack = np.stack(self._calibration)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels outside the sheet
            self.baseline = np.nanmedian(stack, axis=0)
        self.baseline = np.where(np.isfinite(self.baseline), self.baseline, 0.0)
        n_avg = min(self.config.average_frames, len(stack))
        self._recent = list(stack[len(stack) - n_avg + 1 :]) if n_avg > 1 else []
        averaged = _running_mean(stack, n_avg)  # what the segmentation will look at
        if self.pressure_noise_pa:
            sigma = self.pressure_noise_pa / math.sqrt(n_avg)
        else:
            self.pressure_noise_pa = estimate_noise(stack)
            if len(averaged) >= 3:
                # conservative start (few frames): the larger of the smoothed map and each
                # pixel's own spread; then the noise keeps being learnt (_follow_noise)
                sigma = np.maximum(
                    estimate_noise_map(averaged, window=self.config.noise_window),
                    estimate_noise_map(averaged, window=1),
                )
                self._noise_var = sigma**2
                self._noise_floor = self.config.noise_floor_fraction * estimate_noise(averaged)
                self._sample_frames = noise_sample_frames(averaged - self.baseline, n_avg)
                self._noise_samples = len(averaged) / self._sample_frames
            else:
                sigma = estimate_noise(averaged)
        if self._calibration_stretch:
            s_stack = np.stack(self._calibration_stretch)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                s_base = np.nanmedian(s_stack, axis=0)
            self.stretch_baseline = np.where(np.isfinite(s_base), s_base, 0.0)
            if self.stretch_noise is None:
                self.stretch_noise = estimate_noise(s_stack)
        self.segmenter = ContactSegmenter(self.x, self.y, sigma, self.config.segmentation)
        inside = np.isfinite(stack).any(axis=0)
        if len(self._calibration_volts) >= 3:
            self.evidence.calibrate(np.stack(self._calibration_volts))
        if self.config.detect_kernel > 0 and len(averaged) >= 3 and inside.any():
            finger_m = float(np.median(self.contact_spread_m[inside]))
            kernel_px = self.config.detect_kernel * finger_m / self.pixel_m
            self.detector = PooledDetector(
                inside, kernel_px, self.config.k_detect, n_avg, self.config.learn_fraction
            )
            self.detector.calibrate(averaged - self.baseline)
            volts = np.stack(self._calibration_volts) if self._calibration_volts else None
            if self._disc_rel is not None and volts is not None and len(volts) == len(stack):
                # every calibration image came with its raw frame: START from their filter
                self.touch_filter = TouchFilter(self._disc_rel, inside, self._contact_rel)
                self.start_detector = PooledDetector(
                    inside, kernel_px, self.config.k_detect, n_avg, self.config.learn_fraction
                )
                changes = _running_mean(self.evidence.whiten(volts), n_avg)
                self.start_detector.calibrate_pooled(self._filtered(changes))
        self._calibration = []
        self._calibration_stretch = []
        self._calibration_volts = []

    # ------------------------------------------------------------------ stream
    def step(
        self,
        t_s: float,
        pressure: np.ndarray,
        stretch: np.ndarray | None = None,
        volts: np.ndarray | None = None,
    ) -> list[TouchEvent]:
        """Process one frame; its events.

        Args:
            t_s: frame time, s.
            pressure: ``[H, W]`` pressure image, Pa (NaN outside the sheet).
            stretch: ``[H, W]`` stretch image (strain) or None.
            volts: ``[M]`` the raw frame of the pressure layer this image was made from, V
                (NaN: channel missing), or None; given with the calibration frames and then
                with every frame, it feeds ``shape_z`` (a frame without it is left out).
        """
        if volts is not None:
            volts = np.asarray(volts, dtype=np.float64)
        pressure = np.asarray(pressure, dtype=np.float64)
        pressure = np.where(np.isfinite(pressure), pressure, np.nan)
        if stretch is not None:
            stretch = np.asarray(stretch, dtype=np.float64)
            stretch = np.where(np.isfinite(stretch), stretch, np.nan)
        self.frames += 1
        if self.segmenter is None:
            self._calibrate(t_s, pressure, stretch, volts)
            self._t_prev = t_s
            self._raws = [*self._raws[-self.config.average_frames :], pressure]
            self.last_contacts = []
            return []
        dt = max(t_s - (self._t_prev if self._t_prev is not None else t_s), 0.0)
        self._t_prev = t_s
        self._change = self.evidence.whiten(volts)
        self._whites = [] if self._change is None else [*self._whites[-2:], self._change]
        self._recent = [*self._recent[-(self.config.average_frames - 1) :], pressure]
        if self.config.average_frames == 1:
            self._recent = [pressure]
        signal = np.mean(self._recent, axis=0) - self.baseline
        offset = self._sheet_offset(signal)
        signal = signal - offset
        self._raws = [*self._raws[-self.config.average_frames :], pressure]
        self._times = [*self._times[-self.config.lookback_frames :], t_s]
        detected = None  # time of the first frame of a pooled detection, if there is one
        if self.detector is not None:
            # the rising-press credit assumes the calibrated noise: not with an electrode
            # left out of the images, nor after a frame in which the sheet flickered
            self.detector.rising = not self.faulty and self._flicker < FLICKER
            run = self.detector.update(signal)
            self._armed = self._armed or not self.detector.hit
            run = run if self._armed else 0  # after an END, until the image fell silent
            start = self.start_detector
            n = 0 if start is None else start.frames_per_sample
            # a running mean of n raw frames, as calibrated (none yet: the image decides)
            self._start_fresh = start is not None and len(self._whites) >= n
            if self._start_fresh:
                start.rising = self.detector.rising
                change = np.mean(self._whites[-n:], axis=0)
                change[~self.evidence.usable(self.faulty)] = np.nan
                filtered = start.update_pooled(self._filtered(change))
                self._start_armed = self._start_armed or not start.hit
                # an electrode's channels flickering like a fault START nothing
                if self._start_armed and not (len(self._whites) >= 3 and self._fault_like()):
                    run = max(run, filtered)
            if run >= self.config.start_frames:
                detected = self._times[-min(run, len(self._times))]
        contacts, parts = self.segmenter.segment_with_labels(signal)
        self.last_contacts = contacts
        if self._touch is None:
            self._strong = bool(contacts) and self._stands_out(signal, parts > 0)
            self._follow_roughness(pressure, offset, parts > 0, bool(contacts))
        self._touched = parts > 0
        if self._margin_px and contacts:
            self._touched = ndimage.binary_dilation(self._touched, iterations=self._margin_px)
        stretch_peak = None
        if stretch is not None and self.stretch_baseline is not None:
            s = stretch - self.stretch_baseline
            stretch_peak = float(np.nanmax(s)) if np.isfinite(s).any() else None
        shape = None
        if contacts:
            shape = self._shape(t_s, signal, parts > 0)
        else:
            self._run_shapes = []
            self._run_changes = []
            if self._touch is None:
                self._follow_baseline(dt, pressure, stretch)
                self._follow_noise(dt, signal)
                if volts is not None:
                    self.evidence.follow(1.0 - math.exp(-dt / self.config.baseline_tau_s), volts)
        return self._advance(t_s, contacts, stretch_peak, shape, detected)

    def _filtered(self, change: np.ndarray) -> np.ndarray:
        """The raw frames' matched-filter maps ``[..., H, W]`` of whitened changes ``[..., M]``."""
        return self.touch_filter.statistic(change, self.evidence.sigma, self.evidence.reference)

    def _sheet_offset(self, image: np.ndarray) -> float:
        """Sheet-wide offset of a baseline-free ``image`` ``[H, W]``: its median away from touch.

        sigma0 drifts with temperature and humidity over the whole sheet; while touches go on
        back to back the baseline cannot follow it, and a few tenths of a per cent leave most
        of the sheet several noise sigmas "in contact". A touch covers far less than half of
        the rest of the sheet, so the median over the pixels away from the previous frame's
        contacts (``offset_margin`` finger spreads) is that offset; over the whole sheet if
        the contacts leave less than a quarter of it.
        """
        ok = np.isfinite(image)
        free = ok & ~self._touched
        if np.count_nonzero(free) < 0.25 * np.count_nonzero(ok):
            free = ok
        if not free.any():
            return 0.0
        offset = float(np.median(image[free]))
        # an offset within the dead band moves no pixel across the contact thresholds by
        # itself; leaving it keeps the touch's own tails and ringing where they were
        band = self.config.offset_deadband * float(np.median(self.segmenter.noise_sigma))
        return math.copysign(max(abs(offset) - band, 0.0), offset)

    def _stands_out(self, signal: np.ndarray, mask: np.ndarray) -> bool:
        """Whether a contact pixel of ``signal`` ``[H, W]`` (``mask``) clears the START bar.

        The per-pixel noise map comes from few frames (0.5 s of calibration: ~12 independent
        averaged frames), and a pixel's estimate can be half its true noise; then a 3-sigma
        excursion over two frames reads 6 sigma and makes a contact. A contact STARTs a touch
        only if it exceeds ``k_high`` by the estimate's uncertainty as well, ``1 + sqrt(2 /
        n)`` for ``n`` independent frames behind it (x1.41 after calibration, x1.06 after
        ~20 s of learning), the inflation of the pooled detector's noise. Segmentation and
        shapes keep the plain map.
        """
        if self._noise_var is None:
            return True
        inflation = 1.0 + math.sqrt(2.0 / max(self._noise_samples, 1.0))
        bar = self.config.segmentation.k_high * inflation
        with np.errstate(invalid="ignore", divide="ignore"):
            z = signal[mask] / self.segmenter.noise_sigma[mask]
        return bool(np.any(z >= bar))

    def _follow_roughness(
        self, pressure: np.ndarray, offset: float, mask: np.ndarray, contacts: bool
    ) -> None:
        """Sheet flicker and a touch candidate's roughness from the latest raw frame.

        Raw frames ``p`` ``[H, W]``, per-pixel raw noise variance ``v`` (the averaged map's
        times ``average_frames``). **Flicker**: the median over the sheet of ``(p_k -
        2 p_(k-1) + p_(k-2))^2 / (6 v)`` (:data:`FLICKER`; a touch covers less than half of
        the sheet, and its smooth ramps have little second difference).
        **Roughness** of a candidate (the contact pixels, or the pooled detector's hits before
        any contact), summed over its frames: ``sum (p_k - p_(k-n))^2 - 2 v`` against ``sum
        (p_k - baseline - offset)^2 - v``, ``n = average_frames``: ``p_(k-n)`` is the frame
        just before those the contacts were segmented in, independent of that selection, so
        noise gives at least 1 however it was selected; a press, release or stroke changes
        by a fraction of itself.
        """
        cfg = self.config
        if cfg.start_roughness <= 0 or self._noise_var is None:
            return
        if len(self._raws) <= cfg.average_frames:
            return
        var = self.segmenter.noise_sigma**2 * cfg.average_frames
        bend = pressure - 2.0 * self._raws[-2] + self._raws[-3]  # second difference in time
        ok = np.isfinite(bend)
        flicker = float(np.median(bend[ok] ** 2 / (6.0 * var[ok]))) if ok.any() else 0.0
        if flicker >= FLICKER and not self._fault_like():
            flicker = 0.0  # the raw frames name no electrode: the touch's own onset
        self._flicker = flicker
        hits = self.detector is not None and self.detector.hit
        if not contacts and not hits:
            self._rough = []
            return
        if not contacts:
            mask = self.detector.z > self.detector.k
        before = self._raws[0]
        ok = mask & np.isfinite(pressure) & np.isfinite(before)
        if not ok.any():
            return
        noise = float(np.sum(var[ok]))
        change = float(np.sum((pressure[ok] - before[ok]) ** 2)) - 2.0 * noise
        level = float(np.sum((pressure[ok] - self.baseline[ok] - offset) ** 2)) - noise
        self._rough = [*self._rough[-cfg.lookback_frames :], (change, level, flicker)]

    def _fault_like(self) -> bool:
        """Whether the latest raw frames flicker like a fault (:data:`ELECTRODE_FLICKER`).

        True without three raw frames: every flicker counts then.
        """
        channels = self.evidence.channel_electrodes
        if len(self._whites) < 3 or channels is None:
            return True
        w = self._whites
        bend = w[-1] - 2.0 * w[-2] + w[-3]
        bend[~self.evidence.usable(self.faulty)] = np.nan
        return not electrode_roughness(bend, channels) < ELECTRODE_FLICKER

    def _smooth_enough(self) -> bool:
        """No START while the sheet flickers and the candidate is as rough as noise."""
        limit = self.config.start_roughness
        if limit <= 0 or not self._rough:
            return True
        change, level, _ = np.sum(self._rough, axis=0)
        # the largest over the candidate's frames: a fault's first frame is one noisy frame
        # of the three in its second difference (a sixth of the flicker of the next ones)
        if max(r[2] for r in self._rough) < FLICKER:
            return True
        return bool(change < limit * level)

    def _shape(self, t_s: float, signal: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """This frame's blob shape: a 0-d :data:`SHAPE_DTYPE` record."""
        peak, x, y, major, minor, _ = blob_moments(
            signal, self._xx, self._yy, self.config.blob_fraction, mask
        )
        finger = np.nan
        if np.isfinite(x) and np.isfinite(y):
            j = int(np.clip(np.searchsorted(self.x, x), 0, self.x.size - 1))
            i = int(np.clip(np.searchsorted(self.y, y), 0, self.y.size - 1))
            finger = self.contact_spread_m[i, j]
        return np.array((t_s, peak, x, y, major, minor, finger), dtype=SHAPE_DTYPE)

    def _follow_noise(self, dt: float, signal: np.ndarray) -> None:
        """Per-pixel noise variance: exponential average of no-touch deviations squared.

        The short calibration cannot see every pixel's noise well (a noisy spot next to an
        electrode averaged with its quieter neighbours); this keeps learning it.
        """
        if self.config.noise_tau_s <= 0:
            return
        alpha = 1.0 - math.exp(-dt / self.config.noise_tau_s)
        if alpha <= 0.0:  # no time passed (two boards' images with one stamp): nothing to learn
            return
        if self.detector is not None:
            if not self.detector.quiet:  # possibly a weak touch building up: not noise
                return
            self.detector.follow_noise(alpha)
            start = self.start_detector
            if start is not None and self._start_fresh and start.quiet:  # its map quiet too
                start.follow_noise(alpha)
        if self._noise_var is None:
            return
        ok = np.isfinite(signal)
        self._noise_var[ok] += alpha * (signal[ok] ** 2 - self._noise_var[ok])
        self.segmenter.noise_sigma = np.maximum(np.sqrt(self._noise_var), self._noise_floor)
        step = 1.0 / self._sample_frames  # independent samples this frame adds
        self._noise_samples = min(self._noise_samples + step, max(2.0 * step / alpha, 1.0))

    def _follow_baseline(self, dt: float, pressure, stretch) -> None:
        alpha = 1.0 - math.exp(-dt / self.config.baseline_tau_s)
        ok = np.isfinite(pressure)
        self.baseline[ok] += alpha * (pressure[ok] - self.baseline[ok])
        if stretch is not None and self.stretch_baseline is not None:
            ok = np.isfinite(stretch)
            self.stretch_baseline[ok] += alpha * (stretch[ok] - self.stretch_baseline[ok])

    def _advance(
        self, t_s: float, contacts: list[Contact], stretch_peak, shape, detected=None
    ) -> list[TouchEvent]:
        cfg = self.config
        touch = self._touch
        if touch is None:
            starts = [] if detected is None else [detected]
            if contacts:
                if self._run == 0:
                    self.tracker.reset()
                self._run += 1
                self._run_shapes = [*self._run_shapes[-cfg.lookback_frames :], shape]
                self._run_changes = [*self._run_changes[-cfg.lookback_frames :], self._change]
                self._observe_contacts(None, t_s, contacts, stretch_peak)
                # a contact must stay in place (one track) for start_frames frames: noise
                # crossing the threshold at random places in consecutive frames is no touch
                if self._strong:
                    starts += [
                        tr.first_seen_s
                        for tr in self.tracker.tracks
                        if tr.missed == 0 and tr.frames >= cfg.start_frames
                    ]
            else:
                self._run = 0
            if not starts or not self._smooth_enough():
                return []
            t_first = min(starts)
            touch = self._touch = _Touch(self._next_id, t_first)
            self._next_id += 1
            self._run = 0
            self._rough = []
            before = np.array(self._run_shapes[:-1], dtype=SHAPE_DTYPE)
            keep = before["t_s"] >= t_first - 1e-9
            touch.shapes = ShapeHistory(before[keep])
            touch.changes = [c for c, k in zip(self._run_changes[:-1], keep, strict=True) if k]
            self._run_shapes = []
            self._run_changes = []
            if contacts:
                self._observe_contacts(touch, t_s, contacts, stretch_peak, shape, track=False)
            else:  # the pooled detector saw it first: no contact segmented yet
                self.tracker.reset()
                touch.t_last_s = t_s
                touch.detect_centroid_m = self._seeing().peak_m(self.x, self.y)
            self._relabel(touch)
            return [self._event(touch, "start", t_s)]
        if not contacts:
            touch.missing += 1
            self.tracker.update(t_s, [])
            pending = not touch.counts  # started by the pooled detector, no contact yet
            if pending and self.detector is not None:
                seeing = self._seeing()
                if seeing.hit and t_s - touch.t_start_s < cfg.confirm_s - 1e-9:
                    touch.t_last_s = t_s
                    touch.missing = 0
                    touch.detect_centroid_m = seeing.peak_m(self.x, self.y)
                    return self._maybe_update(touch, t_s)
                if t_s - touch.t_start_s >= cfg.confirm_s - 1e-9:
                    return self._end(touch, t_s)
            # the pooled image still sees it (a weak touch's contacts come and go under
            # heavy noise), for at most confirm_s after its last contact
            if (
                self.detector is not None
                and self.detector.hit
                and t_s - touch.t_contact_s < cfg.confirm_s - 1e-9
            ):
                touch.t_last_s = t_s
                return []
            if t_s - touch.t_last_s >= cfg.end_hold_s - 1e-9:
                return self._end(touch, t_s)
            return []
        touch.missing = 0
        self._observe_contacts(touch, t_s, contacts, stretch_peak, shape)
        return self._maybe_update(touch, t_s)

    def _seeing(self) -> PooledDetector:
        """The START detector that sees a touch before any contact.

        The raw frames' filter when it has a hit, else the pooled image.
        """
        start = self.start_detector
        return start if start is not None and start.hit else self.detector

    def _maybe_update(self, touch: _Touch, t_s: float) -> list[TouchEvent]:
        if t_s - touch.t_last_update_s >= self.config.update_period_s - 1e-9:
            self._relabel(touch)
            touch.t_last_update_s = t_s
            return [self._event(touch, "update", t_s)]
        return []

    def _end(self, touch: _Touch, t_s: float) -> list[TouchEvent]:
        """END; the pooled detector waits for a silent pooled image before it starts again."""
        self._touch = None
        self._armed = False
        self._start_armed = False
        self._relabel(touch)
        return [self._event(touch, "end", t_s)]

    def finish(self, t_s: float | None = None) -> list[TouchEvent]:
        """End a touch still going on at the end of a stream (END at its last contact)."""
        touch = self._touch
        if touch is None:
            return []
        return self._end(touch, touch.t_last_s if t_s is None else t_s)

    # ------------------------------------------------------------------ features
    def _observe_contacts(
        self, touch, t_s, contacts, stretch_peak, shape=None, track: bool = True
    ) -> None:
        if track:
            self.tracker.update(t_s, contacts)
        if touch is None:
            return
        touch.t_last_s = touch.t_contact_s = t_s
        touch.last_contacts = contacts
        touch.counts.append(len(contacts))
        if shape is not None:
            touch.shapes.append(shape)
            touch.changes.append(self._change)
        touch.max_pressure = max(touch.max_pressure, max(c.peak for c in contacts))
        if stretch_peak is not None:
            touch.max_stretch = max(touch.max_stretch or 0.0, stretch_peak)

    def features(self, touch: _Touch) -> TouchFeatures:
        """Features of a touch on the evidence so far."""
        f = shape_features(touch.shapes.rows, self.config)
        ratio = None
        if touch.max_stretch is not None and touch.max_pressure > 0:
            ratio = touch.max_stretch / touch.max_pressure
        count = max(touch.count(self.config.count_frames), 1)
        shape_z = self._shape_z(touch) if self.config.pinch_shape_z > 0 else math.nan
        return TouchFeatures(
            count,
            f["travel"],
            f["closing"],
            f["spread"],
            f["elongation"],
            ratio,
            f["frames"],
            f["trend"],
            f["narrowing"],
            f["major"],
            shape_z,
        )

    def _shape_z(self, touch: _Touch) -> float:
        """``shape_z`` of a touch's frames with a raw frame (NaN without enough of them)."""
        if not self.evidence.ready or not any(c is not None for c in touch.changes):
            return math.nan
        rows = touch.shapes.rows
        m = self.evidence.reference.size
        blank = np.full(m, np.nan)
        x = np.stack([blank if c is None else c for c in touch.changes])
        x[:, ~self.evidence.usable(self.faulty)] = np.nan
        xy = np.column_stack([rows["x_m"], rows["y_m"]])
        return shape_change_z(x, rows["t_s"], xy, self.evidence.drift_pattern())

    def _relabel(self, touch: _Touch) -> None:
        features = self.features(touch)
        self.last_features = features
        touch.label, touch.confidence = decide(features, self.config)

    def _event(self, touch: _Touch, state: str, t_s: float) -> TouchEvent:
        contacts = touch.last_contacts
        if contacts:
            centroid = np.mean([c.centroid_m for c in contacts], axis=0)
        else:
            centroid = np.asarray(touch.detect_centroid_m)
        shapes = touch.shapes.rows
        shapes = shapes[np.isfinite(shapes["x_m"]) & np.isfinite(shapes["y_m"])]
        if shapes.size:  # the blob centroid of the latest frame pressed at full strength
            strong = shapes["peak"] >= self.config.strong_fraction * shapes["peak"].max()
            latest = shapes[np.flatnonzero(strong)[-1]]
            centroid = (latest["x_m"], latest["y_m"])
        return TouchEvent(
            touch_id=touch.id,
            state=state,
            label=touch.label,
            confidence=float(touch.confidence)
            * (self.config.fault_confidence if self.near_fault(centroid) else 1.0),
            t_s=float(t_s),
            t_start_s=float(touch.t_start_s),
            t_end_s=float(touch.t_last_s if state == "end" else t_s),
            centroid_m=(float(centroid[0]), float(centroid[1])),
            area_m2=float(sum(c.area_m2 for c in contacts)),
            peak_pa=float(max((c.peak for c in contacts), default=0.0)),
            n_contacts=len(contacts),
        )


def _running_mean(stack: np.ndarray, n: int) -> np.ndarray:
    """``[T - n + 1, H, W]`` means of ``n`` consecutive frames of ``stack`` ``[T, H, W]``."""
    if n <= 1:
        return stack
    c = np.cumsum(np.concatenate([np.zeros_like(stack[:1]), stack]), axis=0)
    return (c[n:] - c[:-n]) / n


def classify_stream(
    t_s: np.ndarray,
    pressure: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    stretch: np.ndarray | None = None,
    config: ClassifierConfig | None = None,
    contact_spread_m: float | np.ndarray | None = None,
    volts: np.ndarray | None = None,
    channel_electrodes: np.ndarray | None = None,
    disc_rel: np.ndarray | None = None,
    contact_rel: np.ndarray | None = None,
) -> list[TouchEvent]:
    """Every event of a whole recording: ``pressure`` ``[T, H, W]`` Pa, ``stretch`` likewise.

    ``contact_spread_m``: one fingertip's spread; ``volts``: ``[T, M]`` the pressure layer's
    raw frames, V, ``channel_electrodes`` their ``[M, E]`` electrode map, ``disc_rel`` and
    ``contact_rel`` the patterns of their START filter (see :class:`TouchClassifier`).
    """
    classifier = TouchClassifier(
        x,
        y,
        config,
        contact_spread_m=contact_spread_m,
        channel_electrodes=channel_electrodes,
        disc_rel=disc_rel,
        contact_rel=contact_rel,
    )
    events: list[TouchEvent] = []
    for k in range(len(t_s)):
        events += classifier.step(
            float(t_s[k]),
            pressure[k],
            None if stretch is None else stretch[k],
            None if volts is None else volts[k],
        )
    events += classifier.finish()
    return events
