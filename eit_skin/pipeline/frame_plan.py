"""A pressure frame's way to its image, planned once: :class:`FramePlan` and its numpy step.

Most frames a node images are alike: every channel finite and used, a linear matrix
(``one_step`` or ``greit``), a pressure layer, no posture table. Everything such a frame needs
is fixed once the reconstructor, the image grid and the unit are: the matrix with its
reciprocal channels merged, the device's signs, the bounds of the relative change, the unit
and the pixel map. :class:`FramePlan` holds exactly that, frozen, built once per reconstructor
(a new reference re-weights the matrix, so :class:`~eit_skin.pipeline.builder.LayerImager`
builds a new plan with it).

A frame then becomes an image in exactly two implementations, both taking the plan:

* :func:`reference_step` here, plain numpy: the reference implementation, and the step of a
  process without numba (or with ``EIT_SKIN_JIT=0``);
* :func:`~eit_skin.pipeline.frame_kernel.compiled_step`, the same arithmetic compiled with
  numba into one call (the step of a node).

Both do, in the same order and precision (float64 quotients, one rounding to float32 before
the product, no fused multiply-add):

0. the values no sheet can give (beyond the full scale, a one-frame jump): the step only
   finds that there are some and returns None; the caller's general path flags them;
1. the relative change ``x = R (v - v_ref) / s_ref``
   (:meth:`~eit_skin.inverse.one_step.MergedColumns.solve_frame`);
2. the contact decision ``max |x| / noise > contact_k``
   (:meth:`~eit_skin.pipeline.reference.ReferenceTracker.touching`);
3. drift tracking of an untouched frame, ``ref + alpha (v - ref)``;
4. the physical image: clip to :data:`~eit_skin.patch.material.RELATIVE_CHANGE_RANGE`, Pa,
   one gather onto the ``[H, W]`` pixels (:func:`pressure_image`).

Frames with a missing, flagged or excluded channel, a faulty electrode, Gauss-Newton, a
stretch layer or a posture table are not planned: the reconstructor's general path
(:meth:`~eit_skin.pipeline.builder.LayerImager.relative_change`, reduced matrices) and
:meth:`~eit_skin.pipeline.builder.LayerImager.physical_image` image them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from eit_skin.fem.image_grid import ImageGrid
from eit_skin.inverse.methods import Reconstructor
from eit_skin.inverse.one_step import MergedColumns, ReconstructionMatrix
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE


@dataclass(frozen=True, eq=False)
class FramePlan:
    """Everything a planned frame needs (see the module docstring); arrays in the kernel's types.

    Attributes:
        merged: the reconstruction matrix ``[N, M]`` with its reciprocal channels merged.
        signs: float64 ``[M]`` +-1 frames and references are multiplied by (a device
            reporting magnitudes: the model's signs; else all 1).
        low, high: float32 bounds of the relative change (clip before the unit).
        pascals: the unit, Pa per unit relative change (> 0).
        owner: intp ``[H*W]`` element under each pixel, ``N`` where none (NaN).
        shape: ``(H, W)``.
    """

    merged: MergedColumns
    signs: np.ndarray
    low: np.float32
    high: np.float32
    pascals: float
    owner: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def build(
        cls, reconstructor: Reconstructor, grid: ImageGrid, pascals: float, signs: np.ndarray | None
    ) -> FramePlan | None:
        """The plan of a linear matrix over every channel on ``grid``; None for any other.

        ``pascals``: the pressure unit (Pa per unit relative change; <= 0: not a pressure
        layer, no plan); ``signs``: ``[M]`` +-1 of a magnitude device, None: all 1.
        """
        rec = reconstructor
        if (
            not isinstance(rec, ReconstructionMatrix)
            or not pascals > 0
            or rec.channels.size != rec.n_channels
            or rec.matrix.shape[0] != grid.matrix.shape[1]
        ):
            return None
        m = rec.n_channels
        low, high = RELATIVE_CHANGE_RANGE
        return cls(
            merged=rec.merged,
            signs=np.ones(m) if signs is None else np.ascontiguousarray(signs, dtype=np.float64),
            low=np.float32(low),
            high=np.float32(high),
            pascals=float(pascals),
            owner=np.ascontiguousarray(grid.pixel_owner, dtype=np.intp),
            shape=grid.shape,
        )

    @cached_property
    def packed(self) -> tuple:
        """The plan as the compiled kernel takes it, packed once.

        ``(signs, matrix, index, weights, owner, low, high, pascals, H, W)``.
        """
        merged, (h, w) = self.merged, self.shape
        arrays = (self.signs, merged.matrix, merged.index, merged.weights, self.owner)
        return (*arrays, self.low, self.high, self.pascals, h, w)


class FrameChecks(NamedTuple):
    """The per-frame state a planned step reads besides the frame and the reference.

    Attributes:
        element_noise: float64 ``[N]`` noise of the relative change per element; None:
            unknown (the frame counts as touched, the reference never follows).
        contact_k: contact threshold in noise units.
        alpha: drift weight of an untouched frame (``ReferenceTracker.drift_alpha``); None:
            tracking off.
        full_scale_v: the board's full scale, V; None: no range check.
        previous_v: float64 ``[M]`` the previous frame, V (NaN: no comparison); None: none.
        jump_limit_v: float64 ``[M]`` largest plausible one-frame change, V; None: none.
    """

    element_noise: np.ndarray | None = None
    contact_k: float = math.inf
    alpha: float | None = None
    full_scale_v: float | None = None
    previous_v: np.ndarray | None = None
    jump_limit_v: np.ndarray | None = None


class FrameResult(NamedTuple):
    """A planned frame's outputs.

    Attributes:
        values: float32 ``[N]`` relative change per element.
        image: float32 ``[H, W]`` pressure image, Pa, NaN outside the sheet.
        reference_v: float64 ``[M]`` the reference after drift tracking, V (the one given
            when touched or tracking is off).
        touching: whether the frame showed a contact.
    """

    values: np.ndarray
    image: np.ndarray
    reference_v: np.ndarray
    touching: bool


def reference_step(
    plan: FramePlan, frame_v: np.ndarray, reference_v: np.ndarray, checks: FrameChecks
) -> FrameResult | None:
    """One finite frame ``[M]`` V against the reference ``[M]`` V, in numpy (module docstring).

    Frames and reference as the device reports them (float64 V; the plan's signs are applied
    here). None when the caller's general path must decide: the reference's floor or the
    product is not finite, or a value is beyond ``checks.full_scale_v`` or jumped more than
    ``checks.jump_limit_v`` from ``checks.previous_v``.
    """
    v = np.asarray(frame_v, dtype=np.float64)
    ref = np.asarray(reference_v, dtype=np.float64)
    if _implausible(v, checks):
        return None
    values = plan.merged.solve_frame(v * plan.signs, ref * plan.signs)
    if values is None:
        return None
    noise = checks.element_noise
    touching = noise is None or bool(
        np.fmax.reduce(np.abs(values.astype(np.float64)) / noise, initial=0.0) > checks.contact_k
    )
    base = ref
    if not touching and checks.alpha is not None:
        base = ref + checks.alpha * (v - ref)
    image = pressure_image(values, plan.pascals, plan.owner, plan.shape)
    return FrameResult(values, image, base, touching)


def _implausible(v: np.ndarray, checks: FrameChecks) -> bool:
    """Whether a value of ``v`` ``[M]`` V is beyond the full scale or jumped (NaN: never)."""
    if checks.full_scale_v is not None and bool((np.abs(v) > checks.full_scale_v).any()):
        return True
    previous, limit = checks.previous_v, checks.jump_limit_v
    if previous is None or limit is None:
        return False
    with np.errstate(invalid="ignore"):
        return bool((np.abs(v - previous) > limit).any())


def pressure_image(
    values: np.ndarray, pascals: float, owner: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """Relative change ``[N]`` -> float32 ``[H, W]`` pressure image, Pa (NaN outside the sheet).

    Clip to :data:`~eit_skin.patch.material.RELATIVE_CHANGE_RANGE`, times ``pascals`` in
    float64 rounded once to float32, one gather through ``owner`` ``[H*W]`` (``N``: NaN); the
    compiled kernel's step 4 in four numpy calls.
    """
    n = values.shape[0]
    low, high = RELATIVE_CHANGE_RANGE
    clipped = np.maximum(values, low)
    np.minimum(clipped, high, out=clipped)
    row = np.empty(n + 1, dtype=np.float32)
    np.multiply(clipped, pascals, out=row[:n], dtype=np.float64)
    row[n] = np.nan
    return row.take(owner, mode="wrap").reshape(shape)
