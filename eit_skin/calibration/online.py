"""Calibrated contacts of a running skin: the press localiser applied frame by frame (no ROS).

The reconstruction node holds one :class:`OnlineLocaliser` when its ``calibration`` parameter
names a file of ``eit-skin calibrate``, and calls :meth:`OnlineLocaliser.contacts` once per
imaged frame of the calibrated layer. It reuses what the layer's
:class:`~eit_skin.pipeline.processor.LayerProcessor` already decided:

* **touch rule**: a contact only when the processor's contact decision says the frame is
  touched (a change above ``contact_k`` times the element noise, the rule that freezes drift
  tracking); an untouched frame has no calibrated contact;
* **reference**: the processor's current reference (captured, re-zeroed, drift-tracked,
  posture-compensated); drift tracking is frozen while touched, so it is the reference the
  frame was imaged against;
* **missing channels**: flagged channels of the frame, non-finite values and the channels of
  electrodes the processor found faulty count as "no change" (the localiser has no notion of
  a missing channel); a press the localiser cannot recognise then shows as a low confidence.
* **excluded electrodes**: a press near an electrode the processor leaves out was located
  without the channels that see it best (and may be put far away), so its confidence is
  scaled by :func:`fault_proximity`: the distance to the nearest excluded electrode, of the
  located press or of the image's peak (the processor's reconstruction without those
  channels, whichever is nearer), over that electrode's spacing to its nearest neighbour,
  capped at 1. This holds for as long as the
  processor's fault checks leave the electrode out; a contact right at it gets confidence 0,
  so the classifier keeps its own centroid there (below :data:`MIN_CONFIDENCE`), one
  spacing or further away it is unchanged.
* **several touches**: with ``max_touches`` K > 1 (and a calibration fitted for it,
  ``eit-skin calibrate --max-touches K``) a frame gives up to K contacts, one confidence each
  (:mod:`eit_skin.calibration.multi_touch`).
* **changed sheet**: a press is brief; a change the processor keeps calling touched for longer
  than its own drift time constant (drift tracking frozen all that time) is the sheet changing
  (damage, drying, a slipped electrode), not a touch. From then on no contact is reported and
  :attr:`OnlineLocaliser.sheet_changed` says why, until the processor calls a frame untouched
  again (the sheet back at its reference, e.g. after a re-zero).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.calibration.localiser import CalibrationError, PressLocaliser
from eit_skin.fem.mesh import Mesh
from eit_skin.frames import excluded_channels
from eit_skin.patch.model import Patch
from eit_skin.pipeline.processor import LayerImages, LayerProcessor

MIN_CONFIDENCE = 0.05
"""Below this localiser confidence a contact is not a calibrated single press
(docs/press-calibration.md); the classifier then keeps its own centroid."""


@dataclass(frozen=True)
class CalibratedContact:
    """One calibrated press.

    Attributes:
        xy_m: ``[2]`` press centre in the patch frame, m.
        depth_m: press depth, m; NaN when the calibration had no depths.
        confidence: localiser confidence in [0, 1].
    """

    xy_m: np.ndarray
    depth_m: float
    confidence: float


def electrode_centres(mesh: Mesh) -> np.ndarray:
    """``[n_electrodes, 2]`` centre of each electrode, m (mean of its boundary edges' nodes)."""
    return np.stack([mesh.nodes[np.unique(edges)].mean(axis=0) for edges in mesh.electrode_edges])


def fault_proximity(xy_m: np.ndarray, centres_m: np.ndarray, excluded: np.ndarray) -> float:
    """Factor in [0, 1] on the confidence of a contact at ``xy_m`` ``[2]`` (or ``[K, 2]``) m.

    ``min over excluded electrodes e (and points) of |xy - c_e| / spacing_e``, capped at 1,
    where ``spacing_e`` is the distance from ``c_e`` to the nearest other electrode centre
    (``centres_m`` ``[n_electrodes, 2]`` m); 1 when nothing is excluded. Scale-free: the
    electrode layout sets the distance that counts as near.
    """
    excluded = np.asarray(excluded, dtype=np.int64)
    if excluded.size == 0 or len(centres_m) < 2:
        return 1.0
    gaps = np.linalg.norm(centres_m[excluded, None, :] - centres_m[None, :, :], axis=2)
    gaps[gaps == 0.0] = np.inf  # the electrode itself
    spacing = gaps.min(axis=1)  # [n_excluded] m
    points = np.atleast_2d(np.asarray(xy_m, dtype=np.float64))  # [K, 2]
    distance = np.linalg.norm(points[:, None, :] - centres_m[excluded][None], axis=2)
    return float(min(1.0, (distance / spacing[None, :]).min()))


class OnlineLocaliser:
    """A press calibration bound to one layer of a patch, located one frame at a time.

    Args:
        localiser: the fitted localiser.
        patch: the patch the node runs; the localiser's layer must be in it, unchanged.
        source: where the localiser came from (error messages).
        max_touches: contacts per frame at most (K); > 1 needs a calibration fitted for it.

    Raises:
        CalibrationError: no layer of that name, or its content hash differs, or
            ``max_touches`` > 1 with a one-touch calibration.
    """

    def __init__(
        self, localiser: PressLocaliser, patch: Patch, source: str, max_touches: int = 1
    ) -> None:
        if localiser.layer_name not in patch.layer_names:
            raise CalibrationError(
                f"{source}: key 'layer_name': calibrated on layer {localiser.layer_name!r}, "
                f"patch {patch.name!r} has layers {list(patch.layer_names)} (another patch?)"
            )
        localiser.check_layer(patch.layer(localiser.layer_name), source)
        if max_touches < 1:
            raise CalibrationError(f"{source}: max_touches {max_touches}: need >= 1")
        if max_touches > 1 and localiser.multi_touch is None:
            raise CalibrationError(
                f"{source}: max_touches {max_touches}: the calibration locates one touch at a "
                f"time (calibrate again with --max-touches {max_touches})"
            )
        self.localiser = localiser
        self.max_touches = int(max_touches)
        self.sheet_changed: str | None = None  # why contacts stopped (module docstring)
        self._touched_since_s: float | None = None
        self.layer_name = localiser.layer_name
        self.source = source
        self._centres: np.ndarray | None = None  # [n_electrodes, 2] m, on first need

    @classmethod
    def load(cls, path: str | Path, patch: Patch, max_touches: int = 1) -> OnlineLocaliser:
        """Read a calibration file made on a layer of ``patch`` (CalibrationError otherwise)."""
        return cls(PressLocaliser.load(path), patch, str(path), max_touches)

    def check_measurements(self, m: int) -> None:
        """Raise :class:`CalibrationError` unless the layer's frames have ``m`` channels."""
        self.localiser.check_frames(m, self.source, "n_measurements")

    def locate(
        self,
        frame_v: np.ndarray,
        reference_v: np.ndarray,
        excluded: np.ndarray | None = None,
        max_touches: int = 1,
    ) -> list[CalibratedContact]:
        """The presses (1..max_touches) of one frame ``[M]`` V against ``reference_v`` ``[M]`` V.

        ``excluded`` (bool ``[M]``) and non-finite channels count as unchanged.
        """
        frame = np.asarray(frame_v, dtype=np.float64)
        reference = np.asarray(reference_v, dtype=np.float64)
        usable = np.isfinite(frame) & np.isfinite(reference) & (reference != 0)
        if excluded is not None:
            usable &= ~excluded
        frame = np.where(usable, frame, 1.0)
        reference = np.where(usable, reference, 1.0)
        located = self.localiser.locate_touches(frame, reference, max_touches)
        depth = np.full(len(located.xy), np.nan) if located.depth is None else located.depth
        return [
            CalibratedContact(xy.copy(), float(z), float(c))
            for xy, z, c in zip(located.xy, depth, located.confidence, strict=True)
        ]

    def contacts(
        self,
        frame_v: np.ndarray,
        flags: np.ndarray | None,
        images: LayerImages,
        processor: LayerProcessor,
    ) -> list[CalibratedContact]:
        """The calibrated contacts (up to ``max_touches``) of a frame the processor just imaged.

        Args:
            frame_v: ``[M]`` volts as received (flags not applied).
            flags: optional uint8 ``[M]`` channel flags (empty / None: all OK).
            images: what ``processor.step`` returned for this frame.
            processor: the layer's processor (reference, faulty electrodes, drift time constant).

        Returns:
            Empty when the frame is untouched or the sheet changed (module docstring). A contact
            near an electrode the processor leaves out has its confidence scaled by
            :func:`fault_proximity`.
        """
        if not images.touching:
            self._touched_since_s = None
            self.sheet_changed = None
            return []
        if self._touched_since_s is None:
            self._touched_since_s = images.t_s
        limit_s = processor.tracker.drift_time_constant_s
        touched_s = images.t_s - self._touched_since_s
        if self.sheet_changed is None and limit_s > 0 and touched_s > limit_s:
            self.sheet_changed = (
                f"layer {self.layer_name}: changed for {touched_s:.0f} s without a break, longer "
                f"than the drift time constant ({limit_s:g} s): the sheet changed since its "
                "reference (damage, drying, an electrode), not a touch; no calibrated contacts "
                "until it is back at its reference (re-zero)"
            )
        if self.sheet_changed is not None:
            return []
        m = processor.n_measurements
        faulty = processor.faulty_electrodes
        excluded = processor.imager.protocol.touching(faulty)
        if flags is not None and np.size(flags):
            excluded = excluded | excluded_channels(flags, m)
        located = self.locate(frame_v, processor.reference(), excluded, self.max_touches)
        if not faulty.size:
            return located
        if self._centres is None:
            self._centres = electrode_centres(processor.imager.mesh)  # the inverse mesh's
        mesh = processor.imager.mesh
        peak = mesh.centroids[int(np.nanargmax(np.abs(images.values)))]  # the image's contact
        return [
            CalibratedContact(
                c.xy_m,
                c.depth_m,
                c.confidence * fault_proximity(np.stack([c.xy_m, peak]), self._centres, faulty),
            )
            for c in located
        ]
