"""The no-load reference of difference imaging: capture, re-zero, drift and posture.

Difference imaging compares every frame with a reference frame of the untouched skin.
:class:`ReferenceTracker` owns that reference for one layer:

* **Capture.** The first ``n_frames`` frames after start (or after :meth:`rezero`) are
  averaged into the reference (seed paper, Fig. 5). No image is made meanwhile. The skin
  must not be touched during those frames (``n_frames / rate`` seconds, 0.4 s at 50 Hz with
  the default 20 frames). Non-finite values are missing values: each channel averages its
  finite values, a frame without any is skipped, and a channel missing in every captured
  frame stays NaN in the reference (so it is left out of the images until the next capture)
  rather than blocking the capture for ever.
* **Noise.** The spread of the captured frames gives the per-channel noise, from which the
  contact threshold of the drift tracker is derived.
* **Drift.** While *no contact* is present (no element's change exceeds ``contact_k``
  times its noise), the reference follows the frames with an exponential moving average of
  time constant ``drift_time_constant_s`` (default 60 s), so slow temperature and ageing
  drift is absorbed but a touch is never learnt into the baseline. During a touch the
  baseline is frozen. Missing (non-finite) values of a frame leave their channel unchanged.
* **Posture.** For skins over joints a :class:`PostureReferences` table (references captured
  at several joint angles by the calibration sweep) replaces the fixed reference: the
  reference is interpolated at the current joint angle, and drift tracking acts on a
  per-channel gain relative to that table.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class PostureReferences:
    """No-load references at several joint angles, for one layer.

    Attributes:
        joint: name of the joint (``sensor_msgs/JointState.name``).
        angles_rad: ``[K]`` strictly increasing joint angles, radians.
        references_v: ``[K, M]`` mean no-load frames at those angles, volts.
    """

    joint: str
    angles_rad: np.ndarray
    references_v: np.ndarray

    def __post_init__(self) -> None:
        angles = np.asarray(self.angles_rad, dtype=np.float64)
        refs = np.asarray(self.references_v, dtype=np.float64)
        if angles.ndim != 1 or angles.size < 1 or refs.shape[:1] != angles.shape:
            raise ValueError(
                f"posture references need angles [K] and references [K, M], "
                f"got {angles.shape} and {refs.shape}"
            )
        if angles.size > 1 and not np.all(np.diff(angles) > 0):
            raise ValueError("posture reference angles must be strictly increasing")
        if not (np.isfinite(angles).all() and np.isfinite(refs).all()):
            raise ValueError("posture references contain NaN or Inf")
        object.__setattr__(self, "angles_rad", angles)
        object.__setattr__(self, "references_v", refs)

    @property
    def n_measurements(self) -> int:
        return int(self.references_v.shape[1])

    def at(self, angle_rad: float) -> np.ndarray:
        """Reference ``[M]`` volts at a joint angle: linear between neighbours, clamped."""
        a = self.angles_rad
        if a.size == 1 or angle_rad <= a[0]:
            return self.references_v[0].copy()
        if angle_rad >= a[-1]:
            return self.references_v[-1].copy()
        i = int(np.searchsorted(a, angle_rad)) - 1
        w = (angle_rad - a[i]) / (a[i + 1] - a[i])
        return (1.0 - w) * self.references_v[i] + w * self.references_v[i + 1]

    def save(self, path: str | Path, layer: str) -> None:
        """Write ``<layer>/angles_rad``, ``<layer>/references_v`` and the joint into an npz."""
        from eit_skin.io.npz import write_npz_atomic

        path = Path(path)
        arrays = {}
        if path.is_file():
            with np.load(path) as existing:
                arrays = dict(existing)
        arrays[f"{layer}/angles_rad"] = self.angles_rad
        arrays[f"{layer}/references_v"] = self.references_v
        arrays["joint"] = np.array(self.joint)
        write_npz_atomic(path, **arrays)

    @classmethod
    def load(cls, path: str | Path, layer: str) -> PostureReferences:
        """Read one layer's table from a calibration file; ValueError names file and key."""
        path = Path(path)
        try:
            with np.load(path) as data:
                return cls(
                    str(data["joint"]),
                    data[f"{layer}/angles_rad"],
                    data[f"{layer}/references_v"],
                )
        except KeyError as error:
            raise ValueError(f"{path}: missing key {error.args[0]!r}") from error
        except (OSError, ValueError) as error:
            raise ValueError(f"{path}: {error}") from error


class JointAngleHistory:
    """Recent joint angles by time stamp, to look up the angle at a frame's acquisition time.

    Joint states and EIT frames travel on different topics with different latencies, so
    "the latest angle" at a frame's arrival can be several frames off while the joint
    moves; interpolating at the frame's stamp is not.

    Args:
        span_ns: how much history to keep, ns.
    """

    def __init__(self, span_ns: int = 5_000_000_000) -> None:
        self.span_ns = span_ns
        self._stamps: list[int] = []
        self._angles: list[float] = []

    def add(self, stamp_ns: int, angle_rad: float) -> None:
        if self._stamps and stamp_ns <= self._stamps[-1]:
            if stamp_ns == self._stamps[-1]:
                self._angles[-1] = angle_rad
            return  # out of order: ignore
        self._stamps.append(stamp_ns)
        self._angles.append(angle_rad)
        cut = 0
        while cut < len(self._stamps) and stamp_ns - self._stamps[cut] > self.span_ns:
            cut += 1
        if cut:
            del self._stamps[:cut], self._angles[:cut]

    def at(self, stamp_ns: int) -> float:
        """Angle at ``stamp_ns``, rad: linear between samples, held beyond them; NaN if empty."""
        if not self._stamps:
            return float("nan")
        return float(np.interp(stamp_ns, self._stamps, self._angles))

    def covers(self, stamp_ns: int) -> bool:
        """Whether a joint state at or after ``stamp_ns`` has arrived (``at`` interpolates)."""
        return bool(self._stamps) and stamp_ns <= self._stamps[-1]


class PostureSync:
    """Pairs each frame with the joint angle at its acquisition time, whatever the delays.

    A frame whose stamp is newer than the newest joint state waits (in arrival order) until a
    joint state at or after its stamp arrives, or until it has waited ``max_wait_s`` of
    receive time: then it goes on with the newest angle held, and is counted in ``late``.
    Frames never overtake each other, so a layer's frames stay in order.

    Args:
        history: the joint angles received so far.
        max_wait_s: longest a frame waits for its joint state, s of receive time.
    """

    def __init__(self, history: JointAngleHistory, max_wait_s: float = 0.5) -> None:
        self.history = history
        self.max_wait_ns = int(max_wait_s * 1e9)
        self._waiting: deque[tuple[int, int, object]] = deque()  # (stamp, received, frame)
        self.late = 0

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    def push(self, stamp_ns: int, received_ns: int, item: object) -> list[tuple[object, float]]:
        """Queue a frame; returns the frames now ready, with their angles (rad), in order."""
        self._waiting.append((stamp_ns, received_ns, item))
        return self.ready(received_ns)

    def ready(self, now_ns: int) -> list[tuple[object, float]]:
        """Frames whose angle is known, or that waited too long (held angle), in order."""
        out = []
        while self._waiting:
            stamp, received, item = self._waiting[0]
            if not self.history.covers(stamp):
                if now_ns - received < self.max_wait_ns:
                    break
                self.late += 1
            self._waiting.popleft()
            out.append((item, self.history.at(stamp)))
        return out


class ReferenceTracker:
    """Reference frame of one layer (see the module docstring for the behaviour).

    Args:
        n_measurements: M, values per frame.
        n_frames: frames averaged into a fresh reference.
        drift_time_constant_s: time constant of drift tracking, seconds (0 disables it).
        contact_k: a frame counts as touched when an element's change exceeds this many
            times its noise.
        posture: optional posture reference table.
    """

    def __init__(
        self,
        n_measurements: int,
        n_frames: int = 20,
        drift_time_constant_s: float = 60.0,
        contact_k: float = 5.0,
        posture: PostureReferences | None = None,
    ) -> None:
        if posture is not None and posture.n_measurements != n_measurements:
            raise ValueError(
                f"posture references have {posture.n_measurements} values per frame, "
                f"the layer {n_measurements}"
            )
        self.n_measurements = n_measurements
        self.n_frames = max(1, int(n_frames))
        self.drift_time_constant_s = drift_time_constant_s
        self.contact_k = contact_k
        self.posture = posture
        self.angle_rad = 0.0
        self.rezero()

    def rezero(self) -> None:
        """Forget the reference and capture a new one from the next ``n_frames`` frames."""
        self._captured: list[np.ndarray] = []
        self.captured_frames: np.ndarray | None = None  # [n_frames, M] of the last capture
        self._base: np.ndarray | None = None  # fixed reference, or gain vs. posture table
        self.noise_v: np.ndarray | None = None
        self.element_noise: np.ndarray | None = None
        self.captured_at_s: float | None = None
        self.updated_at_s: float | None = None
        self.drift_updates = 0

    @property
    def ready(self) -> bool:
        return self._base is not None

    def reference(self) -> np.ndarray:
        """Current reference ``[M]`` volts (at the current joint angle with posture)."""
        if self._base is None:
            raise RuntimeError("reference not captured yet")
        if self.posture is None:
            return self._base
        return self._base * self.posture.at(self.angle_rad)

    def capture(self, frame_v: np.ndarray, t_s: float) -> bool:
        """Add a frame ``[M]`` V to the capture; returns True when the reference became ready.

        Non-finite values are missing (see the module docstring); a frame without any finite
        value does not count. Raises ValueError for a frame that is not ``[M]``.
        """
        frame = self._frame(frame_v)
        if not np.isfinite(frame).any():
            return False
        self._captured.append(frame)
        if len(self._captured) < self.n_frames:
            return False
        stack = np.stack(self._captured)
        finite = np.isfinite(stack)
        count = finite.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(finite, stack, 0.0).sum(axis=0) / count  # NaN where count == 0
            spread = np.where(finite, stack - mean, 0.0)
            self.noise_v = np.sqrt((spread**2).sum(axis=0) / np.maximum(count - 1, 1))
        self.noise_v[count == 0] = np.nan
        self._set_base(mean)
        self.captured_frames = stack
        self._captured = []
        self.captured_at_s = self.updated_at_s = t_s
        return True

    def set_reference(self, reference_v: np.ndarray, t_s: float) -> None:
        """Use a given no-load frame ``[M]`` V as if it had just been captured at ``t_s``.

        For a reference measured elsewhere (the ``reference`` of an offline frames file). The
        noise stays unknown (``noise_v``, ``captured_frames`` None) until
        :meth:`set_element_noise`; until then every frame counts as touched (no drift).
        """
        reference = self._frame(reference_v)
        self.rezero()
        self._set_base(reference)
        self.captured_at_s = self.updated_at_s = t_s

    def _frame(self, frame_v: np.ndarray) -> np.ndarray:
        frame = np.asarray(frame_v, dtype=np.float64)
        if frame.shape != (self.n_measurements,):
            raise ValueError(
                f"a frame must be [{self.n_measurements}] volts, got shape {frame.shape}"
            )
        return frame

    def _set_base(self, mean_v: np.ndarray) -> None:
        if self.posture is None:
            self._base = mean_v.copy()
        else:
            table = self.posture.at(self.angle_rad)
            self._base = np.divide(mean_v, table, out=np.ones_like(mean_v), where=table != 0)

    def set_element_noise(self, element_std: np.ndarray) -> None:
        """Per-element noise of the reconstructed change (from the captured frames)."""
        self.element_noise = np.maximum(np.asarray(element_std, dtype=np.float64), 1e-12)

    def touching(self, element_change: np.ndarray) -> bool:
        """Whether a reconstructed change ``[N]`` shows a contact (above ``contact_k`` noise)."""
        if self.element_noise is None:
            return True  # unknown noise: never learn into the baseline
        score = np.abs(np.asarray(element_change, dtype=np.float64)) / self.element_noise
        return bool(np.fmax.reduce(score, initial=0.0) > self.contact_k)  # NaN ignored

    def track(self, frame_v: np.ndarray, t_s: float, touching: bool) -> None:
        """Drift tracking: follow an untouched frame slowly; freeze during a touch.

        Channels whose value is non-finite in the frame keep their reference.
        """
        alpha = None if touching else self.drift_alpha(t_s)
        if alpha is None:
            return
        frame = self._frame(frame_v)
        if self.posture is None:
            target = frame
        else:
            table = self.posture.at(self.angle_rad)
            target = np.divide(frame, table, out=self._base.copy(), where=table != 0)
        finite = np.isfinite(target) & np.isfinite(self._base)  # an Inf reference stays
        all_finite = bool(finite.all())
        if not all_finite and not finite.any():
            return
        if all_finite:  # the common case: every channel follows
            self.follow(self._base + alpha * (target - self._base), t_s)
        else:
            with np.errstate(invalid="ignore"):  # inf targets: masked out below
                moved = self._base + alpha * (target - self._base)
            self.follow(np.where(finite, moved, self._base), t_s)

    def drift_alpha(self, t_s: float) -> float | None:
        """Weight in [0, 1) an untouched frame at ``t_s`` s gets in the reference.

        None while there is no reference or tracking is off.
        """
        if self._base is None or self.drift_time_constant_s <= 0:
            return None
        dt = 0.0 if self.updated_at_s is None else max(0.0, t_s - self.updated_at_s)
        return 1.0 - math.exp(-dt / self.drift_time_constant_s)

    def follow(self, base_v: np.ndarray, t_s: float) -> None:
        """Take ``base_v`` ``[M]`` V as the reference followed up to ``t_s`` s.

        ``base_v``: the reference moved towards the frame with :meth:`drift_alpha` ``(t_s)``.
        """
        self._base = base_v
        self.updated_at_s = t_s
        self.drift_updates += 1

    def age_s(self, now_s: float) -> float:
        """Seconds since the reference was captured (NaN before)."""
        return float("nan") if self.captured_at_s is None else now_s - self.captured_at_s


def bin_posture_frames(
    joint: str,
    angles_rad: np.ndarray,
    frames_v: np.ndarray,
    bin_width_rad: float = np.deg2rad(10.0),
    min_frames: int = 5,
) -> PostureReferences:
    """Average untouched frames of a joint sweep into references per angle bin.

    Args:
        joint: joint name.
        angles_rad: ``[T]`` joint angle at each frame, radians.
        frames_v: ``[T, M]`` frames, volts (non-finite frames are ignored).
        bin_width_rad: width of the angle bins, radians.
        min_frames: bins with fewer frames are dropped.

    Returns:
        references at the mean angle of every populated bin.

    Raises:
        ValueError: fewer than one populated bin, or mismatched shapes.
    """
    angles = np.asarray(angles_rad, dtype=np.float64)
    frames = np.asarray(frames_v, dtype=np.float64)
    if frames.ndim != 2 or angles.shape != (frames.shape[0],):
        raise ValueError(f"need angles [T] and frames [T, M], got {angles.shape}, {frames.shape}")
    good = np.isfinite(angles) & np.isfinite(frames).all(axis=1)
    angles, frames = angles[good], frames[good]
    if angles.size == 0:
        raise ValueError("no usable frames in the posture sweep")
    index = np.floor((angles - angles.min()) / bin_width_rad).astype(np.int64)
    counts = np.bincount(index)
    populated = np.flatnonzero(counts >= min_frames)
    if populated.size == 0:
        raise ValueError(f"no angle bin has {min_frames} frames; sweep slower or widen the bins")
    sums = np.zeros((counts.size, frames.shape[1]))
    np.add.at(sums, index, frames)
    mean_angle = np.bincount(index, weights=angles)[populated] / counts[populated]
    return PostureReferences(joint, mean_angle, sums[populated] / counts[populated, None])
