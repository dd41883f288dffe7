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
4. :class:`~eit_skin.touch.assembly.EventAssembler`: all contacts on the patch belong to
   the one touch going on; each frame's blob shape (:func:`~eit_skin.touch.shapes.blob_moments`,
   in single-finger spreads) joins its evidence; UPDATEs every ``update_period_s``; END
   after ``end_hold_s`` without contact; labels by :func:`~eit_skin.touch.events.decide`.

The label of START is provisional (evidence of the first frames); UPDATEs carry the label on
the evidence so far and may revise it; END carries the final label. Settings:
:class:`~eit_skin.touch.config.ClassifierConfig`; method and history: docs/classifier.md.
"""

from __future__ import annotations

import math

import numpy as np

from eit_skin.patch.model import Layer, Patch, PatchError
from eit_skin.touch.assembly import EventAssembler
from eit_skin.touch.background import Background, running_mean
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import Contact, PooledDetector
from eit_skin.touch.events import TouchEvent, TouchFeatures
from eit_skin.touch.frame_evidence import FrameEvidence
from eit_skin.touch.settings import setting_values
from eit_skin.touch.sheet_change import StillnessWindow
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


LIVE_SETTINGS = frozenset(
    {
        # segmentation and START thresholds, read on every frame
        "k_high",
        "k_low",
        "split_fraction",
        "artifact_fraction",
        "min_pixels",
        "k_detect",
        "learn_fraction",
        "start_frames",
        "confirm_s",
        "start_roughness",
        # tracking and event assembly
        "gate_pixels",
        "track_missed_frames",
        "end_hold_s",
        "update_period_s",
        "sheet_change_taus",
        "count_frames",
        "strong_fraction",
        "travel_fraction",
        "closing_window",
        # labels and confidence
        "rub_travel",
        "pinch_closing",
        "pinch_trend",
        "pinch_narrowing",
        "pinch_shape_z",
        "grab_spread",
        "grab_major",
        "stretch_ratio_rub",
        "confidence_gain",
        "fault_radius",
        "fault_confidence",
        # how fast the baseline and noise maps follow, the sheet-wide offset
        "baseline_tau_s",
        "noise_tau_s",
        "offset_margin",
        "offset_deadband",
    }
)
"""Settings :meth:`TouchClassifier.update_settings` may change while a stream runs: each is
read on every frame, or gives a value recomputed there. The others shape what calibration
learnt or what the classifier was built with (``calibration_s``, ``average_frames``,
``noise_window``, ``noise_floor_fraction``, ``detect_kernel``, ``lookback_frames``, the
fingertip's ``blob_fraction`` and ``finger_radius_m``) and stay as they started."""


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
        self._given_noise = (pressure_noise_pa, stretch_noise)  # None: learnt by calibration
        shape = (self.y.size, self.x.size)  # [H, W]
        spread = self.config.contact_spread_m if contact_spread_m is None else contact_spread_m
        spread = np.broadcast_to(np.asarray(spread, dtype=np.float64), shape)
        if not (np.all(np.isfinite(spread)) and np.all(spread > 0)):
            raise ValueError(f"contact_spread_m: a finite, positive scalar or [H, W] = {shape} map")
        self.contact_spread_m = spread
        self.electrodes_m = None if electrodes_m is None else np.asarray(electrodes_m, float)
        if self.electrodes_m is not None and (
            self.electrodes_m.ndim != 2 or self.electrodes_m.shape[1] != 2
        ):
            raise ValueError(f"electrodes_m: [E, 2] m, got shape {self.electrodes_m.shape}")
        if disc_rel is not None and np.shape(disc_rel)[:2] != shape:
            raise ValueError(f"disc_rel: [H, W, M] with [H, W] = {shape}, got {np.shape(disc_rel)}")
        self.evidence = FrameEvidence(channel_electrodes)
        self.gates = StartGates(self.config, self.evidence, disc_rel, contact_rel)
        self.events = EventAssembler(
            self.config, self.gates, self.x, self.y, spread, self.electrodes_m
        )
        #: baseline, noise and offset (None until the calibration frames are in)
        self.background: Background | None = None
        self._calibration: list[np.ndarray] = []
        self._calibration_stretch: list[np.ndarray] = []
        self._calibration_volts: list[np.ndarray] = []
        self._t0: float | None = None
        self._t_prev: float | None = None
        self._recent: list[np.ndarray] = []  # the latest average_frames - 1 images
        self._times: list[float] = []
        self.last_contacts: list[Contact] = []
        self.frames = 0
        #: why the latest touch was withdrawn, until the sheet is still again; else None
        self.sheet_changed: str | None = None
        self._stillness: StillnessWindow | None = None  # after a sheet change
        self._relearn_s = 0.0  # no-touch time left to learn the maps of changed images, s

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
        electrode carry ``fault_confidence`` times their confidence, the START gates leave
        its raw channels out, and the image's noise maps, now of other images, are learnt
        again (:meth:`~eit_skin.touch.noise_count.NoiseCount.restart`) from every frame of the
        next ``calibration_s`` without a touch, in which only the raw frames' filter STARTs;
        nothing else changes
        (why: docs/classifier.md, "Faulty electrodes").

        Raises:
            ValueError: an index out of range, or faulty electrodes without ``electrodes_m``.
        """
        faulty = tuple(sorted({int(e) for e in np.atleast_1d(electrodes).tolist()}))
        if faulty and self.electrodes_m is None:
            raise ValueError("faulty electrodes given, but the classifier has no electrodes_m")
        if faulty and not (faulty[0] >= 0 and faulty[-1] < len(self.electrodes_m)):
            raise ValueError(f"faulty electrodes out of range 0..{len(self.electrodes_m) - 1}")
        if faulty != self.gates.faulty and self.background is not None:
            # other images now (issue 37 item 5: a left-out electrode made the arm's one-step
            # images noisier than learnt, and the pooled image STARTed 1-3 false pushes)
            self.background.count.restart()
            if self.gates.detector is not None:
                self.gates.detector.count.restart()
            # and the images START nothing until the maps have learnt them: a map of the old
            # images cannot tell which frames are quiet (Gauss-Newton's images without the
            # electrode never were, and the pooled image STARTed a false push every 0.3 s)
            self._relearn_s = self.config.calibration_s
        self.gates.faulty = faulty

    def near_fault(self, point_m) -> bool:
        """Whether ``(x, y)`` m is within ``fault_radius`` finger spreads of a faulty electrode."""
        return self.events.near_fault(point_m)

    # ------------------------------------------------------------------ live settings
    def update_settings(self, config: ClassifierConfig) -> None:
        """Classify with ``config`` from the next frame on, keeping the running state.

        The baseline, noise maps, START detectors' noise, the touch going on and its track
        stay; every value derived from a setting (the tracking gate in metres, the offset
        margin in pixels, the detectors' thresholds) is recomputed here, in one place.

        Raises:
            ValueError: ``config`` changes a setting outside :data:`LIVE_SETTINGS`, naming it.
        """
        old, new = setting_values(self.config), setting_values(config)
        fixed = sorted(n for n in new if new[n] != old[n] and n not in LIVE_SETTINGS)
        if fixed:
            raise ValueError(
                f"{', '.join(fixed)}: cannot change while classifying (fixed by calibration or "
                "at construction)"
            )
        self.config = self.gates.config = self.events.config = config
        self.events.tracker.gate_m = config.gate_pixels * self.pixel_m
        self.events.tracker.max_missed = config.track_missed_frames
        for detector in (self.gates.detector, self.gates.start_detector):
            if detector is not None:
                detector.k = float(config.k_detect)
                detector.learn_fraction = float(config.learn_fraction)
        if self.background is not None:
            self.background.config = config
            self.background.segmenter.config = config.segmentation
            self.background.margin_px = self._offset_margin_px()

    def _offset_margin_px(self) -> int:
        """``offset_margin`` single-finger spreads in pixels (median spread of the sheet)."""
        unit_px = float(np.median(self.contact_spread_m)) / self.pixel_m
        return max(round(self.config.offset_margin * unit_px), 0)

    @property
    def calibrated(self) -> bool:
        """Whether the first ``calibration_s`` of no-touch frames are in (background learnt)."""
        return self.background is not None

    @property
    def active(self) -> bool:
        """True while a touch is going on (between its START and END)."""
        return self.events.active

    @property
    def last_features(self) -> TouchFeatures | None:
        """The features behind the latest event's label."""
        return self.events.last_features

    # ------------------------------------------------------------------ calibration
    def _learn_background(
        self, t_s: float, pressure: np.ndarray, stretch: np.ndarray | None, volts=None
    ) -> None:
        """Keep a no-touch frame; after ``calibration_s`` of them, learn from them.

        The background (baseline, noise map) and the START gates' noise are learnt ("calibrate"
        is the press localiser's word).
        """
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
        self.background = bg = Background(
            self.x,
            self.y,
            self.config,
            stack,
            np.stack(self._calibration_stretch) if self._calibration_stretch else None,
            pressure_noise_pa=self.pressure_noise_pa,
            stretch_noise=self.stretch_noise,
            margin_px=self._offset_margin_px(),
        )
        self.pressure_noise_pa, self.stretch_noise = bg.pressure_noise_pa, bg.stretch_noise
        if len(self._calibration_volts) >= 3:
            self.evidence.learn_noise(np.stack(self._calibration_volts))
        averaged = running_mean(stack, n_avg)
        inside = np.isfinite(stack).any(axis=0)
        if self.config.detect_kernel > 0 and len(averaged) >= 3 and inside.any():
            finger_m = float(np.median(self.contact_spread_m[inside]))
            volts = np.stack(self._calibration_volts) if self._calibration_volts else None
            self.gates.learn(
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
        if self._stillness is not None:  # the sheet changed: no touch until it is still
            if self._stillness.still(t_s, pressure):
                self._stillness, self.sheet_changed = None, None  # then calibrate again
            self._t_prev = t_s
            return []
        if self.background is None:
            self._learn_background(t_s, pressure, stretch, volts)
            self._t_prev = t_s
            self.gates.push_image(pressure)
            self.last_contacts = []
            return []
        bg = self.background
        dt = max(t_s - (self._t_prev if self._t_prev is not None else t_s), 0.0)
        self._t_prev = t_s
        self.events.change = self.evidence.whiten(volts)
        self.gates.push_change(self.events.change)
        self._recent = [*self._recent[-(self.config.average_frames - 1) :], pressure]
        if self.config.average_frames == 1:
            self._recent = [pressure]
        signal = np.mean(self._recent, axis=0) - bg.baseline
        offset = bg.offset(signal)
        signal = signal - offset
        self.events.signal = signal
        self.gates.push_image(pressure)
        self._times = [*self._times[-self.config.lookback_frames :], t_s]
        # the images changed (set_faulty_electrodes): only the raw frames' filter may START
        relearning = self.gates.relearning = self._relearn_s > 0 and not self.events.active
        detected = self.gates.detect(signal, self._times)  # first frame of a pooled detection
        contacts, parts = bg.segmenter.segment_with_labels(signal)
        self.last_contacts = contacts
        mask = parts > 0
        if not self.events.active:
            self.events.strong = bool(contacts) and bg.stands_out(signal, mask)
            noise = None if bg.noise_var is None else bg.noise_sigma
            candidate = mask if contacts else None
            self.gates.follow_roughness(pressure, bg.baseline, offset, noise, candidate)
        bg.note_contacts(mask, bool(contacts))
        stretch_peak = self._stretch_peak(stretch)
        shape = None
        if contacts:
            shape = self.events.shape(t_s, signal, mask)
        # contacts below the START bar are noise, not a touch: the baseline (and the raw
        # frames' reference) keep following a drifting sheet through them; before, they
        # froze it and a slow drift grew into a touch (data/real/hydrogel_ohmc16)
        if relearning:  # learn the changed images' noise from every frame: no contact counts
            contacts = self._relearn(dt, signal)
        if not self.events.active and not (contacts and self.events.strong):
            bg.follow(dt, pressure, stretch)
            if not contacts and not relearning:
                self._follow_noise(dt, signal)
            if volts is not None:
                self.evidence.follow(1.0 - math.exp(-dt / self.config.baseline_tau_s), volts)
        events = self.events.advance(t_s, contacts, stretch_peak, shape, detected)
        return events + self._withdraw_stuck_touch(t_s)

    def _stretch_peak(self, stretch: np.ndarray | None) -> float | None:
        """The largest stretch above its baseline in ``stretch`` ``[H, W]``, or None."""
        bg = self.background
        if stretch is None or bg.stretch_baseline is None:
            return None
        s = stretch - bg.stretch_baseline
        return float(np.nanmax(s)) if np.isfinite(s).any() else None

    def _relearn(self, dt: float, signal: np.ndarray) -> list[Contact]:
        """Teach the image maps a frame of changed images, whatever they make of it.

        Called for ``calibration_s`` of frames without a touch after a new faulty set; the
        frame's contacts: none (the maps cannot tell them from noise yet).
        """
        self._relearn_s -= dt
        self._follow_noise(dt, signal, every_frame=True)
        return []

    def _withdraw_stuck_touch(self, t_s: float) -> list[TouchEvent]:
        """Withdraw a touch going on for longer than ``sheet_change_taus`` baseline constants.

        A touch is brief next to the drift the baseline follows; one that outlasts many of its
        time constants is the sheet changing under a frozen baseline (docs/classifier.md,
        "Changed sheet"). Its END has confidence 0 and the reason in ``withdrawn``; no touch
        STARTs until the sheet has stayed still over a window
        (:class:`~eit_skin.touch.sheet_change.StillnessWindow`), then the classifier
        calibrates again (baseline, noise maps, START gates) as at start-up.
        """
        limit_s = self.config.sheet_change_taus * self.config.baseline_tau_s
        started = self.events.started_s
        if not limit_s > 0 or started is None or t_s - started <= limit_s:
            return []
        self.sheet_changed = (
            f"sheet changed: a 'touch' went on without a break for {t_s - started:.0f} s, "
            f"longer than {self.config.sheet_change_taus:g} baseline time constants "
            f"({limit_s:g} s): no touch but the sheet (damage, drying, an electrode); "
            f"withdrawn; no touch until the sheet has stayed still for {limit_s:g} s, then the "
            "classifier calibrates again"
        )
        events = self.events.withdraw(t_s, self.sheet_changed)
        self._stillness = StillnessWindow(
            self.background, started, limit_s, self.config.average_frames
        )
        self.background, self._t0 = None, None
        self.pressure_noise_pa, self.stretch_noise = self._given_noise
        return events

    def finish(self, t_s: float | None = None) -> list[TouchEvent]:
        """End a touch still going on at the end of a stream (END at its last contact)."""
        return self.events.finish(t_s)

    def _follow_noise(self, dt: float, signal: np.ndarray, every_frame: bool = False) -> None:
        """Teach the noise maps a no-touch frame ``signal`` ``[H, W]`` (time ``noise_tau_s``).

        ``every_frame``: even one the maps do not find quiet (they are of other images).
        """
        if self.config.noise_tau_s <= 0:
            return
        alpha = 1.0 - math.exp(-dt / self.config.noise_tau_s)
        if alpha <= 0.0:  # no time passed (two boards' images with one stamp): nothing to learn
            return
        if self.gates.follow_noise(alpha, every_frame):
            self.background.follow_noise(alpha, signal)


def classify_stream(
    classifier: TouchClassifier,
    t_s: np.ndarray,
    pressure: np.ndarray,
    stretch: np.ndarray | None = None,
    volts: np.ndarray | None = None,
) -> list[TouchEvent]:
    """Every event of a whole recording, a touch still going on at its end included.

    Args:
        classifier: a fresh classifier of the recording's pixel grid.
        t_s: ``[T]`` frame times, s.
        pressure: ``[T, H, W]`` pressure images, Pa.
        stretch: ``[T, H, W]`` stretch images (strain), or None.
        volts: ``[T, M]`` the pressure layer's raw frames, V, or None.
    """
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
