"""Several presses at once, learnt from single presses only: superposition of press responses.

A frame's feature vector is the localiser's channel-scaled relative change ``x = d / scale``
``[M]`` (:mod:`eit_skin.calibration.localiser`). The training presses give one column each,
``X`` ``[N, M]``. A frame touched at two places is modelled as a non-negative sum of two
single-press responses, ``x ~ a_i X_i + a_j X_j`` (first order in the changes: the relative
changes of two small presses add).

**Count** (how many touches, up to K): every pair (i, j) of training presses is fitted by least
squares with ``a_i, a_j > 0`` in closed form (2 x 2 normal equations for all N^2 pairs at once).
The best pair whose presses lie at least ``min_separation_m`` apart (*far*) is compared with the
best fit by presses closer than that (*near*: one press, or two neighbours interpolating one):
``split = r_far / r_near`` (residual norms squared). A single press is fitted about as well by
a near pair as by any far pair (``split`` ~ 1); two separate presses are fitted much better by
a far pair (``split`` << 1). The frame counts as two when ``split`` is below ``threshold``:
the ``false_split_rate`` quantile of ``split`` over held-out single presses (each against the
other training presses), so by construction that share of single presses is split in two.
Further touches (K > 2) are added greedily the same way: the best far candidate (new press at
least ``min_separation_m`` from every press so far) against the best near one, same threshold;
then each touch is re-placed with the others fixed (two sweeps).

``min_separation_m`` defaults to the layer's electrode pitch (mean distance between
neighbouring electrode centres): a boundary-electrode EIT skin does not resolve two touches
much closer than that, so they are reported as one.

**Where**: each touch is put at the training press fitted for it (resolution: the spacing of
the calibration presses; the kernel ridge localiser, trained on whole single presses, pulls a
peeled-off share of a two-touch frame towards the sheet's centre). Its own response is the frame
minus the fitted responses of the others (peel-off, for its depth).

**Confidence** of each touch, in [0, 1]: the share of held-out single presses whose best fit
left a relative residual at least as large as this touch's (the frame's residual over the norm
of its own response): scale-free like the localiser's confidence; a weak touch, or a frame the
training presses do not explain, scores low.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from eit_skin.calibration.stored_fields import StoredFields, stored_dataclass
from eit_skin.patch.model import Layer

FALSE_SPLIT_RATE = 0.05
"""Default share of held-out single presses counted as two (sets the count threshold)."""

MAX_THRESHOLD_PRESSES = 100
"""At most this many held-out single presses set the threshold (fit time ~ N^2 per press)."""


def electrode_pitch(layer: Layer) -> float:
    """Mean distance between neighbouring electrode centres of ``layer`` (cyclic), m."""
    centres = np.array([e.center for e in layer.electrodes], dtype=np.float64)
    return float(np.linalg.norm(np.roll(centres, -1, axis=0) - centres, axis=1).mean())


@dataclass(frozen=True)
class PairFit:
    """The best near and far explanation of one frame by training presses.

    Attributes:
        near_residual: ``|x - fit|^2 / |x|^2`` of the best single press or near pair.
        far_residual: same for the best pair at least the minimum separation apart (inf: none).
        pair: ``[2]`` training indices of that far pair (-1 if none).
        weights: ``[2]`` their non-negative coefficients.
    """

    near_residual: float
    far_residual: float
    pair: np.ndarray
    weights: np.ndarray

    @property
    def split(self) -> float:
        """``far_residual / near_residual``: < 1 when two separate presses explain it better."""
        return float(self.far_residual / max(self.near_residual, np.finfo(float).tiny))


@dataclass(frozen=True, eq=False)
class MultiTouchModel:
    """Training responses and the count rule of the superposition model (module docstring).

    Attributes:
        responses: ``[N, M]`` channel-scaled relative changes of the single training presses.
        press_xy: ``[N, 2]`` their positions, m.
        min_separation_m: touches closer than this are one touch, m.
        threshold: ``split`` below this counts another touch.
        false_split_rate: quantile of held-out single presses that set ``threshold``.
        residuals: ``[R]`` sorted relative residuals of the held-out single presses' best fits.
    """

    responses: np.ndarray
    press_xy: np.ndarray
    min_separation_m: float
    threshold: float
    false_split_rate: float
    residuals: np.ndarray

    @classmethod
    def fit(
        cls,
        responses: np.ndarray,
        press_xy: np.ndarray,
        min_separation_m: float,
        false_split_rate: float = FALSE_SPLIT_RATE,
        seed: int = 0,
    ) -> MultiTouchModel:
        """Fit on single presses ``responses`` [N, M] at ``press_xy`` [N, 2] m.

        The threshold is the ``false_split_rate`` quantile of ``split`` of up to
        :data:`MAX_THRESHOLD_PRESSES` presses (chosen with ``seed``), each fitted by the others.
        """
        if not 0.0 < false_split_rate < 1.0:
            raise ValueError(f"false_split_rate: {false_split_rate} not in (0, 1)")
        if not min_separation_m > 0:
            raise ValueError(f"min_separation_m: {min_separation_m} must be > 0")
        x = np.asarray(responses, dtype=np.float64)
        xy = np.asarray(press_xy, dtype=np.float64)
        basis = PairBasis(x, xy, min_separation_m)
        n = len(x)
        rows = np.random.default_rng(seed).permutation(n)[:MAX_THRESHOLD_PRESSES]
        fits = [basis.fit(x[r], exclude=int(r)) for r in rows]
        threshold = float(np.quantile([f.split for f in fits], false_split_rate))
        residuals = np.sort([f.near_residual for f in fits])
        return cls(x, xy, float(min_separation_m), threshold, float(false_split_rate), residuals)

    @cached_property
    def basis(self) -> PairBasis:
        """The pair fits of the training responses (built once, on first use)."""
        return PairBasis(self.responses, self.press_xy, self.min_separation_m)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return stored_dataclass(prefix, self)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> MultiTouchModel:
        return StoredFields(arrays, prefix).dataclass(cls)

    def decompose(self, x: np.ndarray, max_touches: int) -> TouchSplit | None:
        """Split one frame's response ``x`` [M] into 2..max_touches touches; None: one touch."""
        if max_touches < 1:
            raise ValueError(f"max_touches: {max_touches}, need >= 1")
        x = np.asarray(x, dtype=np.float64)
        if max_touches == 1 or not np.any(x):
            return None
        basis = self.basis
        pair = basis.fit(x)
        if not pair.split < self.threshold:
            return None
        chosen = [int(i) for i in pair.pair]
        while len(chosen) < max_touches:
            added = basis.extend(x, chosen, self.threshold)
            if added is None:
                break
            chosen.append(added)
        if len(chosen) > 2:  # a greedy third touch may fit better with the first two moved
            chosen = basis.refine(x, chosen)
        cols = self.responses[chosen].T  # [M, k]
        weights = np.maximum(np.linalg.lstsq(cols, x, rcond=None)[0], 0.0)
        fitted = cols * weights[None, :]  # [M, k] each touch's fitted response
        residual = x - fitted.sum(axis=1)  # [M]
        own = residual[:, None] + fitted  # [M, k] the frame minus the others' fitted responses
        relative = float(residual @ residual) / np.maximum(np.einsum("mk,mk->k", own, own), 1e-300)
        rank = self.residuals.size - np.searchsorted(self.residuals, relative, side="left")
        return TouchSplit(own.T.copy(), self.press_xy[chosen], rank / max(self.residuals.size, 1))


@dataclass(frozen=True)
class TouchSplit:
    """A frame split into several touches.

    Attributes:
        responses: ``[K, M]`` each touch's own response (the frame minus the others' fits).
        xy: ``[K, 2]`` each touch's position (its fitted training press), m.
        confidence: ``[K]`` in [0, 1] (module docstring).
    """

    responses: np.ndarray
    xy: np.ndarray
    confidence: np.ndarray


class PairBasis:
    """Closed-form least-squares fits of a response by one or two training presses.

    Args:
        responses: ``[N, M]`` training responses.
        press_xy: ``[N, 2]`` their positions, m.
        min_separation_m: pairs at least this far apart are *far*, m.
    """

    def __init__(self, responses: np.ndarray, press_xy: np.ndarray, min_separation_m: float):
        self.x = responses
        self.gram = responses @ responses.T  # [N, N]
        self.diag = np.diag(self.gram).copy()
        self.far = (
            np.linalg.norm(press_xy[:, None, :] - press_xy[None, :, :], axis=2) >= min_separation_m
        )
        self.press_xy = press_xy
        self.min_separation_m = min_separation_m
        det = self.diag[:, None] * self.diag[None, :] - self.gram**2
        degenerate = det <= 1e-9 * self.diag[:, None] * self.diag[None, :]
        self.inv_det = np.where(degenerate, 0.0, 1.0 / np.where(degenerate, 1.0, det))

    def fit(self, x: np.ndarray, exclude: int | None = None) -> PairFit:
        """Best near and far fit of ``x`` [M]; ``exclude``: a training press left out."""
        qq = float(x @ x)
        if not qq > 0:
            return PairFit(1.0, np.inf, np.array([-1, -1]), np.zeros(2))
        b = self.x @ x  # [N]
        single = qq - np.maximum(b, 0.0) ** 2 / np.where(self.diag > 0, self.diag, np.inf)
        ai = (self.diag[None, :] * b[:, None] - self.gram * b[None, :]) * self.inv_det
        aj = ai.T  # the gram matrix and inv_det are symmetric
        residual = qq - ai * b[:, None] - aj * b[None, :]  # [N, N]
        valid = (ai > 0) & (aj > 0) & (self.inv_det > 0)
        if exclude is not None:
            single[exclude] = np.inf
            valid[exclude, :] = valid[:, exclude] = False
        residual = np.where(valid, residual, np.inf)
        near = min(float(single.min()), float(np.where(self.far, np.inf, residual).min()))
        far = np.where(self.far, residual, np.inf)
        k = int(np.argmin(far))
        i, j = divmod(k, len(b))
        if not np.isfinite(far[i, j]):
            return PairFit(near / qq, np.inf, np.array([-1, -1]), np.zeros(2))
        return PairFit(near / qq, far[i, j] / qq, np.array([i, j]), np.array([ai[i, j], aj[i, j]]))

    def additions(self, x: np.ndarray, chosen: list[int]) -> tuple[np.ndarray, np.ndarray, float]:
        """What adding each training press to ``chosen`` (indices) gives for ``x`` [M].

        Returns ``[N]`` decrease of the squared residual (-inf: not a positive addition),
        ``[N]`` whether the press is at least the minimum separation from every chosen one,
        and the squared residual of the chosen presses alone (unconstrained least squares).
        """
        q, _ = np.linalg.qr(self.x[chosen].T)  # [M, k]
        residual = x - q @ (q.T @ x)  # [M]
        projected = self.x - (self.x @ q) @ q.T  # [N, M] each candidate off the chosen span
        norm2 = np.einsum("nm,nm->n", projected, projected)
        gain = projected @ residual
        ok = (gain > 0) & (norm2 > 1e-12 * max(float(norm2.max()), 1e-300))
        drop = np.where(ok, gain**2 / np.where(ok, norm2, 1.0), -np.inf)
        distance = np.linalg.norm(
            self.press_xy[:, None, :] - self.press_xy[chosen][None, :, :], axis=2
        ).min(axis=1)
        return drop, distance >= self.min_separation_m, float(residual @ residual)

    def extend(self, x: np.ndarray, chosen: list[int], threshold: float) -> int | None:
        """The training press to add to ``chosen`` as another touch, or None (module docstring)."""
        drop, far, rr = self.additions(x, chosen)
        far_r = rr - float(np.where(far, drop, -np.inf).max(initial=-np.inf))
        near_r = rr - float(max(np.where(far, -np.inf, drop).max(initial=-np.inf), 0.0))
        if not np.isfinite(far_r) or not far_r / max(near_r, np.finfo(float).tiny) < threshold:
            return None
        return int(np.argmax(np.where(far, drop, -np.inf)))

    def refine(self, x: np.ndarray, chosen: list[int], sweeps: int = 2) -> list[int]:
        """Re-place each touch with the others fixed (best far press), ``sweeps`` times."""
        chosen = list(chosen)
        for _ in range(sweeps):
            for j in range(len(chosen)):
                others = chosen[:j] + chosen[j + 1 :]
                drop, far, _ = self.additions(x, others)
                best = np.where(far, drop, -np.inf)
                if np.isfinite(best.max()):
                    chosen[j] = int(np.argmax(best))
        return chosen
