"""Event assembly: START, UPDATE and END of the one touch going on, labelled.

All contacts on the patch belong to the touch going on. A touch STARTs once a contact stayed
in place (one track) for ``start_frames`` frames, or on a pooled detection
(:class:`~eit_skin.touch.start_gates.StartGates`), never while the gates find the candidate
as rough as noise; its START is dated back to the first frame of that evidence. UPDATEs
come at most every ``update_period_s`` and END after ``end_hold_s`` without contact (a touch
the pooled detector started: after ``end_hold_s`` of silent pooled image, or ``confirm_s``
without any contact). Each event carries the label of :func:`~eit_skin.touch.events.decide`
on the evidence so far (:class:`~eit_skin.touch.events.TouchFeatures`).
"""

from __future__ import annotations

import math

import numpy as np

from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import Contact, ContactTracker
from eit_skin.touch.events import (
    SHAPE_DTYPE,
    OngoingTouch,
    ShapeHistory,
    TouchEvent,
    TouchFeatures,
    decide,
    shape_features,
)
from eit_skin.touch.frame_evidence import shape_change_z
from eit_skin.touch.shapes import blob_moments
from eit_skin.touch.start_gates import StartGates


class EventAssembler:
    """The touch going on and the evidence of a candidate before its START.

    Args:
        config: thresholds and timing.
        gates: the START gates (their detectors, faulty electrodes and raw-frame evidence).
        x: ``[W]`` pixel-centre x, m.  y: ``[H]`` pixel-centre y, m.
        contact_spread_m: ``[H, W]`` one fingertip's spread at every pixel, m.
        electrodes_m: ``[E, 2]`` electrode centres, m, or None (no fault proximity).

    Attributes:
        change: this frame's whitened raw change ``[M]``, or None.
        strong: whether a contact of this frame stands out of the noise estimate.
        last_features: the features behind the latest event's label.
    """

    def __init__(
        self,
        config: ClassifierConfig,
        gates: StartGates,
        x: np.ndarray,
        y: np.ndarray,
        contact_spread_m: np.ndarray,
        electrodes_m: np.ndarray | None,
    ) -> None:
        self.config = config
        self.gates = gates
        self.x, self.y = x, y
        self._xx, self._yy = np.meshgrid(x, y)
        self.contact_spread_m = contact_spread_m
        self.electrodes_m = electrodes_m
        pixel_m = float(abs(x[1] - x[0]))
        self.tracker = ContactTracker(
            config.gate_pixels * pixel_m, max_missed=config.track_missed_frames
        )
        self._touch: OngoingTouch | None = None
        self._next_id = 1
        self._run = 0
        self._run_shapes: list[np.ndarray] = []  # 0-d SHAPE_DTYPE records before a START
        self._run_changes: list[np.ndarray | None] = []  # beside _run_shapes
        self.change: np.ndarray | None = None
        self.strong = False
        self.last_features: TouchFeatures | None = None

    @property
    def active(self) -> bool:
        """True while a touch is going on (between its START and END)."""
        return self._touch is not None

    def shape(self, t_s: float, signal: np.ndarray, mask: np.ndarray) -> np.ndarray:
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

    def near_fault(self, point_m) -> bool:
        """Whether ``(x, y)`` m is within ``fault_radius`` finger spreads of a faulty electrode."""
        if not self.gates.faulty or self.electrodes_m is None:
            return False
        d = np.linalg.norm(self.electrodes_m[list(self.gates.faulty)] - np.asarray(point_m), axis=1)
        unit = float(np.median(self.contact_spread_m))
        return bool(d.min() <= self.config.fault_radius * unit)

    def advance(
        self,
        t_s: float,
        contacts: list[Contact],
        stretch_peak: float | None,
        shape: np.ndarray | None,
        detected: float | None,
    ) -> list[TouchEvent]:
        """This frame's events (START, UPDATE, END or none).

        Args:
            t_s: frame time, s.
            contacts: this frame's contacts (segmented in the averaged image).
            stretch_peak: the stretch image's largest change (strain), or None.
            shape: this frame's blob shape (:meth:`shape`), None without contacts.
            detected: time of the first frame of a pooled detection (:class:`StartGates`),
                or None.

        Before, set :attr:`change` (this frame's whitened raw change or None) and
        :attr:`strong` (a contact stands out of the noise estimate).
        """
        if not contacts:  # a candidate's shapes are of consecutive frames with contacts
            self._run_shapes = []
            self._run_changes = []
        if self._touch is None:
            return self._maybe_start(t_s, contacts, stretch_peak, shape, detected)
        return self._follow(self._touch, t_s, contacts, stretch_peak, shape)

    def _maybe_start(self, t_s, contacts, stretch_peak, shape, detected) -> list[TouchEvent]:
        """START, dated to its first evidence, or nothing (arguments as :meth:`advance`)."""
        cfg = self.config
        starts = [] if detected is None else [detected]
        if contacts:
            if self._run == 0:
                self.tracker.reset()
            self._run += 1
            self._run_shapes = [*self._run_shapes[-cfg.lookback_frames :], shape]
            self._run_changes = [*self._run_changes[-cfg.lookback_frames :], self.change]
            self.tracker.update(t_s, contacts)
            # a contact must stay in place (one track) for start_frames frames: noise
            # crossing the threshold at random places in consecutive frames is no touch
            if self.strong:
                starts += [
                    tr.first_seen_s
                    for tr in self.tracker.tracks
                    if tr.missed == 0 and tr.frames >= cfg.start_frames
                ]
        else:
            self._run = 0
        if not starts or not self.gates.smooth_enough():
            return []
        t_first = min(starts)
        touch = self._touch = OngoingTouch(self._next_id, t_first)
        self._next_id += 1
        self._run = 0
        self.gates.touch_started()
        before = np.array(self._run_shapes[:-1], dtype=SHAPE_DTYPE)
        keep = before["t_s"] >= t_first - 1e-9
        touch.shapes = ShapeHistory(before[keep])
        touch.changes = [c for c, k in zip(self._run_changes[:-1], keep, strict=True) if k]
        self._run_shapes = []
        self._run_changes = []
        if contacts:
            self._observe_contacts(touch, t_s, contacts, stretch_peak, shape)
        else:  # the pooled detector saw it first: no contact segmented yet
            self.tracker.reset()
            touch.t_last_s = t_s
            touch.detect_centroid_m = self.gates.seeing().peak_m(self.x, self.y)
        self._relabel(touch)
        return [self._event(touch, "start", t_s)]

    def _follow(self, touch: OngoingTouch, t_s, contacts, stretch_peak, shape) -> list[TouchEvent]:
        """UPDATE, END or nothing for ``touch``, going on (arguments as :meth:`advance`)."""
        cfg = self.config
        if not contacts:
            touch.missing += 1
            self.tracker.update(t_s, [])
            pending = not touch.counts  # started by the pooled detector, no contact yet
            if pending and self.gates.detector is not None:
                seeing = self.gates.seeing()
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
                self.gates.detector is not None
                and self.gates.detector.hit
                and t_s - touch.t_contact_s < cfg.confirm_s - 1e-9
            ):
                touch.t_last_s = t_s
                return []
            if t_s - touch.t_last_s >= cfg.end_hold_s - 1e-9:
                return self._end(touch, t_s)
            return []
        touch.missing = 0
        self.tracker.update(t_s, contacts)
        self._observe_contacts(touch, t_s, contacts, stretch_peak, shape)
        return self._maybe_update(touch, t_s)

    def _maybe_update(self, touch: OngoingTouch, t_s: float) -> list[TouchEvent]:
        if t_s - touch.t_last_update_s >= self.config.update_period_s - 1e-9:
            self._relabel(touch)
            touch.t_last_update_s = t_s
            return [self._event(touch, "update", t_s)]
        return []

    def _end(self, touch: OngoingTouch, t_s: float) -> list[TouchEvent]:
        """END; the pooled detector waits for a silent pooled image before it starts again."""
        self._touch = None
        self.gates.touch_ended()
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
        self,
        touch: OngoingTouch,
        t_s: float,
        contacts: list[Contact],
        stretch_peak: float | None,
        shape: np.ndarray | None,
    ) -> None:
        """A frame with contacts joins the touch's evidence (the tracker has seen it)."""
        touch.t_last_s = touch.t_contact_s = t_s
        touch.last_contacts = contacts
        touch.counts.append(len(contacts))
        if shape is not None:
            touch.shapes.append(shape)
            touch.changes.append(self.change)
        touch.max_pressure = max(touch.max_pressure, max(c.peak for c in contacts))
        if stretch_peak is not None:
            touch.max_stretch = max(touch.max_stretch or 0.0, stretch_peak)

    def features(self, touch: OngoingTouch) -> TouchFeatures:
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

    def _shape_z(self, touch: OngoingTouch) -> float:
        """``shape_z`` of a touch's frames with a raw frame (NaN without enough of them)."""
        if not self.gates.evidence.ready or not any(c is not None for c in touch.changes):
            return math.nan
        rows = touch.shapes.rows
        m = self.gates.evidence.reference.size
        blank = np.full(m, np.nan)
        x = np.stack([blank if c is None else c for c in touch.changes])
        x[:, ~self.gates.evidence.usable(self.gates.faulty)] = np.nan
        xy = np.column_stack([rows["x_m"], rows["y_m"]])
        return shape_change_z(x, rows["t_s"], xy, self.gates.evidence.drift_pattern())

    def _relabel(self, touch: OngoingTouch) -> None:
        features = self.features(touch)
        self.last_features = features
        touch.label, touch.confidence = decide(features, self.config)

    def _event(self, touch: OngoingTouch, state: str, t_s: float) -> TouchEvent:
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
