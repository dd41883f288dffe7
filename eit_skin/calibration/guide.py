"""Calibration by hand: pair the presses found in a frame stream with printed targets.

A person presses a finger on each numbered target of the printed template
(:mod:`~eit_skin.calibration.template`) in turn. :class:`PressDetector` finds each press and
its release from the touch classifier's START/END events of the layer's images and keeps,
per press, the frames it needs: its **baseline** (mean of the frames ``baseline_s`` before
START, ``guard_s`` clear of it) and its **full-press frame** (mean of the frames between
START and END whose change is at least ``PLATEAU_FRACTION`` of the press's largest).
:class:`GuidedSession` judges each press against the prompted target and refuses one that is

* **too short**: held less than ``min_hold_s`` (a tap: no settled full-press frame);
* **too weak**: its change is below ``min_snr`` times the frames' own noise (RMS over the
  channels of the change per channel's noise standard deviation), or its image peak is below
  ``min_relative`` of the median accepted press's (much lighter than the person's others);
* **on two targets**: the classifier saw two touches at once, or the image's rough position
  is nearer another target than the prompted one and more than ``max_offset_m`` from it;

with the reason, and lets the person redo a target (``answer(..., "redo")``). A refused
press is redone by the next press. :meth:`GuidedSession.session` gives the press session
``eit-skin calibrate`` reads (positions: the targets).
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np

from eit_skin.calibration.session import MIN_PRESSES, PressSession
from eit_skin.touch.events import TouchEvent

PLATEAU_FRACTION = 0.9
"""Frames whose change from the baseline is at least this share of the press's largest make
up its full-press frame."""

ANSWERS = ("ok", "redo")
QUIET_DIFFERENCES = 1000
"""Latest untouched frame-to-frame differences kept for the noise estimate."""

CHI2_1_MEDIAN = 0.4549
"""Median of a chi-square variable with one degree of freedom."""

TYPICAL_AFTER = 3
"""Accepted presses after which a press is compared with the session's typical one."""
"""What a person may answer after an accepted press."""


@dataclass(frozen=True)
class GuideRules:
    """When a press is refused, and which frames make it.

    Attributes:
        min_hold_s: shortest START-to-END time of a press, s.
        min_snr: smallest RMS change of a press, in noise standard deviations per channel.
        min_relative: smallest image peak relative to the median of the accepted presses
            (once there are :data:`TYPICAL_AFTER`): a press much lighter than the person's
            others (the image's peak, unlike the raw change, does not grow near electrodes).
        max_offset_m: an image position farther than this from the prompted target and
            nearer another target is refused, m; 0: no position check (skins whose images do
            not localise).
        baseline_s: length of the baseline window before START, s.
        guard_s: gap between the baseline window and START, s.
    """

    min_hold_s: float = 0.3
    min_snr: float = 10.0
    min_relative: float = 0.25
    max_offset_m: float = 0.0
    baseline_s: float = 0.3
    guard_s: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "min_hold_s",
            "min_snr",
            "min_relative",
            "max_offset_m",
            "baseline_s",
            "guard_s",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")
        if not self.baseline_s > 0:
            raise ValueError(f"baseline_s: must be > 0 s, got {self.baseline_s}")


@dataclass(frozen=True, eq=False)
class DetectedPress:
    """One press found in the stream (START to END of one touch).

    Attributes:
        t_start_s, t_end_s: START and END times, s.
        image_xy: ``[2]`` the image's position of the touch (classifier centroid), m.
        snr: RMS over channels of the change per channel's noise standard deviation.
        peak_pa: the image's largest pressure during the touch, Pa (the layer's unit).
        frame: ``[M]`` mean of the full-press frames, V (or device units).
        baseline: ``[M]`` mean of the baseline frames.
        together: most touches seen at once during it (2: two fingers or two targets).
        label: the classifier's label.
    """

    t_start_s: float
    t_end_s: float
    image_xy: np.ndarray
    snr: float
    peak_pa: float
    frame: np.ndarray
    baseline: np.ndarray
    together: int
    label: str

    @property
    def hold_s(self) -> float:
        return self.t_end_s - self.t_start_s


class PressDetector:
    """Presses (START..END of the classifier's touches) with their frames, one frame at a time.

    Args:
        rules: baseline window (``baseline_s``, ``guard_s``).
        memory_s: frames kept, s (the longest press plus its baseline).
    """

    def __init__(self, rules: GuideRules, memory_s: float = 30.0) -> None:
        self.rules = rules
        self.memory_s = memory_s
        self._frames: deque[tuple[float, np.ndarray]] = deque()
        self._active: set[int] = set()
        self._together: dict[int, int] = {}
        self._peak: dict[int, float] = {}
        self._quiet_sq: deque[np.ndarray] = deque(maxlen=QUIET_DIFFERENCES)
        self._last_quiet: np.ndarray | None = None
        self._last_end_s = -np.inf

    def noise_std(self) -> np.ndarray | None:
        """``[M]`` per-channel noise standard deviation from consecutive untouched frames.

        The median of the squared differences over ``2 x CHI2_1_MEDIAN`` (robust to a jump).
        """
        if len(self._quiet_sq) < 2:
            return None
        with warnings.catch_warnings():  # a channel missing in every frame: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            d2 = np.nanmedian(np.array(self._quiet_sq), axis=0)
        return np.sqrt(d2 / (2.0 * CHI2_1_MEDIAN))

    def step(
        self, t_s: float, frame: np.ndarray | None, events: list[TouchEvent]
    ) -> list[DetectedPress]:
        """The presses that ended with one frame ``[M]`` at ``t_s`` and its classifier events.

        ``frame`` None: events only (the END of a touch still going on at the stream's end).
        """
        if frame is not None:
            frame = np.asarray(frame, float)
            self._frames.append((t_s, frame))
            while self._frames and self._frames[0][0] < t_s - self.memory_s:
                self._frames.popleft()
        out = []
        for event in events:
            peak = max(self._peak.get(event.touch_id, 0.0), float(event.peak_pa))
            self._peak[event.touch_id] = peak
            if event.state in ("start", "update"):
                self._active.add(event.touch_id)
                for touch in self._active:
                    self._together[touch] = max(self._together.get(touch, 1), len(self._active))
            if event.state == "end":
                self._active.discard(event.touch_id)
                together = self._together.pop(event.touch_id, 1)
                press = self._press(event, together, self._peak.pop(event.touch_id))
                self._last_end_s = max(self._last_end_s, event.t_end_s)
                if press is not None:
                    out.append(press)
        if frame is None:
            return out
        if not self._active and t_s > self._last_end_s + self.rules.baseline_s:
            if self._last_quiet is not None and self._last_quiet.shape == frame.shape:
                self._quiet_sq.append((frame - self._last_quiet) ** 2)
            self._last_quiet = frame
        else:
            self._last_quiet = None
        return out

    def _press(self, event: TouchEvent, together: int, peak_pa: float) -> DetectedPress | None:
        """The press of a touch that just ended, or None if its frames are no longer kept."""
        t = np.array([s for s, _ in self._frames])
        frames = np.array([f for _, f in self._frames])
        stop = event.t_start_s - self.rules.guard_s
        before = (t <= stop) & (t >= stop - self.rules.baseline_s)
        during = (t >= event.t_start_s) & (t <= event.t_end_s)
        if not before.any() or not during.any():
            return None
        with warnings.catch_warnings():  # a channel missing (NaN) in every frame stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            baseline = np.nanmean(frames[before], axis=0)
            change = np.sqrt(np.nansum((frames[during] - baseline) ** 2, axis=1))
            plateau = frames[during][change >= PLATEAU_FRACTION * change.max()]
            frame = np.nanmean(plateau, axis=0)
        sigma = self.noise_std()
        if sigma is None:
            snr = np.inf
        else:
            floor = max(float(np.nanmedian(sigma)), np.finfo(float).tiny) * 1e-3
            snr = float(np.sqrt(np.nanmean(((frame - baseline) / np.maximum(sigma, floor)) ** 2)))
        return DetectedPress(
            event.t_start_s,
            event.t_end_s,
            np.asarray(event.centroid_m, float),
            snr,
            peak_pa,
            frame,
            baseline,
            together,
            event.label,
        )


@dataclass(frozen=True, eq=False)
class Verdict:
    """What the guide made of one press.

    Attributes:
        press: the press.
        target: index (0-based) of the target it was made for.
        accepted: whether it was taken for that target.
        reason: why it was refused ("" if accepted).
    """

    press: DetectedPress
    target: int
    accepted: bool
    reason: str = ""


class GuidedSession:
    """Targets prompted in order, presses judged and paired with them, redos allowed.

    Args:
        targets: ``[N, 2]`` printed targets, m (patch frame), in prompting order.
        rules: refusal rules.
        source: where the frames came from (messages, the session's source).
    """

    def __init__(self, targets: np.ndarray, rules: GuideRules, source: str = "<stream>") -> None:
        self.targets = np.asarray(targets, float)
        if self.targets.ndim != 2 or self.targets.shape[1] != 2 or len(self.targets) < 1:
            raise ValueError(f"targets: shape {self.targets.shape}, want [N, 2]")
        self.rules = rules
        self.source = source
        self.current = 0
        self.accepted: dict[int, DetectedPress] = {}
        self.log: list[Verdict] = []

    @property
    def done(self) -> bool:
        return self.current >= len(self.targets)

    def judge(self, press: DetectedPress) -> Verdict:
        """Judge ``press`` for the current target; accepted presses await :meth:`answer`."""
        if self.done:
            raise ValueError("every target has its press already")
        k = self.current
        rules = self.rules
        reason = ""
        distance = np.linalg.norm(self.targets - press.image_xy, axis=1)
        nearest = int(np.argmin(distance))
        if press.hold_s < rules.min_hold_s:
            reason = f"too short: held {press.hold_s:.2f} s, need {rules.min_hold_s:g} s"
        elif press.snr < rules.min_snr:
            reason = (
                f"too weak: change {press.snr:.1f} x noise, need {rules.min_snr:g} x (press harder)"
            )
        elif len(self.accepted) >= TYPICAL_AFTER and press.peak_pa < rules.min_relative * (
            typical := float(np.median([p.peak_pa for p in self.accepted.values()]))
        ):
            reason = (
                f"too weak: image peak {press.peak_pa / 1e3:.2g} kPa, under "
                f"{rules.min_relative:g} of your typical press ({typical / 1e3:.2g} kPa; press "
                "as hard as before)"
            )
        elif press.together > 1:
            reason = f"on two targets: {press.together} touches at once"
        elif rules.max_offset_m > 0 and distance[k] > rules.max_offset_m and nearest != k:
            reason = (
                f"on another target: the image places it {distance[k] * 1e3:.0f} mm from "
                f"target {k + 1}, nearer target {nearest + 1}"
            )
        verdict = Verdict(press, k, not reason, reason)
        self.log.append(verdict)
        if verdict.accepted:
            self.accepted[k] = press
            self.current += 1
        return verdict

    def answer(self, verdict: Verdict, reply: str) -> None:
        """The person's reply to an accepted press: ``"ok"`` keeps it, ``"redo"`` drops it."""
        if reply not in ANSWERS:
            raise ValueError(f"answer {reply!r}: want one of {', '.join(ANSWERS)}")
        if (
            reply == "redo"
            and verdict.accepted
            and self.accepted.get(verdict.target) is verdict.press
        ):
            del self.accepted[verdict.target]
            self.current = verdict.target

    def session(self) -> PressSession:
        """The press session of every target (positions: the targets; frames: their presses).

        Raises:
            ValueError: a target without an accepted press (named), or fewer targets than
                ``eit-skin calibrate`` needs.
        """
        missing = [k + 1 for k in range(len(self.targets)) if k not in self.accepted]
        if missing:
            raise ValueError(
                f"{self.source}: target(s) {', '.join(map(str, missing[:10]))} have no accepted "
                f"press ({len(missing)} of {len(self.targets)} missing): nothing written"
            )
        if len(self.targets) < MIN_PRESSES:
            raise ValueError(
                f"{self.source}: {len(self.targets)} targets, calibrate needs {MIN_PRESSES}"
            )
        order = range(len(self.targets))
        frames = np.array([self.accepted[k].frame for k in order])
        baselines = np.array([self.accepted[k].baseline for k in order])
        return PressSession(baselines[0], frames, self.targets.copy(), None, baselines, self.source)
