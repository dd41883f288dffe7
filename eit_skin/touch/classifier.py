"""Touches from a stream of reconstructed images: START / UPDATE / END events, labelled.

:class:`TouchClassifier` takes frames ``(t_s, pressure [H, W] Pa, stretch [H, W] strain or
None, raw frame [M] V or None)`` and returns :class:`~eit_skin.touch.events.TouchEvent`
records. Per frame, after ``calibration_s`` of no-touch frames:

1. :class:`~eit_skin.touch.background.Background`: the mean of the latest ``average_frames``
   images minus the baseline and the sheet-wide offset; baseline and noise keep following
   the no-touch frames;
2. contacts: hysteresis segmentation of that image at multiples of the noise
   (:class:`~eit_skin.touch.contacts.ContactSegmenter`), tracked over frames;
3. :class:`~eit_skin.touch.start_gates.StartGates`: a touch STARTs once a contact stayed in
   place (one track) for ``start_frames`` frames, or earlier on a pooled detection; never
   while the sheet flickers and the candidate is as rough as noise;
4. event assembly (here): all contacts on the patch belong to the one touch going on; each
   frame's blob shape (:func:`~eit_skin.touch.shapes.blob_moments`, in single-finger
   spreads) joins its evidence; UPDATEs every ``update_period_s``; END after ``end_hold_s``
   without contact (a touch the pooled detector started: ``end_hold_s`` of silent pooled
   image, or ``confirm_s`` without any contact); labels by
   :func:`~eit_skin.touch.events.decide`.

The label of START is provisional (evidence of the first frames); UPDATEs carry the label on
the evidence so far and may revise it; END carries the final label. Settings:
:class:`~eit_skin.touch.config.ClassifierConfig`; method and history: docs/classifier.md.

Example (a 3 cm square sheet, one 1.5 s press of 400 Pa after 0.5 s of noise):

>>> import numpy as np
>>> x = y = np.linspace(-0.015, 0.015, 31)
>>> xx, yy = np.meshgrid(x, y)
>>> rng = np.random.default_rng(0)
>>> clf = TouchClassifier(x, y)
>>> events = []
>>> for k in range(150):
...     t = k / 50
...     press = 400.0 * np.exp(-(xx**2 + yy**2) / 0.004**2) if 1.0 <= t < 2.5 else 0.0
...     events += clf.step(t, press + rng.normal(0.0, 5.0, xx.shape))
>>> events += clf.finish()
>>> [(e.state, e.label) for e in events if e.state != "update"]
[('start', 'push'), ('end', 'push')]
"""

from __future__ import annotations

import math

import numpy as np

from eit_skin.patch.model import Layer, Patch, PatchError
from eit_skin.touch.background import Background, running_mean
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
from eit_skin.touch.frame_evidence import FrameEvidence, shape_change_z
from eit_skin.touch.shapes import blob_moments
from eit_skin.touch.start_gates import StartGates

_MAX_CALIBRATION_FRAMES = 10_000
"""Calibration ends after this many frames even if ``calibration_s`` has not passed (a
memory bound against stamps that do not advance)."""


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
        self._xx, self._yy = np.meshgrid(self.x, self.y)
        spread = self.config.contact_spread_m if contact_spread_m is None else contact_spread_m
        spread = np.broadcast_to(np.asarray(spread, dtype=np.float64), self._xx.shape)
        if not (np.all(np.isfinite(spread)) and np.all(spread > 0)):
            raise ValueError(
                f"contact_spread_m: a finite, positive scalar or [H, W] = {self._xx.shape} map"
            )
        self.contact_spread_m = spread
        self.electrodes_m = None if electrodes_m is None else np.asarray(electrodes_m, float)
        if self.electrodes_m is not None and (
            self.electrodes_m.ndim != 2 or self.electrodes_m.shape[1] != 2
        ):
            raise ValueError(f"electrodes_m: [E, 2] m, got shape {self.electrodes_m.shape}")
        if disc_rel is not None and np.shape(disc_rel)[:2] != self._xx.shape:
            raise ValueError(
                f"disc_rel: [H, W, M] with [H, W] = {self._xx.shape}, got {np.shape(disc_rel)}"
            )
        self.tracker = ContactTracker(
            self.config.gate_pixels * self.pixel_m, max_missed=self.config.track_missed_frames
        )
        self.evidence = FrameEvidence(channel_electrodes)
        self.gates = StartGates(self.config, self.evidence, disc_rel, contact_rel)
        #: baseline, noise and offset (None until the calibration frames are in)
        self.background: Background | None = None
        self._calibration: list[np.ndarray] = []
        self._calibration_stretch: list[np.ndarray] = []
        self._calibration_volts: list[np.ndarray] = []
        self._t0: float | None = None
        self._t_prev: float | None = None
        self._recent: list[np.ndarray] = []  # the latest average_frames - 1 images
        self._times: list[float] = []
        self._change: np.ndarray | None = None  # the latest frame's whitened raw change
        # event assembly: the touch going on, and the candidate's evidence before a START
        self._touch: OngoingTouch | None = None
        self._next_id = 1
        self._run = 0
        self._run_shapes: list[np.ndarray] = []  # 0-d SHAPE_DTYPE records before a START
        self._run_changes: list[np.ndarray | None] = []  # beside _run_shapes
        self._strong = False  # a contact of the latest frame stands out of the noise estimate
        self.last_contacts: list[Contact] = []
        self.last_features: TouchFeatures | None = None
        self.frames = 0

    @property
    def segmenter(self):
        """The contact segmenter (holding the noise map), or None before calibration."""
        return None if self.background is None else self.background.segmenter

    @property
    def detector(self) -> PooledDetector | None:
        """The pooled image's START detector (None before calibration, or disabled)."""
        return self.gates.detector

    @property
    def start_detector(self) -> PooledDetector | None:
        """The raw frames' matched-filter START detector (None without raw frames)."""
        return self.gates.start_detector

    @property
    def faulty(self) -> tuple[int, ...]:
        """Electrodes the imaging leaves out (:meth:`set_faulty_electrodes`), sorted."""
        return self.gates.faulty

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
        self.gates.faulty = faulty

    def near_fault(self, point_m) -> bool:
        """Whether ``(x, y)`` m is within ``fault_radius`` finger spreads of a faulty electrode."""
        if not self.faulty or self.electrodes_m is None:
            return False
        d = np.linalg.norm(self.electrodes_m[list(self.faulty)] - np.asarray(point_m), axis=1)
        unit = float(np.median(self.contact_spread_m))
        return bool(d.min() <= self.config.fault_radius * unit)

    @property
    def calibrated(self) -> bool:
        return self.background is not None

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
        n_avg = min(self.config.average_frames, len(stack))
        self._recent = list(stack[len(stack) - n_avg + 1 :]) if n_avg > 1 else []
        unit_px = float(np.median(self.contact_spread_m)) / self.pixel_m
        self.background = bg = Background(
            self.x,
            self.y,
            self.config,
            stack,
            np.stack(self._calibration_stretch) if self._calibration_stretch else None,
            pressure_noise_pa=self.pressure_noise_pa,
            stretch_noise=self.stretch_noise,
            margin_px=max(round(self.config.offset_margin * unit_px), 0),
        )
        self.pressure_noise_pa, self.stretch_noise = bg.pressure_noise_pa, bg.stretch_noise
        if len(self._calibration_volts) >= 3:
            self.evidence.calibrate(np.stack(self._calibration_volts))
        averaged = running_mean(stack, n_avg)
        inside = np.isfinite(stack).any(axis=0)
        if self.config.detect_kernel > 0 and len(averaged) >= 3 and inside.any():
            finger_m = float(np.median(self.contact_spread_m[inside]))
            volts = np.stack(self._calibration_volts) if self._calibration_volts else None
            self.gates.calibrate(
                inside,
                self.config.detect_kernel * finger_m / self.pixel_m,
                averaged - bg.baseline,
                n_avg,
                # every calibration image came with its raw frame: START from their filter
                volts if volts is not None and len(volts) == len(stack) else None,
            )
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
        if self.background is None:
            self._calibrate(t_s, pressure, stretch, volts)
            self._t_prev = t_s
            self.gates.push_image(pressure)
            self.last_contacts = []
            return []
        bg = self.background
        dt = max(t_s - (self._t_prev if self._t_prev is not None else t_s), 0.0)
        self._t_prev = t_s
        self._change = self.evidence.whiten(volts)
        self.gates.push_change(self._change)
        self._recent = [*self._recent[-(self.config.average_frames - 1) :], pressure]
        if self.config.average_frames == 1:
            self._recent = [pressure]
        signal = np.mean(self._recent, axis=0) - bg.baseline
        offset = bg.offset(signal)
        signal = signal - offset
        self.gates.push_image(pressure)
        self._times = [*self._times[-self.config.lookback_frames :], t_s]
        detected = self.gates.detect(signal, self._times)  # first frame of a pooled detection
        contacts, parts = bg.segmenter.segment_with_labels(signal)
        self.last_contacts = contacts
        mask = parts > 0
        if self._touch is None:
            self._strong = bool(contacts) and bg.stands_out(signal, mask)
            noise = None if bg.noise_var is None else bg.noise_sigma
            candidate = mask if contacts else None
            self.gates.follow_roughness(pressure, bg.baseline, offset, noise, candidate)
        bg.note_contacts(mask, bool(contacts))
        stretch_peak = None
        if stretch is not None and bg.stretch_baseline is not None:
            s = stretch - bg.stretch_baseline
            stretch_peak = float(np.nanmax(s)) if np.isfinite(s).any() else None
        shape = None
        if contacts:
            shape = self._shape(t_s, signal, mask)
        else:
            self._run_shapes = []
            self._run_changes = []
            if self._touch is None:
                bg.follow(dt, pressure, stretch)
                self._follow_noise(dt, signal)
                if volts is not None:
                    self.evidence.follow(1.0 - math.exp(-dt / self.config.baseline_tau_s), volts)
        return self._advance(t_s, contacts, stretch_peak, shape, detected)

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
        """Teach the noise maps a no-touch frame ``signal`` ``[H, W]`` (time ``noise_tau_s``)."""
        if self.config.noise_tau_s <= 0:
            return
        alpha = 1.0 - math.exp(-dt / self.config.noise_tau_s)
        if alpha <= 0.0:  # no time passed (two boards' images with one stamp): nothing to learn
            return
        if self.gates.follow_noise(alpha):
            self.background.follow_noise(alpha, signal)

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
                self._observe_contacts(touch, t_s, contacts, stretch_peak, shape, track=False)
            else:  # the pooled detector saw it first: no contact segmented yet
                self.tracker.reset()
                touch.t_last_s = t_s
                touch.detect_centroid_m = self.gates.seeing().peak_m(self.x, self.y)
            self._relabel(touch)
            return [self._event(touch, "start", t_s)]
        if not contacts:
            touch.missing += 1
            self.tracker.update(t_s, [])
            pending = not touch.counts  # started by the pooled detector, no contact yet
            if pending and self.detector is not None:
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
        if not self.evidence.ready or not any(c is not None for c in touch.changes):
            return math.nan
        rows = touch.shapes.rows
        m = self.evidence.reference.size
        blank = np.full(m, np.nan)
        x = np.stack([blank if c is None else c for c in touch.changes])
        x[:, ~self.evidence.usable(self.faulty)] = np.nan
        xy = np.column_stack([rows["x_m"], rows["y_m"]])
        return shape_change_z(x, rows["t_s"], xy, self.evidence.drift_pattern())

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
