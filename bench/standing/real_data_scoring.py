"""Scores of reconstructed images of the real-device recordings in ``data/real/``.

One place for the rules, shared by ``bench/standing/bench_real_data.py`` (which imports it as a
sibling module) and ``test/pipeline/test_real_data.py`` (which loads this file with ``importlib``),
so that the benchmark's table and the regression test measure the same thing. It depends on
numpy and scipy only, never on a reconstruction package: every tool is scored by the same
rules from its images ``[T, H, W]`` on pixel centres ``x [W]``, ``y [H]`` (metres).

Blob of the expected sign (scale-free, the same for every tool): in each image, signed so
that the expected change (``expected_sign``: -1 insulating, +1 conductive) is positive, the
pixels at or above half of the image's own maximum form a mask; its 8-connected components
are the blobs, each placed at its amplitude-weighted centroid and ranked by summed amplitude.
An image with no pixel of the expected sign has no blob.

Position error (frames with documented targets): the ``K`` targets of a frame are matched to
the ``K`` strongest blobs one-to-one with the smallest total distance; when the image shows
fewer blobs than targets, every target is measured to its nearest blob (targets the image
merged both count); with no blob at all the error is the sheet's diameter (no answer can be
further off), and it is counted.

Image quality (artefacts cannot hide behind a matched blob): the blobs of *either* sign are
the 8-connected components of the pixels whose magnitude is at least :data:`BLOB_FRACTION` of
the image's largest magnitude, one sign at a time; a frame's spurious blobs are those beyond
the number of its targets (``max(B - K, 0)``). The artefact energy of a frame is the fraction
of ``sum(image**2)`` over the sheet that lies farther than :data:`ARTEFACT_RADIUS_FRACTION`
of the sheet radius from every target (documented targets; on a track, the track's blob,
i.e. the frame's strongest blob of the expected sign). Both are scale-free (pixels are of
equal area) and both are 0 for an image that shows only its targets.

Track (no positions documented, an object moving around the tank): on the frames where the
object is present (RMS relative voltage change at least :data:`PRESENCE_FRACTION` of the
recording's largest), the blob positions form a track. Its direction consistency is the
fraction of consecutive steps whose angle about the sheet centre changes in the majority
sense; the circle fit residual is the RMS radial distance of the track from its least-squares
circle.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

#: Blob mask: pixels at or above this fraction of the image's extreme of the expected sign.
BLOB_FRACTION = 0.5

#: A frame shows the object when its RMS relative change is at least this fraction of the
#: recording's largest (the empty-tank frames at the start and end of a track recording).
PRESENCE_FRACTION = 0.2

#: Artefact energy: pixels farther than this fraction of the sheet radius from every target.
ARTEFACT_RADIUS_FRACTION = 0.25

_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class RealSet:
    """One recording of ``data/real/`` (keys as in its README).

    Attributes:
        name: file stem, e.g. ``"ottawa_ph1"``.
        reference: ``[M]`` object-free frame, volts or device units.
        frames: ``[T, M]`` frames, same units and order.
        ex_mat: ``[n_inj, 2]`` (source, sink) electrodes, 0-based.
        meas_mat: ``[M, 3]`` (injection, plus, minus): each number is V(plus) - V(minus).
        truth_xy: ``[T, K, 2]`` target centres, metres, NaN where not documented.
        expected_sign: -1 for an insulating target, +1 for a conductive one.
        labels: ``[T]`` what each frame shows.
    """

    name: str
    reference: np.ndarray
    frames: np.ndarray
    ex_mat: np.ndarray
    meas_mat: np.ndarray
    truth_xy: np.ndarray
    expected_sign: int
    labels: np.ndarray

    @property
    def has_positions(self) -> bool:
        """Whether any frame documents a target position."""
        return bool(np.isfinite(self.truth_xy).all(axis=-1).any())


def load_set(path: str | Path) -> RealSet:
    """Read ``<name>.npz`` of ``data/real/`` (no pickles)."""
    path = Path(path)
    with np.load(path, allow_pickle=False) as d:
        return RealSet(
            name=path.stem,
            reference=np.asarray(d["reference"], dtype=np.float64),
            frames=np.asarray(d["frames"], dtype=np.float64),
            ex_mat=np.asarray(d["ex_mat"], dtype=np.int64),
            meas_mat=np.asarray(d["meas_mat"], dtype=np.int64),
            truth_xy=np.asarray(d["truth_xy"], dtype=np.float64),
            expected_sign=int(d["expected_sign"]),
            labels=np.asarray(d["labels"]),
        )


def blobs(
    image: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    sign: float,
    fraction: float = BLOB_FRACTION,
) -> tuple[np.ndarray, np.ndarray]:
    """Blobs of the expected sign in one image, strongest first.

    Args:
        image: ``[H, W]`` image, NaN outside the sheet.
        x: ``[W]`` pixel-centre x, metres.
        y: ``[H]`` pixel-centre y, metres.
        sign: expected sign of the change (-1 or +1).
        fraction: mask threshold as a fraction of the image's extreme of that sign.

    Returns:
        ``([B, 2]`` centroids in metres, ``[B]`` summed signed amplitudes``)``; ``B = 0`` when
        no pixel has the expected sign.
    """
    s = sign * np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0)
    peak = float(s.max(initial=0.0))
    if not peak > 0:
        return np.empty((0, 2)), np.empty(0)
    labels, n = ndimage.label(s >= fraction * peak, structure=_EIGHT_CONNECTED)
    index = np.arange(1, n + 1)
    weight = ndimage.sum_labels(s, labels, index)
    xx, yy = np.meshgrid(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    cx = ndimage.sum_labels(s * xx, labels, index) / weight
    cy = ndimage.sum_labels(s * yy, labels, index) / weight
    order = np.argsort(-weight, kind="stable")
    return np.column_stack([cx, cy])[order], weight[order]


def blob_count(image: np.ndarray, fraction: float = BLOB_FRACTION) -> int:
    """Blobs of either sign: components of ``|image| >= fraction * max|image|``, per sign.

    Args:
        image: ``[H, W]`` image, NaN outside the sheet.
        fraction: mask threshold as a fraction of the image's largest magnitude.

    Returns:
        the number of 8-connected components of the positive and of the negative mask
        (0 for an image that is zero everywhere).
    """
    s = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0)
    peak = float(np.abs(s).max(initial=0.0))
    if not peak > 0:
        return 0
    n_pos = ndimage.label(s >= fraction * peak, structure=_EIGHT_CONNECTED)[1]
    n_neg = ndimage.label(-s >= fraction * peak, structure=_EIGHT_CONNECTED)[1]
    return int(n_pos + n_neg)


def artefact_energy(
    image: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    targets: np.ndarray,
    radius_m: float,
    fraction: float = ARTEFACT_RADIUS_FRACTION,
) -> float:
    """Fraction of the image's energy farther than ``fraction * radius_m`` from every target.

    Args:
        image: ``[H, W]`` image, NaN outside the sheet.
        x: ``[W]`` pixel-centre x, metres.
        y: ``[H]`` pixel-centre y, metres.
        targets: ``[K, 2]`` target centres, metres (``K = 0``: all the energy is artefact).
        radius_m: sheet radius, metres.
        fraction: the distance, as a fraction of ``radius_m``.

    Returns:
        ``sum(image**2 far) / sum(image**2)`` in ``[0, 1]``; 0 for an all-zero image.
    """
    s = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0) ** 2
    total = float(s.sum())
    if not total > 0:
        return 0.0
    xx, yy = np.meshgrid(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    far = np.ones(s.shape, dtype=bool)
    for tx, ty in np.asarray(targets, dtype=np.float64).reshape(-1, 2):
        far &= np.hypot(xx - tx, yy - ty) > fraction * radius_m
    return float(s[far].sum()) / total


def image_quality(
    images: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    targets: list[np.ndarray],
    radius_m: float,
) -> dict[str, float]:
    """Spurious blobs and artefact energy of a recording's scored frames.

    Args:
        images: ``[T, H, W]`` the scored frames' images.
        x: ``[W]`` pixel-centre x, metres.
        y: ``[H]`` pixel-centre y, metres.
        targets: ``T`` arrays ``[K_t, 2]``: each frame's targets, metres.
        radius_m: sheet radius, metres.

    Returns:
        ``blobs`` (mean blobs of either sign per frame), ``targets`` (mean targets per frame),
        ``spurious`` (mean of ``max(B - K, 0)``), ``artefact_energy`` (median over the frames
        of :func:`artefact_energy`) and ``artefact_energy_p90``.
    """
    counts = np.array([blob_count(image) for image in images], dtype=np.float64)
    k = np.array([len(t) for t in targets], dtype=np.float64)
    energy = np.array(
        [artefact_energy(im, x, y, t, radius_m) for im, t in zip(images, targets, strict=True)]
    )
    return {
        "blobs": float(counts.mean()),
        "targets": float(k.mean()),
        "spurious": float(np.maximum(counts - k, 0.0).mean()),
        "artefact_energy": float(np.median(energy)),
        "artefact_energy_p90": float(np.quantile(energy, 0.9)),
    }


def match_errors(blob_xy: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Distance (m) from each target to its blob by the module's matching rule.

    Args:
        blob_xy: ``[B, 2]`` blob centroids, strongest first, metres.
        targets: ``[K, 2]`` documented target centres, metres.

    Returns:
        ``[K]`` errors, metres; ``inf`` when there is no blob.
    """
    matched = matched_blobs(blob_xy, targets)
    return np.linalg.norm(matched - targets, axis=1)  # inf rows stay inf


def matched_blobs(blob_xy: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``[K, 2]`` the blob each target is matched to (metres; ``inf`` rows: no blob at all).

    One-to-one among the ``K`` strongest blobs with the smallest total distance; with fewer
    blobs than targets, every target takes its nearest blob.
    """
    k = len(targets)
    if len(blob_xy) == 0:
        return np.full((k, 2), np.inf)
    d = np.linalg.norm(targets[:, None, :] - blob_xy[None, :k, :], axis=-1)  # [K, min(B, K)]
    if d.shape[1] < k:
        return blob_xy[d.argmin(axis=1)]
    rows = np.arange(k)
    best = min(itertools.permutations(range(k)), key=lambda p: d[rows, list(p)].sum())
    return blob_xy[list(best)]


def position_errors(
    images: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    truth_xy: np.ndarray,
    sign: float,
    fraction: float = BLOB_FRACTION,
) -> np.ndarray:
    """Position error of every documented target of every frame.

    Args:
        images: ``[T, H, W]`` images.
        x: ``[W]`` pixel-centre x, metres.
        y: ``[H]`` pixel-centre y, metres.
        truth_xy: ``[T, K, 2]`` target centres, metres, NaN where not documented.
        sign: expected sign of the change.
        fraction: blob threshold (:func:`blobs`).

    Returns:
        ``[n]`` errors in metres (``inf`` for a target of a frame with no blob), frames in
        order, targets in their order within a frame.
    """
    out = []
    for image, truth in zip(images, truth_xy, strict=True):
        targets = truth[np.isfinite(truth).all(axis=1)]
        if len(targets):
            out.append(match_errors(blobs(image, x, y, sign, fraction)[0], targets))
    return np.concatenate(out) if out else np.empty(0)


def centre_errors(truth_xy: np.ndarray, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The "always the centre" answer's errors (m), in :func:`position_errors` order."""
    t = truth_xy.reshape(-1, 2)
    t = t[np.isfinite(t).all(axis=1)]
    return np.linalg.norm(t - np.asarray(centre, dtype=np.float64), axis=1)


def error_summary(errors: np.ndarray, radius_m: float) -> dict[str, float]:
    """Median and 90th percentile (linear interpolation) of position errors, metres.

    Args:
        errors: ``[n]`` errors, metres, ``inf`` for a target of a frame without a blob.
        radius_m: sheet radius, metres: a missing blob scores the diameter ``2 * radius_m``.

    Returns:
        ``median_m``, ``p90_m``, ``n`` (targets) and ``no_blob`` (targets without a blob).
    """
    e = np.asarray(errors, dtype=np.float64)
    missing = np.isinf(e)
    e = np.where(missing, 2.0 * radius_m, e)
    return {
        "median_m": float(np.median(e)),
        "p90_m": float(np.quantile(e, 0.9)),
        "n": int(e.size),
        "no_blob": int(missing.sum()),
    }


def present_frames(frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``[T]`` bool: frames whose RMS relative change reaches :data:`PRESENCE_FRACTION` of the max.

    The relative change is ``(v - v_ref) / |v_ref|`` per channel (zero-reference channels are
    left out); the rule looks at the data only, never at a tool's images.
    """
    ref = np.asarray(reference, dtype=np.float64)
    used = np.abs(ref) > 0
    dv = (np.asarray(frames, dtype=np.float64)[:, used] - ref[used]) / np.abs(ref[used])
    rms = np.sqrt(np.mean(dv**2, axis=1))
    return rms >= PRESENCE_FRACTION * rms.max()


def track(
    images: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    sign: float,
    fraction: float = BLOB_FRACTION,
) -> np.ndarray:
    """``[T, 2]`` strongest blob of every image (metres), NaN where an image has none."""
    out = np.full((len(images), 2), np.nan)
    for t, image in enumerate(images):
        xy, _ = blobs(image, x, y, sign, fraction)
        if len(xy):
            out[t] = xy[0]
    return out


def direction_consistency(
    positions: np.ndarray, centre: tuple[float, float] = (0.0, 0.0)
) -> tuple[float, int]:
    """Fraction of consecutive steps turning the majority way about ``centre``, and that way.

    Args:
        positions: ``[T, 2]`` track, metres; a step touching a NaN position counts as
            inconsistent.
        centre: the point the object moves around, metres.

    Returns:
        ``(fraction in [0, 1], sense)``: ``sense`` +1 counter-clockwise, -1 clockwise
        (the majority of the steps; a step of exactly zero angle goes neither way).
    """
    p = np.asarray(positions, dtype=np.float64) - np.asarray(centre, dtype=np.float64)
    angle = np.arctan2(p[:, 1], p[:, 0])
    step = np.angle(np.exp(1j * np.diff(angle)))  # wrapped to (-pi, pi]
    n = step.size
    if n == 0:
        return float("nan"), 0
    ccw = int(np.sum(step > 0))
    cw = int(np.sum(step < 0))
    sense = 1 if ccw >= cw else -1
    return max(ccw, cw) / n, sense


def circle_fit(positions: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares (algebraic, Kasa) circle through a track.

    Args:
        positions: ``[T, 2]`` track, metres (NaN rows are ignored).

    Returns:
        ``(centre [2] m, radius m, RMS radial residual m)``.
    """
    p = np.asarray(positions, dtype=np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    a = np.column_stack([2 * p, np.ones(len(p))])
    b = (p**2).sum(axis=1)
    (cx, cy, c), *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = np.array([cx, cy])
    radius = float(np.sqrt(c + cx**2 + cy**2))
    residual = np.linalg.norm(p - centre, axis=1) - radius
    return centre, radius, float(np.sqrt(np.mean(residual**2)))


def nonfinite_pixels(images: np.ndarray, inside: np.ndarray) -> int:
    """Number of non-finite pixels on the sheet (``inside`` ``[H, W]``) over all images."""
    return int((~np.isfinite(np.asarray(images)[:, inside])).sum())


def score(
    data: RealSet,
    images: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    inside: np.ndarray,
    radius_m: float,
    fraction: float = BLOB_FRACTION,
) -> dict[str, float]:
    """Every figure of one tool on one recording.

    Args:
        data: the recording.
        images: ``[T, H, W]`` the tool's images of ``data.frames`` against ``data.reference``.
        x: ``[W]`` pixel-centre x, metres.
        y: ``[H]`` pixel-centre y, metres.
        inside: ``[H, W]`` pixels on the sheet.
        radius_m: sheet radius, metres (sheets centred on the origin).
        fraction: blob threshold (:func:`blobs`).

    Returns:
        ``nonfinite``; the image quality of :func:`image_quality` (``blobs``, ``targets``,
        ``spurious``, ``artefact_energy``, ``artefact_energy_p90``); with documented
        positions ``median_m``, ``p90_m``, ``n``, ``no_blob``; otherwise ``frames``
        (present), ``consistency``, ``sense``, ``fit_radius_m`` and ``fit_residual_m``.
    """
    out: dict[str, float] = {"nonfinite": nonfinite_pixels(images, inside)}
    if data.has_positions:
        errors = position_errors(images, x, y, data.truth_xy, data.expected_sign, fraction)
        out.update(error_summary(errors, radius_m))
        documented = np.isfinite(data.truth_xy).all(axis=-1)  # [T, K]
        scored = np.flatnonzero(documented.any(axis=1))
        targets = [data.truth_xy[t][documented[t]] for t in scored]
        out.update(image_quality(images[scored], x, y, targets, radius_m))
        return out
    present = present_frames(data.frames, data.reference)
    positions = track(images[present], x, y, data.expected_sign, fraction)
    targets = [p[None, :] if np.isfinite(p).all() else np.empty((0, 2)) for p in positions]
    out.update(image_quality(images[present], x, y, targets, radius_m))
    fraction, sense = direction_consistency(positions)
    _, radius, residual = circle_fit(positions)
    out.update(
        frames=int(present.sum()),
        consistency=fraction,
        sense=sense,
        fit_radius_m=radius,
        fit_residual_m=residual,
    )
    return out
