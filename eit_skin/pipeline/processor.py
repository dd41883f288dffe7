"""The per-frame pipeline of one layer, ROS-free, shared by the node and the offline commands.

The reconstruction node and ``eit-skin reconstruct`` / ``eit-skin classify`` all run
:class:`LayerProcessor`.

Per frame ``[M]`` volts at frame time ``t_s``:

1. **Flags.** Channels whose flag byte has an :data:`~eit_skin.frames.EXCLUDING_FLAGS` bit
   (saturated, invalid) become missing values (NaN), exactly like the NaN that
   ``eit-skin frames export`` writes for them; a frame with flags and the same frame with NaN
   there are the same frame to everything below. Then the values no sheet can give are
   flagged the same way (:func:`~eit_skin.frames.implausible_flags`): beyond the board's full
   scale (the layer's ``full_scale_v``, when stated: ``FLAG_OUT_OF_RANGE``), or jumped by more
   than ``jump_k`` times the channel's measured noise since the previous frame (``FLAG_JUMP``;
   once the reference's noise is known; a jump must be one from the previous frame and from
   the channel's last value kept). A one-frame spike is left out in its frame only; a step
   that stays is taken from its second frame on; an input that jumps every frame (floating)
   is left out every frame until the fault check names its electrode.
   Counted in :attr:`LayerProcessor.values_out_of_range` and
   :attr:`LayerProcessor.values_jumped`, the last frame's in :attr:`LayerProcessor.last_flags`.
2. **Reference.** Until the reference is ready (:class:`ReferenceTracker`: capture of the
   first ``reference_frames`` frames, or :meth:`LayerProcessor.set_reference`) no image is
   made. The reference is checked (:meth:`LayerImager.use_reference`): channels whose
   reference is 0, NaN, Inf, near zero or of the wrong sign are left out, named in
   :attr:`LayerProcessor.reference_report`; an unusable reference (all zero, more than half of
   the channels bad) sets :attr:`LayerProcessor.reference_error` and no frame is imaged until
   the next capture; so is a reference whose frames are more than
   ``CONDUCTANCE_RATIO_LIMIT`` times larger or smaller than it (a reference in another unit).
   The captured frames give the per-channel noise that weights the channels
   and chooses the hyperparameter, and the per-element noise of the contact decision.
3. **Faults.** The captured frames, and then every ``fault_check_period_s`` of FRAME time
   (not wall time: an offline run over recorded frames checks at the same frames as the node
   did) the last :data:`FAULT_WINDOW_FRAMES` frames, are checked for faulty electrodes
   (at frame times ``(k + phase) * period``, the phase a fixed fraction named by the patch and
   layer, :func:`fault_check_phase`: the patches of one process, started together, do not all
   check on the same frame, which held each frame behind it for as many checks)
   (:func:`~eit_skin.inverse.electrode_faults.faulty_electrodes`); their channels stay out of
   the images until the next check. The element noise is re-estimated without them, since
   a floating electrode's channels would otherwise inflate it so much that no touch counts
   as a contact and drift tracking learns touches into the reference.
4. **Image.** Relative change per element against the current reference, then contact
   decision and drift tracking (the reference follows untouched frames), then the physical
   image (the layer's unit) on the image grid. A frame of a pressure layer whose every
   channel is used takes these four in one planned step
   (:mod:`eit_skin.pipeline.frame_plan`: numpy's or the compiled kernel, bit for bit alike);
   the others take the reconstructor's general path.

Same frames, same times, same settings: bit-identical images, whichever process runs it.
"""

from __future__ import annotations

import hashlib
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from eit_skin.frames import (
    FLAG_INVALID,
    FLAG_JUMP,
    FLAG_OUT_OF_RANGE,
    flagged_as_nan,
    implausible_flags,
)
from eit_skin.inverse.channel_noise import UnusableReferenceError
from eit_skin.inverse.electrode_faults import faulty_electrodes
from eit_skin.patch.material import CONDUCTANCE_RATIO_LIMIT
from eit_skin.pipeline.builder import LayerImager, ReferenceReport
from eit_skin.pipeline.frame_kernel import compiled_step, frame_step
from eit_skin.pipeline.frame_plan import FrameChecks, FrameResult
from eit_skin.pipeline.reference import PostureReferences, ReferenceTracker

#: Defaults shared by the node's parameters and the offline commands' options.
DEFAULT_DRIFT_TIME_CONSTANT_S = 60.0
DEFAULT_CONTACT_K = 5.0
DEFAULT_FAULT_CHECK_PERIOD_S = 1.0
#: A one-frame change above this many times the channel's noise is flagged ``FLAG_JUMP``:
#: 7x the largest of any simulated touch (688 noise sigmas: arm, face, elbow, demo and random
#: scripts at 50 Hz) and 25x the largest of the real recordings (197: data/real/, sciospec);
#: a wrong flag costs the channel one frame.
DEFAULT_JUMP_K = 5000.0
#: Median channel noise below this fraction of the reference's RMS is no measured noise (a
#: millionth, 20 bits: model voltages, or one frame repeated): no jump check on it.
MIN_MEASURED_NOISE = 1e-6
#: Frames the fault check looks at, and the fewest it needs.
FAULT_WINDOW_FRAMES = 50
MIN_FAULT_FRAMES = 10


def fault_check_phase(patch_name: str, layer_name: str) -> float:
    """Fraction in [0, 1) of the fault-check period a layer checks at: a hash of its names.

    Deterministic (the node and the offline commands check at the same frames) and spread
    evenly over the period however alike the names are (``arm_1``, ``arm_2``: a 64-bit
    BLAKE2 digest, not a CRC, whose values for such names cluster).
    """
    digest = hashlib.blake2b(f"{patch_name}/{layer_name}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") / 2**64


def stamp_to_s(stamp_ns: int) -> float:
    """Frame time, s, of a header stamp, ns: bit for bit the ``t`` of ``eit-skin frames export``."""
    return int(stamp_ns) / 1e9


@dataclass(frozen=True, eq=False)
class LayerImages:
    """What one imaged frame gives.

    Attributes:
        t_s: frame time, s.
        values: float32 ``[N]`` relative conductivity change per inverse-mesh element.
        image: float32 ``[H, W]`` physical image in the layer's unit (Pa for pressure,
            strain for stretch), NaN outside the sheet and in holes.
        touching: whether the frame showed a contact (drift tracking froze).
        channels_used: channels that went into the image (of M).
        faulty_electrodes: electrodes left out of this image (found faulty by the latest
            fault check), sorted indices; what the touch classifier needs to know.
        frame_v: ``[M]`` the frame that was imaged, V, flagged channels NaN (the touch
            classifier's raw evidence: ``TouchClassifier.step(volts=...)``).
    """

    t_s: float
    values: np.ndarray
    image: np.ndarray
    touching: bool
    channels_used: int
    faulty_electrodes: tuple[int, ...] = ()
    frame_v: np.ndarray | None = None


class LayerProcessor:
    """Frames of one layer -> images, with reference, drift, flags and fault handling.

    Args:
        imager: the layer's reconstruction chain.
        reference_frames: frames averaged into a captured reference; ``None``/0: the layer's
            ``solver.reference_frames``.
        drift_time_constant_s: drift tracking time constant while untouched, s; 0: off.
        contact_k: a change above ``contact_k`` times the element noise is a contact.
        posture: optional posture reference table (the joint angle comes with each frame).
        fault_check_period_s: frame time between fault checks, s; <= 0: never.
        fault_check_phase: checks fall at frame times ``(k + phase) * period``, phase in
            [0, 1) (:func:`fault_check_phase`).
        compiled_step: False: every frame takes the numpy path (the reference
            implementation the compiled step is tested against).
        jump_k: a one-frame change above ``jump_k`` times the channel's measured noise is
            flagged ``FLAG_JUMP`` and left out; <= 0: no jump check (frames that are not a
            time series: per-press references).

    >>> from eit_skin.patch.loading import load_patch
    >>> from eit_skin.resources import config_path
    >>> from eit_skin.sim.simulator import SkinSimulator
    >>> patch = load_patch(config_path("face"))
    >>> processor = LayerProcessor(LayerImager.build(patch.layers[0]))
    >>> recording = SkinSimulator(patch, "push", seed=1).run(duration_s=1.5)
    >>> frames = recording.layers["pressure"].frames  # [T, M] V
    >>> images = [processor.step(f, t) for f, t in zip(frames, recording.t.tolist(), strict=True)]
    >>> sum(i is None for i in images)  # the first frames become the reference
    20
    >>> peak_pa = max(float(np.nanmax(i.image)) for i in images[20:])
    >>> peak_pa > 1000.0  # the 5 N push from 1 s on
    True
    """

    def __init__(
        self,
        imager: LayerImager,
        reference_frames: int | None = None,
        drift_time_constant_s: float = DEFAULT_DRIFT_TIME_CONSTANT_S,
        contact_k: float = DEFAULT_CONTACT_K,
        posture: PostureReferences | None = None,
        fault_check_period_s: float = DEFAULT_FAULT_CHECK_PERIOD_S,
        fault_check_phase: float = 0.0,
        compiled_step: bool = True,
        jump_k: float = DEFAULT_JUMP_K,
    ) -> None:
        if not 0.0 <= fault_check_phase < 1.0:
            raise ValueError(f"fault_check_phase must be in [0, 1), got {fault_check_phase}")
        self.imager = imager
        self.n_measurements = imager.n_measurements
        self.tracker = ReferenceTracker(
            self.n_measurements,
            int(reference_frames or imager.layer.solver.reference_frames),
            float(drift_time_constant_s),
            float(contact_k),
            posture,
        )
        self._frame_step = frame_step(compiled_step)  # the compiled kernel or numpy's step
        self._excluded_seen: np.ndarray | None = None
        self._excluded_any = False
        self.fault_check_period_s = float(fault_check_period_s)
        self.fault_check_phase = float(fault_check_phase)
        self._recent: deque[np.ndarray] = deque(maxlen=FAULT_WINDOW_FRAMES)
        self._faulty = np.zeros(0, dtype=np.int64)
        self._faulty_names: tuple[int, ...] = ()  # the same, as each image carries them
        self._fault_mask = np.zeros(self.n_measurements, dtype=bool)
        self._fault_flags: np.ndarray | None = None
        self._next_fault_check_s: float | None = None
        self._noise_frames: np.ndarray | None = None  # [K, M] V behind the element noise
        self.full_scale_v = imager.layer.full_scale_v
        self.jump_k = float(jump_k)
        self._jump_limit: np.ndarray | None = None  # [M] V, from the reference's noise
        self._previous: np.ndarray | None = None  # [M] V, the last frame as received
        self._accepted: np.ndarray | None = None  # [M] V, each channel's last value kept
        self.last_flags: np.ndarray | None = None  # uint8 [M] of the last frame; None: none
        self.values_out_of_range = 0
        self.values_jumped = 0
        self.reference_report: ReferenceReport | None = None
        self.reference_error: str | None = None
        self.frames_in = 0
        self.frames_imaged = 0
        self.frames_unusable = 0
        self.frames_compiled = 0  # imaged by the compiled kernel (frame_kernel.compiled_step)

    # ------------------------------------------------------------ diagnostics
    @property
    def reference_ready(self) -> bool:
        return self.tracker.ready

    @property
    def reference_frames(self) -> int:
        return self.tracker.n_frames

    @property
    def drift_updates(self) -> int:
        """Frames the reference followed since it was captured."""
        return self.tracker.drift_updates

    @property
    def faulty_electrodes(self) -> np.ndarray:
        """int64 electrode indices left out since the last fault check."""
        return self._faulty.copy()

    @property
    def angle_rad(self) -> float:
        """Joint angle the reference is taken at, rad (posture compensation)."""
        return self.tracker.angle_rad

    def reference_age_s(self, now_s: float) -> float:
        """Seconds from the reference's capture (frame time) to ``now_s``; NaN before."""
        return self.tracker.age_s(now_s)

    def reference(self) -> np.ndarray:
        """Copy of the current reference ``[M]`` V; RuntimeError before it is ready."""
        return self.tracker.reference().copy()

    # ---------------------------------------------------------------- control
    def rezero(self) -> None:
        """Capture a new reference from the next frames.

        The fault window restarts; the faulty set stands until the captured frames are checked.
        """
        self.tracker.rezero()
        self._recent.clear()
        self._next_fault_check_s = None
        self._noise_frames = None
        self.reference_report = None
        self.reference_error = None

    def set_reference(
        self, reference_v: np.ndarray, t_s: float, noise_frames_v: np.ndarray | None = None
    ) -> None:
        """Use a reference ``[M]`` V measured elsewhere, as if captured at ``t_s``.

        ``noise_frames_v`` ``[K, M]`` V (untouched frames) give the element noise of the
        contact decision; without them every frame counts as touched and drift never runs.
        """
        self.rezero()
        self.tracker.set_reference(reference_v, t_s)
        if noise_frames_v is not None and len(noise_frames_v):
            self._noise_frames = np.asarray(noise_frames_v, dtype=np.float64)
        self._reference_ready(t_s)

    # ----------------------------------------------------------------- frames
    def step(
        self,
        frame_v: np.ndarray,
        t_s: float,
        flags: np.ndarray | None = None,
        angle_rad: float | None = None,
    ) -> LayerImages | None:
        """One frame ``[M]`` V at frame time ``t_s`` s -> its images, or None.

        Args:
            frame_v: ``[M]`` volts, protocol order; NaN marks a missing value.
            t_s: frame (acquisition) time, s; times must not go backwards for drift to act.
            flags: optional uint8 ``[M]`` ``EitFrame.channel_flags`` (empty: all OK).
            angle_rad: joint angle at the frame time, rad (posture); None/NaN: keep the last.

        Returns:
            None while the reference is captured and for a frame without a usable channel.

        Raises:
            ValueError: wrong frame or flags shape, non-finite time.
        """
        if flags is None and angle_rad is None:
            images = self._common_step(frame_v, t_s)
            if images is not None:
                return images
        frame = self._screen(frame_v, t_s, flags)
        t_s = float(t_s)
        self.frames_in += 1
        tracker = self.tracker
        if angle_rad is not None and np.isfinite(angle_rad):
            tracker.angle_rad = float(angle_rad)
        if not tracker.ready:
            if tracker.capture(frame, t_s):
                self._noise_frames = tracker.captured_frames
                self._reference_ready(t_s)
            return None
        if self.reference_error is not None:
            self.frames_unusable += 1
            return None
        reference = tracker.reference()
        if not np.isfinite(frame).any():
            self.frames_unusable += 1
            return None
        self._recent.append(frame)
        self._check_faults_if_due(t_s, reference)
        used = self._channels_used(frame, reference)
        if used == 0:
            self.frames_unusable += 1
            return None
        planned = self._planned_step(frame, reference, t_s, None) if used < 0 else None
        if planned is None:
            values = self.imager.relative_change(frame, reference, self._fault_flags)
            touching = tracker.touching(values)
            tracker.track(frame, t_s, touching)
            image = self.imager.physical_image(values)
        else:
            values, image, touching = planned
        self.frames_imaged += 1
        used = self.n_measurements if used < 0 else used
        return LayerImages(t_s, values, image, touching, used, self._faulty_names, frame)

    def _screen(self, frame_v: np.ndarray, t_s: float, flags: np.ndarray | None) -> np.ndarray:
        """Check a frame's shapes, flagged and implausible values NaN (a copy) ``[M]`` V.

        Keeps the previous frame and each channel's last value for the jump check.
        """
        m = self.n_measurements
        frame = np.asarray(frame_v, dtype=np.float64)
        if frame.shape != (m,):
            raise ValueError(f"a frame must be [{m}] volts, got shape {frame.shape}")
        if not math.isfinite(float(t_s)):
            raise ValueError(f"frame time must be finite, got {t_s}")
        if flags is not None and np.size(flags) and np.shape(flags) != (m,):
            raise ValueError(f"flags must be [{m}] (or empty), got shape {np.shape(flags)}")
        frame = flagged_as_nan(frame, flags)  # a copy: flagged values become NaN
        previous, accepted = self._previous, self._accepted
        implausible = implausible_flags(
            frame, self.full_scale_v, self._jump_limit, previous, accepted
        )
        self._previous = frame
        if implausible.any():
            self._count_implausible(implausible)
            self._previous = frame.copy()
            frame[implausible != 0] = np.nan
        else:
            self.last_flags = None
        if accepted is None or np.isfinite(frame).all():
            self._accepted = frame
        else:
            self._accepted = np.where(np.isfinite(frame), frame, accepted)
        return frame

    def _channels_used(self, frame: np.ndarray, reference: np.ndarray) -> int:
        """Channels that go into the frame's image; -1: every one (a plannable frame)."""
        finite = np.isfinite(frame)
        excluded = self._reference_excluded()
        if (
            finite.all()
            and not self._faulty.size
            and excluded is None
            and np.isfinite(reference).all()
        ):
            return -1  # the common case, without building the mask
        usable = finite & np.isfinite(reference) & ~self._fault_mask
        if excluded is not None:
            usable &= ~excluded
        return int(np.count_nonzero(usable))

    def process(
        self, frames_v: np.ndarray, t_s: np.ndarray, flags: np.ndarray | None = None
    ) -> list[LayerImages | None]:
        """:meth:`step` over frames ``[T, M]`` V at times ``[T]`` s (flags ``[T, M]``)."""
        frames = np.asarray(frames_v, dtype=np.float64)
        times = np.asarray(t_s, dtype=np.float64)
        if frames.ndim != 2 or times.shape != frames.shape[:1]:
            raise ValueError(f"need frames [T, M] and times [T], got {frames.shape}, {times.shape}")
        if flags is not None and np.shape(flags) != frames.shape:
            raise ValueError(f"flags must be [T, M] = {frames.shape}, got {np.shape(flags)}")
        return [
            self.step(frames[k], times[k], None if flags is None else flags[k])
            for k in range(frames.shape[0])
        ]

    def _common_step(self, frame_v: np.ndarray, t_s: float) -> LayerImages | None:
        """:meth:`step` of the frame most frames are, in the fewest calls; None: not one.

        That frame: a ready, usable reference without excluded channels, no faulty electrode,
        no posture table, no fault check due, every value finite (the planned step finds
        out), a layer with a frame plan (:attr:`LayerImager.frame_plan`). The same result and
        bookkeeping as the full step, without its finiteness checks and masks (about 3 us less
        per frame at 50 patches, a tenth of the step). Nothing changes when it returns None:
        the full step then takes the frame (a frame with a missing value has then gone
        through the planned step twice).
        """
        tracker = self.tracker
        if (
            tracker.posture is not None
            or not tracker.ready
            or self.reference_error is not None
            or self._faulty.size
            or np.shape(frame_v) != (self.n_measurements,)
        ):
            return None
        t = float(t_s)
        due = self._next_fault_check_s
        if not math.isfinite(t) or (due is not None and t >= due):
            return None
        if self._reference_excluded() is not None:
            return None
        frame = np.array(frame_v, dtype=np.float64)  # a copy: the fault window keeps it
        planned = self._planned_step(frame, tracker.reference(), t, self._previous)
        if planned is None:
            return None
        values, image, touching = planned
        self._previous = self._accepted = frame
        self.last_flags = None
        self.frames_in += 1
        self._recent.append(frame)
        self.frames_imaged += 1
        return LayerImages(
            t, values, image, touching, self.n_measurements, self._faulty_names, frame
        )

    def _reference_excluded(self) -> np.ndarray | None:
        """The channels the reference check left out (bool ``[M]``); None for none.

        Looked at again only when the check made a new mask.
        """
        excluded = self.imager.reference_excluded
        if excluded is not self._excluded_seen:
            self._excluded_seen = excluded
            self._excluded_any = excluded is not None and bool(excluded.any())
        return excluded if self._excluded_any else None

    def _planned_step(
        self,
        frame: np.ndarray,
        reference: np.ndarray,
        t_s: float,
        previous: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, bool] | None:
        """Relative change, image and contact of a frame by its plan, or None.

        The compiled kernel or numpy's step (:mod:`eit_skin.pipeline.frame_plan`), drift
        tracking included. None: no plan, or the frame takes the general path (which flags
        the values beyond the full scale or jumped from ``previous`` ``[M]`` V: the planned
        step only finds that there may be some; None: the general step checked the frame).
        """
        tracker = self.tracker
        plan = self.imager.frame_plan
        if tracker.posture is not None or plan is None:
            return None
        alpha = tracker.drift_alpha(t_s)
        checks = FrameChecks(
            tracker.element_noise,
            tracker.contact_k,
            alpha,
            self.full_scale_v,
            previous,
            self._jump_limit,
        )
        out: FrameResult | None = self._frame_step(plan, frame, reference, checks)
        if out is None:
            return None
        if self._frame_step is compiled_step:
            self.frames_compiled += 1
        if not out.touching and alpha is not None:
            tracker.follow(out.reference_v, t_s)
        return out.values, out.image, out.touching

    def _count_implausible(self, flags: np.ndarray) -> None:
        """Note one frame's :func:`~eit_skin.frames.implausible_flags` (some set)."""
        self.last_flags = flags
        self.values_out_of_range += int(np.count_nonzero(flags & FLAG_OUT_OF_RANGE))
        self.values_jumped += int(np.count_nonzero(flags & FLAG_JUMP))

    # ----------------------------------------------------------------- faults
    def _reference_ready(self, t_s: float) -> None:
        """Reference check and channel noise, faults in the frames behind it, element noise."""
        frames = self._noise_frames
        reference = self.tracker.reference()
        self.reference_error = unit_mismatch(reference, frames)
        if self.reference_error is not None:
            return
        try:
            self.reference_report = self.imager.use_reference(reference, frames)
        except UnusableReferenceError as error:
            self.reference_error = str(error)
            return
        self._jump_limit = jump_limit(self.imager.channel_noise_v, reference, self.jump_k)
        if frames is not None and len(frames) >= MIN_FAULT_FRAMES and self.fault_check_period_s > 0:
            self._check_faults(frames, self.tracker.reference())
        self._update_element_noise()
        self._schedule_fault_check(t_s)

    def _update_element_noise(self) -> None:
        if self._noise_frames is None:
            return
        change = self.imager.relative_change(
            self._noise_frames, self.tracker.reference(), self._fault_flags
        )
        self.tracker.set_element_noise(change.std(axis=0))

    def _schedule_fault_check(self, t_s: float) -> None:
        """The next check: the first frame at or after this layer's next grid time."""
        period, phase = self.fault_check_period_s, self.fault_check_phase
        if period <= 0:
            self._next_fault_check_s = None
            return
        self._next_fault_check_s = (math.floor(t_s / period - phase) + 1 + phase) * period

    def _check_faults_if_due(self, t_s: float, reference: np.ndarray) -> None:
        due = self._next_fault_check_s
        if due is None or t_s < due or len(self._recent) < MIN_FAULT_FRAMES:
            return
        if self._check_faults(np.stack(self._recent), reference):
            self._update_element_noise()
        self._schedule_fault_check(t_s)

    def _check_faults(self, frames: np.ndarray, reference: np.ndarray) -> bool:
        """Find faulty electrodes in ``frames`` ``[T, M]``; returns whether the set changed."""
        protocol = self.imager.protocol
        faulty = faulty_electrodes(frames, reference, protocol, saturation_v=self.full_scale_v)
        if np.array_equal(faulty, self._faulty):
            return False
        self._faulty = faulty
        self._faulty_names = tuple(int(e) for e in faulty)
        if faulty.size:
            self._fault_mask = protocol.touching(faulty)
            self._fault_flags = self._fault_mask.astype(np.uint8) * np.uint8(FLAG_INVALID)
        else:
            self._fault_mask = np.zeros(self.n_measurements, dtype=bool)
            self._fault_flags = None
        return True


def jump_limit(
    channel_noise_v: np.ndarray | None, reference_v: np.ndarray, jump_k: float
) -> np.ndarray | None:
    """``[M]`` V: ``jump_k`` times each channel's noise; None: no jump check.

    A channel of unknown (NaN) or smaller noise than the median channel's gets the median's
    (a one-sample estimate can be small by chance). None for ``jump_k <= 0`` and for frames
    without measured noise: the median noise below :data:`MIN_MEASURED_NOISE` of the
    reference's RMS (computed frames, or the same frame repeated).
    """
    if channel_noise_v is None or not jump_k > 0:
        return None
    sigma = np.asarray(channel_noise_v, dtype=np.float64)
    positive = sigma[np.isfinite(sigma) & (sigma > 0)]
    ref = np.asarray(reference_v, dtype=np.float64)
    rms = float(np.sqrt(np.mean(ref[np.isfinite(ref)] ** 2))) if np.isfinite(ref).any() else 0.0
    if not positive.size or not np.median(positive) >= MIN_MEASURED_NOISE * rms:
        return None
    return float(jump_k) * np.fmax(sigma, float(np.median(positive)))


def unit_mismatch(reference_v: np.ndarray, frames_v: np.ndarray | None) -> str | None:
    """Why ``frames_v`` ``[K, M]`` V cannot be imaged against ``reference_v`` ``[M]``, or None.

    The median over channels of ``|v / v_ref|`` (each channel's median over the frames)
    outside ``[1/K, K]``, ``K = CONDUCTANCE_RATIO_LIMIT``: no load changes every channel by
    that factor, so the two are in different units (mV and V) or of different boards.
    """
    if frames_v is None or not len(frames_v):
        return None
    ref = np.asarray(reference_v, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.abs(np.asarray(frames_v, dtype=np.float64) / ref)
    ratio = np.where(np.isfinite(ratio) & (ref != 0), ratio, np.nan)
    per_channel = ratio[:, np.isfinite(ratio).any(axis=0)]
    if not per_channel.size:
        return None
    typical = float(np.median(np.nanmedian(per_channel, axis=0)))
    k = CONDUCTANCE_RATIO_LIMIT
    if 1.0 / k <= typical <= k:
        return None
    return (
        f"reference: the frames are {typical:.3g} times the reference (median of |v / v_ref| "
        f"over channels, first {len(frames_v)} frames); no load scales every channel by more "
        f"than {k:g}x: is the reference in another unit (V / mV) or from another board?"
    )
