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
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import Contact, ContactTracker, PooledDetector
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
        signal: this frame's averaged image minus baseline and offset ``[H, W]``, Pa, or None.
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
        self.signal: np.ndarray | None = None
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

        Before, set :attr:`change` (this frame's whitened raw change or None), :attr:`signal`
        (this frame's averaged image minus baseline, Pa) and :attr:`strong` (a contact stands
        out of the noise estimate).
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
        touch.faulty = [self.gates.faulty] * len(touch.changes)
        self._run_shapes = []
        self._run_changes = []
        discs = self._discs()
        if contacts:
            self._observe_contacts(touch, t_s, contacts, stretch_peak, shape)
        else:  # the pooled detector saw it first: no contact segmented yet
            self.tracker.reset()
            touch.t_last_s = t_s
            touch.early = self._early_estimate(discs)
        self._relabel(touch)
        # the raw frames' discs place a START better than its first, partial contacts
        at = None if discs is None else disc_centroid(discs, self._xx, self._yy)
        return [self._event(touch, "start", t_s, at)]

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
                    touch.early = self._early_estimate(self._discs())
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
        firmed = not touch.counts  # the first segmented contact of a pooled START
        self._observe_contacts(touch, t_s, contacts, stretch_peak, shape)
        return self._maybe_update(touch, t_s, firmed)

    def _maybe_update(self, touch: OngoingTouch, t_s: float, now: bool = False) -> list[TouchEvent]:
        """UPDATE if ``update_period_s`` passed since the last event, or ``now``."""
        if now or t_s - touch.t_last_update_s >= self.config.update_period_s - 1e-9:
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

    @property
    def started_s(self) -> float | None:
        """START time of the touch going on, s, or None."""
        return None if self._touch is None else self._touch.t_start_s

    def withdraw(self, t_s: float, reason: str) -> list[TouchEvent]:
        """END the touch going on as no touch: confidence 0, ``reason`` in ``withdrawn``."""
        if self._touch is None:
            return []
        return [replace(e, confidence=0.0, withdrawn=reason) for e in self._end(self._touch, t_s)]

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
            touch.faulty.append(self.gates.faulty)
        touch.max_pressure = max(touch.max_pressure, max(c.peak for c in contacts))
        if stretch_peak is not None:
            touch.max_stretch = max(touch.max_stretch or 0.0, stretch_peak)

    def sound_frames(self, touch: OngoingTouch) -> np.ndarray:
        """``[T]`` bool: which of a touch's shape frames were imaged without a hidden fault.

        An electrode that fails during a touch spoils the images until the pipeline's fault
        check names it (up to a second later); its first sign in the raw frames is its
        channels left out as one-frame jumps (NaN). The frames from that sign to the naming,
        and the ``average_frames - 1`` averaged images after it (they still hold one), are
        not sound: the features and the centroid leave them out (issue 38: a pinch while an
        electrode died was labelled grab from them). Without raw frames, all are sound.
        """
        n = len(touch.shapes)
        sound = np.ones(n, dtype=bool)
        channels = self.gates.evidence.channel_electrodes
        if channels is None or len(touch.faulty) != n or not self.gates.faulty:
            return sound
        missing = np.array(
            [c is not None and not np.all(np.isfinite(c)) for c in touch.changes], dtype=bool
        )
        for e in self.gates.faulty:
            before = np.array([e not in f for f in touch.faulty], dtype=bool)  # not named yet
            mine = channels[:, e]
            gone = np.array(
                [c is not None and bool(np.any(~np.isfinite(c[mine]))) for c in touch.changes],
                dtype=bool,
            )
            signs = np.flatnonzero(before & missing & gone)
            if signs.size:
                named = signs[0] + int(np.count_nonzero(before[signs[0] :]))
                # and the averaged images that still hold a frame of before the naming
                sound[signs[0] : named + self.config.average_frames - 1] = False
        return sound if sound.any() else np.ones(n, dtype=bool)

    def features(self, touch: OngoingTouch) -> TouchFeatures:
        """Features of a touch on the evidence so far (its sound frames: :meth:`sound_frames`)."""
        sound = self.sound_frames(touch)
        f = shape_features(touch.shapes.rows[sound], self.config)
        ratio = None
        if touch.max_stretch is not None and touch.max_pressure > 0:
            ratio = touch.max_stretch / touch.max_pressure
        count = max(touch.count(self.config.count_frames), 1)
        shape_z = self._shape_z(touch, sound) if self.config.pinch_shape_z > 0 else math.nan
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

    def _shape_z(self, touch: OngoingTouch, sound: np.ndarray) -> float:
        """``shape_z`` of a touch's ``sound`` frames with a raw frame (NaN: too few)."""
        if not self.gates.evidence.ready or not any(c is not None for c in touch.changes):
            return math.nan
        rows = touch.shapes.rows[sound]
        m = self.gates.evidence.reference.size
        blank = np.full(m, np.nan)
        changes = [c for c, ok in zip(touch.changes, sound, strict=True) if ok]
        x = np.stack([blank if c is None else c for c in changes])
        x[:, ~self.gates.evidence.usable(self.gates.faulty)] = np.nan
        xy = np.column_stack([rows["x_m"], rows["y_m"]])
        return shape_change_z(x, rows["t_s"], xy, self.gates.evidence.drift_pattern())

    def _relabel(self, touch: OngoingTouch) -> None:
        features = self.features(touch)
        self.last_features = features
        touch.label, touch.confidence = decide(features, self.config)

    def _discs(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The fingertip discs in this frame's raw change (``(places, amplitudes)``).

        :meth:`~eit_skin.touch.frame_evidence.TouchFilter.fit_discs` on the change the
        matched filter read, its detector's noise map and ``blob_fraction``; None without a
        filter map this frame or a disc in it.
        """
        gates, evidence = self.gates, self.gates.evidence
        change, start = gates.filter_change, gates.start_detector
        if change is None or start is None or start.noise is None or gates.touch_filter is None:
            return None
        discs = gates.touch_filter.fit_discs(
            change, evidence.sigma, evidence.reference, start.noise, self.config.blob_fraction
        )
        return discs if discs[1].size else None

    def _early_estimate(self, discs: tuple[np.ndarray, np.ndarray] | None) -> EarlyEstimate:
        """Where, how large and how strong a touch is that no contact segmented yet.

        From the evidence that fired it (:func:`early_estimate`): the raw frames' ``discs``
        and matched filter map when there are, else the pooled image's z-scores; this
        frame's :attr:`signal` for area and peak; the detector that sees it for the
        confidence.
        """
        gates = self.gates
        start = gates.start_detector
        located = gates.detector.z if start is None else start.pooled
        return early_estimate(
            located,
            self.signal,
            gates.seeing(),
            self._xx,
            self._yy,
            self.config.blob_fraction,
            self.config.confidence_gain,
            discs,
        )

    def _event(
        self, touch: OngoingTouch, state: str, t_s: float, at: np.ndarray | None = None
    ) -> TouchEvent:
        """The event of ``touch`` at ``t_s``; ``at``: its position, m, if known better."""
        contacts = touch.last_contacts
        early = touch.early if not contacts else None
        if contacts:
            centroid = np.mean([c.centroid_m for c in contacts], axis=0)
        else:
            centroid = np.asarray(early.centroid_m if early is not None else (0.0, 0.0))
        shapes = touch.shapes.rows[self.sound_frames(touch)]
        shapes = shapes[np.isfinite(shapes["x_m"]) & np.isfinite(shapes["y_m"])]
        if shapes.size:  # the blob centroid of the latest frame pressed at full strength
            strong = shapes["peak"] >= self.config.strong_fraction * shapes["peak"].max()
            latest = shapes[np.flatnonzero(strong)[-1]]
            centroid = (latest["x_m"], latest["y_m"])
        if at is not None:
            centroid = at
        confidence = float(touch.confidence)
        if early is not None:  # no contact yet: no surer than the evidence
            confidence = min(confidence, early.confidence)
        return TouchEvent(
            touch_id=touch.id,
            state=state,
            label=touch.label,
            confidence=confidence
            * (self.config.fault_confidence if self.near_fault(centroid) else 1.0),
            t_s=float(t_s),
            t_start_s=float(touch.t_start_s),
            t_end_s=float(touch.t_last_s if state == "end" else t_s),
            centroid_m=(float(centroid[0]), float(centroid[1])),
            area_m2=float(sum(c.area_m2 for c in contacts)) if early is None else early.area_m2,
            peak_pa=float(max((c.peak for c in contacts), default=0.0))
            if early is None
            else early.peak_pa,
            n_contacts=len(contacts),
        )


@dataclass(frozen=True)
class EarlyEstimate:
    """A touch seen by a START detector before any contact is segmented.

    Attributes:
        centroid_m: ``(x, y)`` m, patch frame.
        area_m2: area of the peak region, m^2.
        peak_pa: largest averaged-image change in the region, Pa.
        confidence: 0..1, from how far the detector's z-score is above its threshold.
    """

    centroid_m: tuple[float, float]
    area_m2: float
    peak_pa: float
    confidence: float


def disc_centroid(
    discs: tuple[np.ndarray, np.ndarray], xx: np.ndarray, yy: np.ndarray
) -> np.ndarray:
    """``[2]`` m: the centre of a touch's contacts, each weighed by its strength.

    The amplitude-weighted centroid of ``discs`` (``(places [D, 2], amplitudes [D])``,
    fractional (row, column) pixel indices:
    :meth:`~eit_skin.touch.frame_evidence.TouchFilter.fit_discs`) on the regular pixel grid
    ``xx``, ``yy`` ``[H, W]``, m.
    """
    places, amplitude = discs
    row, column = amplitude @ places / amplitude.sum()
    dx, dy = xx[0, 1] - xx[0, 0], yy[1, 0] - yy[0, 0]  # the grid's steps (either sign)
    return np.array([xx[0, 0] + column * dx, yy[0, 0] + row * dy])


def early_estimate(
    located: np.ndarray,
    signal: np.ndarray | None,
    detector: PooledDetector,
    xx: np.ndarray,
    yy: np.ndarray,
    fraction: float,
    gain: float,
    discs: tuple[np.ndarray, np.ndarray] | None = None,
) -> EarlyEstimate:
    """Position, area, peak and confidence of a touch a pooled detector STARTed.

    **Position**: with ``discs`` (the fingertip discs the raw frames show,
    :meth:`~eit_skin.touch.frame_evidence.TouchFilter.fit_discs`), their amplitude-weighted
    centroid (:func:`disc_centroid`): the centre of a pinch's or grab's contacts, not one
    finger's. Else the centroid of the connected region of ``located`` above ``fraction`` of
    its largest value holding that value, weighed ``located - fraction * peak`` (as
    :func:`~eit_skin.touch.shapes.blob_moments`). With the raw frames, ``located`` is the
    matched filter's map (the best-matching fingertip positions); the pooled image's z-scores
    otherwise. Neither the pooled image itself nor the averaged image: in the first frames of
    a touch their peaks lie tens of mm off (docs/classifier.md, "START position").
    **Peak**: the largest value of ``signal`` in the regions of ``located`` above ``fraction``
    of its largest value that hold that value or a disc, Pa; **area**: their pixels with
    ``signal`` at or above half that peak, m^2 (0 without a positive peak).
    **Confidence**: ``0.5 + 0.5 tanh(gain (z_max - k) / k)`` of the ``detector`` that fired
    (0.5 on its threshold ``k``).

    Args:
        located: ``[H, W]`` map whose peak region is the touch (NaN off the sheet).
        signal: ``[H, W]`` averaged image minus baseline, Pa (NaN off the sheet), or None.
        detector: the detector that fired (its latest ``z`` ``[H, W]`` and ``k``).
        xx: ``[H, W]`` pixel-centre x, m.
        yy: ``[H, W]`` pixel-centre y, m.
        fraction: blob weight fraction (``blob_fraction``).
        gain: ``confidence_gain``.
        discs: ``(places [D, 2] fractional (row, column) pixel indices, amplitudes [D])`` or
            None.
    """
    values = np.where(np.isfinite(located), located, -np.inf)
    i, j = np.unravel_index(int(np.argmax(values)), values.shape)
    top = values[i, j]
    parts, _ = ndimage.label(values > fraction * top) if top > 0 else (np.zeros(values.shape), 0)
    held = [(i, j)] if discs is None else [(i, j), *map(tuple, np.rint(discs[0]).astype(int))]
    ids = {int(parts[p]) for p in held} - {0}
    region = np.isin(parts, list(ids)) if ids else np.zeros(values.shape, dtype=bool)
    region[i, j] = True
    if discs is not None:
        x, y = disc_centroid(discs, xx, yy)
    else:
        _, x, y, *_ = blob_moments(np.where(region, located, 0.0), xx, yy, fraction, region)
    if not (np.isfinite(x) and np.isfinite(y)):
        x, y = xx[i, j], yy[i, j]
    peak, area = 0.0, 0.0
    if signal is not None:
        inside = np.where(region & np.isfinite(signal), signal, -np.inf)
        peak = max(float(inside.max()), 0.0)
        if peak > 0:
            pixel_m2 = float(abs(xx[0, 1] - xx[0, 0]) * abs(yy[1, 0] - yy[0, 0]))
            area = float(np.count_nonzero(inside >= 0.5 * peak)) * pixel_m2
    z_max = float(np.max(detector.z))
    confidence = 0.5 + 0.5 * math.tanh(gain * (z_max - detector.k) / detector.k)
    return EarlyEstimate((float(x), float(y)), area, peak, confidence)
