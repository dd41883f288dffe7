"""Evidence from the raw boundary frames: does a still touch change its shape while it lasts?

A close pinch (two fingers 15 mm apart closing to 5 mm) changes its reconstructed blob by a
few per cent of a finger spread, below the frame-to-frame scatter of the image shape on a
large patch, yet its boundary voltages change in a pattern that no still push makes
(bench/studies/pinch_information.md: 8-84 noise standard units on the face patch against at most
4.4 for every push). The reconstruction keeps only a smoothed part of the 208 channels; this
module looks at the channels themselves.

:class:`FrameEvidence` learns, from the classifier's no-touch calibration frames, each
channel's reference voltage and noise, then keeps following the reference while nothing
touches. :func:`shape_change_z` measures, over a touch's plateau, how much of the whitened
change is neither its amplitude (with a quadratic term for a contact that grows with force),
nor its centroid's motion (a finger that rolls or slides a little), nor a sheet-wide drift,
but a steady trend in time: a chi-square over the channels turned into a z-score, so a
threshold means the same on every patch and device (noise units, no fitted constant).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import nnls

from eit_skin.inverse.channel_noise import difference_noise
from eit_skin.inverse.electrode_faults import row_medians
from eit_skin.patch.protocol import Protocol

#: Plateau: frames whose amplitude is at least this fraction of the touch's largest.
PLATEAU_FRACTION = 0.8
#: Fewest plateau frames the statistic is computed from (6 regressors, at least 6 more).
MIN_FRAMES = 12
#: Most fingertip discs :meth:`TouchFilter.fit_discs` fits (a hand's fingers).
MOST_DISCS = 5


class FrameEvidence:
    """Per-channel reference and noise of one layer's raw frames, learnt while nothing touches.

    Args:
        channel_electrodes: ``[M, E]`` bool, which electrodes each channel drives or measures
            with (``Protocol.touching`` per electrode), so the channels of a faulty electrode
            can be left out; ``None``: none are.
    """

    def __init__(self, channel_electrodes: np.ndarray | None = None) -> None:
        self.channel_electrodes = (
            None if channel_electrodes is None else np.asarray(channel_electrodes, dtype=bool)
        )
        self.reference: np.ndarray | None = None  # [M] V
        self.sigma: np.ndarray | None = None  # [M] V

    @property
    def ready(self) -> bool:
        return self.reference is not None

    def learn_noise(self, frames_v: np.ndarray) -> None:
        """Reference (mean) and noise of ``frames_v`` ``[N, M]`` V, no touch, ``N >= 3``.

        The noise is the robust spread of frame-to-frame differences over sqrt(2)
        (:func:`~eit_skin.inverse.channel_noise.difference_noise`: a slow drift over the
        calibration does not count as noise). Channels that are NaN in any frame, or with no
        spread at all, stay out (NaN reference).
        """
        frames_v = np.asarray(frames_v, dtype=np.float64)
        if frames_v.ndim != 2 or frames_v.shape[0] < 3:
            raise ValueError(f"frames_v: [N >= 3, M] V, got shape {frames_v.shape}")
        if self.channel_electrodes is not None and (
            self.channel_electrodes.shape[0] != frames_v.shape[1]
        ):
            raise ValueError(
                f"frames have {frames_v.shape[1]} channels, channel_electrodes "
                f"{self.channel_electrodes.shape[0]}"
            )
        sigma = difference_noise(frames_v)
        ok = np.isfinite(frames_v).all(axis=0) & (sigma > 0)
        self.reference = np.where(ok, frames_v.mean(axis=0), np.nan)
        self.sigma = np.where(ok, sigma, np.nan)

    def follow(self, alpha: float, frame_v: np.ndarray) -> None:
        """Move the reference towards a no-touch ``frame_v`` ``[M]`` V by ``alpha`` (0..1)."""
        if self.reference is None:
            return
        frame_v = np.asarray(frame_v, dtype=np.float64)
        ok = np.isfinite(frame_v) & np.isfinite(self.reference)
        self.reference[ok] += alpha * (frame_v[ok] - self.reference[ok])

    def whiten(self, frame_v: np.ndarray | None) -> np.ndarray | None:
        """``[..., M]`` change of ``frame_v`` ``[..., M]`` from the reference, noise units.

        NaN: unusable.
        """
        if frame_v is None or self.reference is None:
            return None
        frame_v = np.asarray(frame_v, dtype=np.float64)
        if frame_v.shape[-1:] != self.reference.shape:
            raise ValueError(
                f"frame has {frame_v.shape[-1]} channels, the calibration {self.reference.size}"
            )
        return (frame_v - self.reference) / self.sigma

    def drift_pattern(self) -> np.ndarray:
        """``[M]`` whitened pattern of a sheet-wide conductivity change (the reference)."""
        return self.reference / self.sigma

    def usable(self, faulty: tuple[int, ...]) -> np.ndarray:
        """``[M]`` bool: calibrated channels that touch none of the ``faulty`` electrodes."""
        ok = np.isfinite(self.reference)
        if faulty and self.channel_electrodes is not None:
            ok &= ~self.channel_electrodes[:, list(faulty)].any(axis=1)
        return ok


def _electrode_ratios(b2: np.ndarray, channel_electrodes: np.ndarray) -> np.ndarray:
    """``[E]`` median ``b2`` over each electrode's channels over the median over the others.

    ``b2`` ``[M]`` (NaN: left out); NaN for an electrode without channels on either side.
    """
    ok = np.isfinite(b2)
    table = np.asarray(channel_electrodes, dtype=bool).T  # [E, M]
    touch, rest = table & ok, ~table & ok  # row_medians reads only these entries
    keep = touch.any(axis=1) & rest.any(axis=1)
    ratios = np.full(len(table), np.nan)
    if keep.any():
        own, others = row_medians(b2, touch)[keep], row_medians(b2, rest)[keep]
        ratios[keep] = own / np.maximum(others, np.finfo(float).tiny)
    return ratios


def electrode_roughness(bend: np.ndarray, channel_electrodes: np.ndarray) -> float:
    """How much rougher one electrode's channels are than the rest, in one frame.

    ``bend`` ``[M]``: a whitened frame's second difference in time (noise units; NaN: left
    out), ``channel_electrodes`` ``[M, E]``. Returns the largest over electrodes of the
    median ``bend**2`` over its channels over the median over the other channels: about 1-4
    for noise, a smooth touch or a touch's onset spread over the sheet, ``g**2`` for an
    electrode whose channels have ``g`` times their noise. NaN without enough channels.
    """
    ratios = _electrode_ratios(np.asarray(bend, dtype=np.float64) ** 2, channel_electrodes)
    return float(np.nanmax(ratios)) if np.isfinite(ratios).any() else float("nan")


def whiteness(bend: np.ndarray, step: np.ndarray, channel_electrodes: np.ndarray) -> float:
    """How white in time the roughest electrode's channels are, in one frame.

    ``bend`` ``[M]``: a whitened frame's second difference in time, ``step`` ``[M]``: its
    first (NaN: left out), ``channel_electrodes`` ``[M, E]``. On the channels of the
    electrode of :func:`electrode_roughness`, the median ``bend**2`` over the median
    ``step**2``: 3 for white noise (2.5 in the second frame of a noise that starts), 1 at
    the corner of a ramp, 0 on a ramp. NaN without enough channels.
    """
    bend, step = np.asarray(bend, dtype=np.float64), np.asarray(step, dtype=np.float64)
    b2 = np.where(np.isfinite(step), bend**2, np.nan)
    ratios = _electrode_ratios(b2, channel_electrodes)
    if not np.isfinite(ratios).any():
        return float("nan")
    own = np.asarray(channel_electrodes, dtype=bool)[:, int(np.nanargmax(ratios))]
    own = own & np.isfinite(b2)
    return float(np.median(b2[own]) / max(float(np.median(step[own] ** 2)), np.finfo(float).tiny))


def channel_electrodes(protocol: Protocol) -> np.ndarray:
    """``[M, E]`` bool: the electrodes each channel of ``protocol`` drives or measures with."""
    return protocol.touching_table().T


def shape_change_z(
    x: np.ndarray,
    t_s: np.ndarray,
    xy_m: np.ndarray,
    drift: np.ndarray,
) -> float:
    """Still-touch shape-change z-score of a touch's whitened frames.

    Args:
        x: ``[T, M]`` whitened changes (:meth:`FrameEvidence.whiten`) of the touch's frames;
            channels with a NaN anywhere are left out.
        t_s: ``[T]`` frame times, s.
        xy_m: ``[T, 2]`` blob centroid per frame, m (NaN rows: frame left out).
        drift: ``[M]`` whitened sheet-wide drift pattern (:meth:`FrameEvidence.drift_pattern`).

    Method: the amplitude ``a`` of each frame is its projection on the touch's mean pattern;
    the plateau frames (``a >= PLATEAU_FRACTION * max a``) are fitted, every channel at
    once, by least squares on ``[1, a, a^2, x - mean x, y - mean y, t - mean t]``, after
    the ``drift`` pattern is projected out of every frame. The time coefficients ``c_t``
    ``[M']`` give ``chi2 = |c_t|^2 /
    (var_t s2)`` over ``M' - 1`` degrees of freedom (``var_t`` from the design, ``s2`` the
    residual variance per entry, ~1 for well-calibrated noise, so a mis-scaled noise
    estimate cancels); the result is ``(chi2 - (M' - 1)) / sqrt(2 (M' - 1))``: about N(0, 1)
    for a still touch of any shape, large when the shape changes steadily (a closing pinch).

    Returns:
        the z-score, or NaN with fewer than ``MIN_FRAMES`` plateau frames or 8 channels.
    """
    x = np.asarray(x, dtype=np.float64)
    rows = np.isfinite(np.asarray(t_s)) & np.isfinite(xy_m).all(axis=1)
    rows &= np.isfinite(x).any(axis=1)  # a frame that came without its raw frame
    x, t, xy = x[rows], np.asarray(t_s, float)[rows], np.asarray(xy_m, float)[rows]
    cols = np.isfinite(x).all(axis=0) & np.isfinite(drift)
    x, d = x[:, cols], np.asarray(drift, float)[cols]
    if x.shape[1] < 8 or x.shape[0] < MIN_FRAMES:
        return math.nan
    # the sheet-wide drift is no shape change: leave its pattern out of every frame first
    # (then it cannot leak into the amplitude either)
    d = d / max(float(np.linalg.norm(d)), 1e-300)
    x = x - np.outer(x @ d, d)
    mean = x.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm == 0.0:
        return math.nan
    a = x @ (mean / norm)
    plateau = a >= PLATEAU_FRACTION * a.max()
    if np.count_nonzero(plateau) < MIN_FRAMES:
        return math.nan
    x, a, t, xy = x[plateau], a[plateau], t[plateau], xy[plateau]
    design = np.column_stack([np.ones(a.size), a, a * a, xy - xy.mean(axis=0), t - t.mean()])
    # scale the columns (a is hundreds of noise units, xy millimetres); a centroid that did
    # not move at all (one pixel's worth of image) leaves its column out
    scale = np.linalg.norm(design, axis=0)
    keep = scale > 0
    keep[0] = keep[-1] = True
    design = design[:, keep] / np.where(scale[keep] > 0, scale[keep], 1.0)
    coef, _, rank, _ = np.linalg.lstsq(design, x, rcond=None)
    if rank < design.shape[1]:
        return math.nan
    var_t = float(np.linalg.inv(design.T @ design)[-1, -1])
    resid = x - design @ coef
    dof = x.shape[1] - 1  # channels less the drift pattern
    s2 = float(np.sum(resid * resid)) / ((a.size - design.shape[1]) * dof)
    c_t = coef[-1]
    return float((float(c_t @ c_t) / (var_t * s2) - dof) / math.sqrt(2.0 * dof))


class TouchFilter:
    """Matched filter of the whitened raw frames for a fingertip disc at every pixel.

    The disc's pattern in volts is its relative pattern times ``|reference|``; whitened by
    each channel's noise. A sheet-wide conductivity change (the reference's own pattern)
    and each electrode's contact-impedance change (``nuisance``) are projected out of both
    the patterns and the frames: they read zero. ``z_p = (P f_p) . x / |P f_p|``. The
    projected rows are built on the first call and again whenever the set of usable channels
    changes, with that call's ``|reference|`` and ``sigma`` (a sheet-wide drift of the
    reference scales every channel alike, which the unit-norm rows do not see).

    Args:
        disc_rel: ``[H, W, M]`` relative change of every channel for a fingertip disc of
            unit relative conductivity change on each pixel (NaN off the sheet).
        inside: ``[H, W]`` bool.
        nuisance_rel: ``[M, K]`` relative patterns to project out besides the drift.
    """

    def __init__(self, disc_rel, inside, nuisance_rel=None) -> None:
        disc_rel = np.asarray(disc_rel, dtype=np.float64)
        inside = np.asarray(inside, dtype=bool)
        if disc_rel.ndim != 3 or disc_rel.shape[:2] != inside.shape:
            raise ValueError(
                f"disc_rel: [H, W, M] with [H, W] = {inside.shape}, got {disc_rel.shape}"
            )
        self.inside = inside & np.isfinite(disc_rel).all(axis=2)
        if not self.inside.any():
            raise ValueError("TouchFilter: no pixel inside the sheet")
        self._disc = disc_rel[self.inside]  # [P, M]
        self._nuisance = None if nuisance_rel is None else np.asarray(nuisance_rel, float)
        self._rows: np.ndarray | None = None  # [P, M'] projected, unit-norm rows
        self._norms: np.ndarray | None = None  # [P] the projected rows' norms before that
        self._usable: np.ndarray | None = None

    def statistic(self, change, sigma, reference) -> np.ndarray:
        """``[..., H, W]`` z maps of whitened changes ``[..., M]`` (NaN: channel left out)."""
        change = np.asarray(change, dtype=np.float64)
        usable = np.isfinite(change).reshape(-1, change.shape[-1]).all(axis=0)
        usable &= np.isfinite(sigma) & np.isfinite(reference)
        if self._rows is None or not np.array_equal(usable, self._usable):
            self._usable = usable
            scale = np.abs(reference[usable]) / sigma[usable]
            rows = self._disc[:, usable] * scale
            columns = [reference[usable] / sigma[usable]]
            if self._nuisance is not None:
                columns += list((self._nuisance[usable] * scale[:, None]).T)
            basis, _ = np.linalg.qr(np.column_stack(columns))
            rows = rows - (rows @ basis) @ basis.T
            norm = np.linalg.norm(rows, axis=1, keepdims=True)
            self._norms = norm[:, 0]
            self._rows = rows / np.maximum(norm, np.finfo(float).tiny)
        x = change[..., usable]
        out = np.full((*change.shape[:-1], *self.inside.shape), np.nan)
        out[..., self.inside] = x @ self._rows.T
        return out

    def fit_discs(
        self, change, sigma, reference, noise, fraction: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Fingertip discs that together explain one whitened change, by greedy pursuit.

        The greedy path: the first disc is the best-matching pixel (the largest value of
        :meth:`statistic`); each next one is the pixel best matching what the discs before
        leave (their least-squares fit), and then every disc is moved in turn to the best
        match of what the others leave, until none moves (:meth:`_polish`). The number of
        discs is chosen by the risk inflation criterion: the fit's residual sum of squares
        plus ``2 ln P s^2`` per disc (``P`` pixels, ``s`` the median of ``noise``; the
        universal threshold ``sqrt(2 ln P)`` squared, about what the best of ``P`` places
        explains of noise alone) is least. The path stops at :data:`MOST_DISCS` discs or
        when a further disc, the others moved too, explains less than that penalty. The
        whole polished fit is tested, not the further disc's match before the others move: a
        wide grab's first disc sits between its fingers and leaves little to match until
        they move. Only fits with every coefficient positive (a touch raises the
        conductivity) and every **amplitude** at least ``fraction`` of the largest count
        (what one finger's pattern mismatch leaves is a few per cent of its amplitude). An
        amplitude is a coefficient over its pattern's norm: the disc's relative conductivity
        change, so a finger's force whatever the sensitivity at its place.

        Args:
            change: ``[M]`` whitened change (NaN: channel left out).
            sigma: ``[M]`` channel noise, V.
            reference: ``[M]`` reference frame, V.
            noise: ``[H, W]`` noise of the map of such changes (same unit as the map; no
                positive value: one disc).
            fraction: smallest amplitude of a further disc, relative to the largest.

        Returns:
            ``(places, amplitudes)``: ``[D, 2]`` fractional (row, column) pixel indices
            (between pixel centres: :meth:`_between_pixels`) and ``[D]`` amplitudes (> 0),
            ``1 <= D <= MOST_DISCS``, strongest first; ``D = 0`` if no pixel matches the
            change positively.
        """
        change = np.asarray(change, dtype=np.float64)
        self.statistic(change, sigma, reference)  # the rows for these channels
        x = change[self._usable]
        rows, norms = self._rows, self._norms
        scale = np.asarray(noise, dtype=np.float64)[self.inside]
        scale = scale[np.isfinite(scale) & (scale > 0)]
        penalty = math.inf
        if scale.size:
            penalty = 2.0 * math.log(max(rows.shape[0], 2)) * float(np.median(scale)) ** 2
        chosen = [self._best_match(x, [])]
        fit = rows[chosen] @ x
        if not fit[0] > 0:  # nothing matches a touch
            return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        path, left = chosen, self._residual(x, chosen)
        least = left + penalty
        while len(path) < MOST_DISCS:
            path = self._polish(x, [*path, self._best_match(x, path)], MOST_DISCS)
            before, left = left, self._residual(x, path)
            if not before - left > penalty:  # no more than noise would explain
                break
            coef = np.linalg.lstsq(rows[path].T, x, rcond=None)[0]
            amplitude = coef / norms[path]
            cost = left + penalty * len(path)
            if np.all(coef > 0) and amplitude.min() >= fraction * amplitude.max() and cost < least:
                chosen, fit, least = path, coef, cost
        places, amplitude = self._between_pixels(x, chosen, fit / norms[chosen])
        order = np.argsort(-amplitude)
        return places[order], amplitude[order]

    def _between_pixels(
        self, x: np.ndarray, chosen: list[int], amplitude: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``([D, 2] (row, column), [D] amplitudes)`` of the ``chosen`` discs between pixels.

        Each disc in turn: what the other discs leave of ``x`` (their coefficients in the
        joint least-squares fit) is fitted, by non-negative
        least squares, with the patterns of its pixel and the (up to) 8 around it; its
        amplitude is the sum of theirs, its place (fractional pixel indices) their
        amplitude-weighted mean. A contact lies between pixel centres, and near an electrode
        the pattern changes so fast from one pixel to the next that the nearest pixel's
        amplitude is off by up to 2x. A disc nothing fits there keeps its pixel and
        ``amplitude``.
        """
        pixels = np.argwhere(self.inside)
        index = np.full(self.inside.shape, -1)
        index[self.inside] = np.arange(pixels.shape[0])
        places = pixels[chosen].astype(np.float64)
        amplitude = np.array(amplitude, dtype=np.float64)
        coef = np.linalg.lstsq(self._rows[chosen].T, x, rcond=None)[0]  # the joint fit
        for i, p in enumerate(chosen):
            others = chosen[:i] + chosen[i + 1 :]
            left = x - self._rows[others].T @ np.delete(coef, i)
            r, c = pixels[p]
            block = index[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2].ravel()
            block = block[block >= 0]
            local = nnls(self._rows[block].T, left)[0] / self._norms[block]
            if local.sum() > 0:
                places[i] = local @ pixels[block] / local.sum()
                amplitude[i] = local.sum()
        return places, amplitude

    def _fitted(self, x: np.ndarray, chosen: list[int]) -> np.ndarray:
        """``[M']`` least-squares fit of the ``chosen`` rows' patterns to ``x`` (0: none)."""
        if not chosen:
            return np.zeros_like(x)
        basis = self._rows[chosen].T  # [M', D]
        return basis @ np.linalg.lstsq(basis, x, rcond=None)[0]

    def _residual(self, x: np.ndarray, chosen: list[int]) -> float:
        """Residual sum of squares of the ``chosen`` rows' least-squares fit to ``x``."""
        left = x - self._fitted(x, chosen)
        return float(left @ left)

    def _best_match(self, x: np.ndarray, others: list[int]) -> int:
        """The row (not one of ``others``) best matching what the ``others`` leave of ``x``.

        The best match, not the best z-score: that would lean to quiet pixels.
        """
        match = (x - self._fitted(x, others)) @ self._rows.T
        match[others] = -np.inf
        return int(np.argmax(match))

    def _polish(self, x: np.ndarray, chosen: list[int], rounds: int) -> list[int]:
        """``chosen`` rows, each moved in turn to the best match of what the others leave.

        Until none moves, at most ``rounds`` rounds: a greedy first disc lands between two
        fingers (it matches both a little), and the second then beside the other one.
        """
        chosen = list(chosen)
        for _ in range(rounds):
            moved = False
            for i in range(len(chosen)):
                best = self._best_match(x, chosen[:i] + chosen[i + 1 :])
                moved |= best != chosen[i]
                chosen[i] = best
            if not moved:
                break
        return chosen
