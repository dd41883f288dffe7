"""START gates: what lets a touch start before, or besides, its segmented contacts.

* the **pooled image**: the image pooled over a fingertip-sized Gaussian kernel
  (``detect_kernel``) above ``k_detect`` sigmas of its own noise for ``start_frames`` frames
  in one place (:class:`~eit_skin.touch.contacts.PooledDetector`): a weak, slowly pressed
  touch STARTs 50-100 ms before single pixels cross ``k_high``;
* the **matched filter** of the raw frames (with the pressure layer's raw frames and the
  fingertip patterns ``disc_rel``: :class:`~eit_skin.touch.frame_evidence.TouchFilter`, in
  its own pooled detector);
* **flicker and roughness**: while the raw frames flicker like a failing electrode
  (:data:`ELECTRODE_FLICKER`; images alone: the whole sheet, :data:`FLICKER`), a candidate
  STARTs only if it is smoother than noise (``start_roughness``).

After an END each detector waits for a silent image before it can START again. Why each rule
exists: docs/classifier.md.
"""

from __future__ import annotations

import numpy as np

from eit_skin.touch.background import running_mean
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import PooledDetector
from eit_skin.touch.frame_evidence import (
    FrameEvidence,
    TouchFilter,
    electrode_roughness,
    whiteness,
)

FLICKER = 2.0
"""The sheet flickers when the median over its pixels of the raw image's second difference in
time, squared, exceeds this many times its noise variance (``6 v`` for a pixel of raw noise
variance ``v``): noise alone gives about 0.45 (the median of a chi-square with one degree of
freedom), smooth touches 0.4-1, a degrading electrode 2-8."""

ELECTRODE_FLICKER = 10.0
"""With raw frames, the sheet flickers like a fault when one electrode's channels are this
much rougher than the others (:func:`~eit_skin.touch.frame_evidence.electrode_roughness`, a
ratio of median squared second differences: sqrt(10) = 3.2 in amplitude, the pipeline's rule
for a noisy electrode), whatever the image's flicker (how far a fault's noise spreads over
the image depends on the reconstruction); otherwise the flicker is the touch's own and delays
nothing."""


WHITE = 2.0
"""With raw frames, a fault's flicker must also be white in time on its electrode's channels:
their second difference in time, squared, at least this many times their first
(:func:`~eit_skin.touch.frame_evidence.whiteness`; white noise 3, its second frame 2.5, a
ramp's corner 1, a ramp 0): a failing electrode's noise is white, the onset of a press next
to an electrode, which can bend its channels as much, is a ramp."""


class StartGates:
    """The pooled detectors and the flicker and roughness checks of one classifier.

    Args:
        config: thresholds (``detect_kernel``, ``k_detect``, ``start_roughness``, ...).
        evidence: the pressure layer's raw-frame statistics (shared with the classifier).
        disc_rel: ``[H, W, M]`` relative raw-channel change for a fingertip on each pixel,
            or None (no matched filter).
        contact_rel: ``[M, E]`` raw-channel change per electrode contact change, projected
            out of the matched filter, or None.

    Attributes:
        detector: the pooled image's detector (None before calibration, or disabled).
        start_detector: the matched filter's detector (None without raw frames).
        flicker: the sheet's flicker in the latest frame it was computed for.
        faulty: electrodes the imaging leaves out (sorted; their channels are left out).
        relearning: the image maps are learning images changed by a new faulty set: the
            pooled image STARTs nothing (set by the classifier each frame).
        filter_change: ``[M]`` the whitened change the matched filter read this frame (its
            running mean; NaN: channel left out), or None (no filter map this frame).
    """

    def __init__(
        self,
        config: ClassifierConfig,
        evidence: FrameEvidence,
        disc_rel: np.ndarray | None = None,
        contact_rel: np.ndarray | None = None,
    ) -> None:
        self.config = config
        self.evidence = evidence
        self._disc_rel = disc_rel
        self._contact_rel = contact_rel
        self.touch_filter: TouchFilter | None = None  # set at calibration (raw frames given)
        self.detector: PooledDetector | None = None
        self.start_detector: PooledDetector | None = None
        self._armed = True
        self._start_armed = True
        self._start_fresh = False  # the filter's map is of this frame
        self.filter_change: np.ndarray | None = None
        self._raws: list[np.ndarray] = []  # the latest average_frames + 1 raw images
        self._whites: list[np.ndarray] = []  # the latest 3 whitened raw frames (volts given)
        self._rough: list[tuple[float, float, float]] = []  # per candidate frame
        self.flicker = 0.0
        self.faulty: tuple[int, ...] = ()
        self.relearning = False

    def learn(
        self,
        inside: np.ndarray,
        kernel_px: float,
        signals: np.ndarray,
        n_avg: int,
        volts: np.ndarray | None,
    ) -> None:
        """Set up the detectors from the calibration frames.

        Args:
            inside: ``[H, W]`` pixels on the sheet.
            kernel_px: the pooling kernel's standard deviation, pixels.
            signals: ``[T, H, W]`` averaged calibration images minus the baseline, Pa.
            n_avg: frames behind each averaged image.
            volts: ``[T0, M]`` the raw calibration frames if every image came with one, V,
                else None (no matched filter).
        """
        cfg = self.config
        self.detector = PooledDetector(inside, kernel_px, cfg.k_detect, n_avg, cfg.learn_fraction)
        self.detector.learn_noise(signals)
        if self._disc_rel is not None and volts is not None:
            self.touch_filter = TouchFilter(self._disc_rel, inside, self._contact_rel)
            self.start_detector = PooledDetector(
                inside, kernel_px, cfg.k_detect, n_avg, cfg.learn_fraction
            )
            changes = running_mean(self.evidence.whiten(volts), n_avg)
            self.start_detector.learn_pooled_noise(self._filtered(changes))

    def push_image(self, pressure: np.ndarray) -> None:
        """Keep the latest raw pressure image ``[H, W]`` (for flicker and roughness)."""
        self._raws = [*self._raws[-self.config.average_frames :], pressure]

    def push_change(self, change: np.ndarray | None) -> None:
        """Keep the latest whitened raw frame ``[M]`` (None: this frame has none: forget all)."""
        self._whites = [] if change is None else [*self._whites[-2:], change]

    def _filtered(self, change: np.ndarray) -> np.ndarray:
        """The matched-filter maps ``[..., H, W]`` of whitened changes ``[..., M]``."""
        return self.touch_filter.statistic(change, self.evidence.sigma, self.evidence.reference)

    def detect(self, signal: np.ndarray, times: list[float]) -> float | None:
        """Time of the first frame of a pooled detection in ``signal`` ``[H, W]``, or None.

        ``times``: the latest frame times, s (this frame's last).
        """
        faulty = self.faulty
        if self.detector is None:
            return None
        # the rising-press credit assumes the calibrated noise: not with an electrode
        # left out of the images, nor after a frame in which the sheet flickered
        self.detector.rising = not faulty and self.flicker < FLICKER
        run = self.detector.update(signal)
        self._armed = self._armed or not self.detector.hit
        run = run if self._armed else 0  # after an END, until the image fell silent
        run = 0 if self.relearning else run  # a map of other images: no evidence
        start = self.start_detector
        n = 0 if start is None else start.frames_per_sample
        # a running mean of n raw frames, as calibrated (none yet: the image decides)
        self._start_fresh = start is not None and len(self._whites) >= n
        self.filter_change = None
        if self._start_fresh:
            start.rising = self.detector.rising
            change = np.mean(self._whites[-n:], axis=0)
            change[~self.evidence.usable(faulty)] = np.nan
            self.filter_change = change
            filtered = start.update_pooled(self._filtered(change))
            self._start_armed = self._start_armed or not start.hit
            # an electrode's channels flickering like a fault START nothing
            if self._start_armed and not (len(self._whites) >= 3 and self.fault_like()):
                run = max(run, filtered)
        if run >= self.config.start_frames:
            return times[-min(run, len(times))]
        return None

    def follow_roughness(
        self,
        pressure: np.ndarray,
        baseline: np.ndarray,
        offset: float,
        noise_sigma: np.ndarray | None,
        mask: np.ndarray | None,
    ) -> None:
        """Sheet flicker and a touch candidate's roughness from the latest raw image.

        Raw images ``p`` ``[H, W]``; per-pixel raw noise variance ``v``: ``noise_sigma``
        ``[H, W]`` (the averaged image's; None: no check) squared, times ``average_frames``.
        **Flicker**: the median over the sheet of ``(p_k - 2 p_(k-1) + p_(k-2))^2 / (6 v)``
        (:data:`FLICKER`). **Roughness** of a candidate (``mask``: its contact pixels; None:
        the pooled detector's hits), summed over its frames: ``sum (p_k - p_(k-n))^2 - 2 v``
        against ``sum (p_k - baseline - offset)^2 - v``, ``n = average_frames``: the frame
        just before those the contacts were segmented in, so noise gives at least 1 however
        it was selected; a press, release or stroke changes by a fraction of itself.
        """
        cfg = self.config
        if cfg.start_roughness <= 0 or noise_sigma is None:
            return
        if len(self._raws) <= cfg.average_frames:
            return
        var = noise_sigma**2 * cfg.average_frames
        bend = pressure - 2.0 * self._raws[-2] + self._raws[-3]  # second difference in time
        ok = np.isfinite(bend)
        flicker = float(np.median(bend[ok] ** 2 / (6.0 * var[ok]))) if ok.any() else 0.0
        if self.raw_fault_test:
            # the raw frames decide, whatever the reconstruction makes of the fault: GREIT
            # spreads a failing electrode's noise over the sheet (flicker 2-8), a one-step
            # Tikhonov image keeps it near the electrode (1.7, face), Gauss-Newton's image
            # of the idle small disc reads 0.99: no image flicker is a fault's bar. A fault
            # is white in time, a press's onset next to an electrode a ramp (:data:`WHITE`)
            fault = self.fault_like() and self.white_in_time()
            flicker = max(flicker, FLICKER) if fault else 0.0
        elif flicker >= FLICKER and not self.fault_like():
            flicker = 0.0  # the raw frames name no electrode: the touch's own onset
        self.flicker = flicker
        hits = self.detector is not None and self.detector.hit
        if mask is None and not hits:
            self._rough = []
            return
        if mask is None:
            mask = self.detector.z > self.detector.k
        before = self._raws[0]
        ok = mask & np.isfinite(pressure) & np.isfinite(before)
        if not ok.any():
            return
        noise = float(np.sum(var[ok]))
        change = float(np.sum((pressure[ok] - before[ok]) ** 2)) - 2.0 * noise
        level = float(np.sum((pressure[ok] - baseline[ok] - offset) ** 2)) - noise
        self._rough = [*self._rough[-cfg.lookback_frames :], (change, level, flicker)]

    @property
    def raw_fault_test(self) -> bool:
        """Whether the latest three raw frames and the channel map can name a fault."""
        return len(self._whites) >= 3 and self.evidence.channel_electrodes is not None

    def fault_like(self) -> bool:
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

    def white_in_time(self) -> bool:
        """Whether the roughest electrode's channels are white in time (:data:`WHITE`).

        Needs three raw frames and the channel map (:attr:`raw_fault_test`).
        """
        w = self._whites
        usable = self.evidence.usable(self.faulty)
        bend = np.where(usable, w[-1] - 2.0 * w[-2] + w[-3], np.nan)
        step = np.where(usable, w[-1] - w[-2], np.nan)
        return not whiteness(bend, step, self.evidence.channel_electrodes) < WHITE

    def smooth_enough(self) -> bool:
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

    def seeing(self) -> PooledDetector:
        """The detector that sees a touch before any contact.

        The raw frames' filter when it has a hit, else the pooled image.
        """
        start = self.start_detector
        return start if start is not None and start.hit else self.detector

    def follow_noise(self, alpha: float, every_frame: bool = False) -> bool:
        """Teach the detectors' noise (weight ``alpha``).

        False while the pooled image is not quiet: a weak touch may be building up, and no
        noise map learns then; ``every_frame``: the pooled map learns even so (its images
        changed, so its quiet means nothing).
        """
        if self.detector is None:
            return True
        if not (self.detector.quiet or every_frame):
            return False
        self.detector.follow_noise(alpha)
        start = self.start_detector
        if start is not None and self._start_fresh and start.quiet:  # its map quiet too
            start.follow_noise(alpha)
        return True

    def touch_started(self) -> None:
        """A touch started: the candidate's roughness starts afresh."""
        self._rough = []

    def touch_ended(self) -> None:
        """A touch ended: each detector waits for a silent image before it STARTs again."""
        self._armed = False
        self._start_armed = False
