"""Contact regions in reconstructed images: noise estimate, hysteresis segmentation, tracking.

A reconstructed pressure image (Pa, ``[H, W]``, NaN outside the sheet) is noisy everywhere and
blurred around a touch. Contacts are found relative to the image noise ``sigma`` (same unit as
the image), estimated robustly from no-touch frames (:func:`estimate_noise`):

1. hysteresis: connected regions (8-neighbour) of pixels above the low threshold that contain
   at least one pixel above the high threshold. The thresholds are ``k_low * sigma`` and
   ``k_high * sigma``, raised to ``artifact_fraction / 2`` and ``artifact_fraction`` of the
   frame's largest value: a one-step EIT reconstruction of a strong touch rings elsewhere on
   the sheet with a few per cent of its peak, which no noise threshold removes;
2. splitting: EIT blur merges nearby fingertips into one region, so each region is split into
   the separate peaks it holds at ``split_fraction`` of its maximum; every pixel of the region
   goes to the nearest peak;
3. each part is a :class:`Contact`: value-weighted centroid (m, patch frame), area (m^2, the
   pixels above ``k_low * sigma``), peak and mean (image unit).

:class:`ContactTracker` keeps ids across frames: nearest-neighbour assignment (Hungarian) within
a gate in metres; a track missing for more than ``max_missed`` frames is dropped.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from eit_skin.touch.noise_count import NoiseCount
from eit_skin.touch.settings import check_settings, setting

MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution per median absolute deviation."""
_EIGHT = np.ones((3, 3), dtype=bool)


def estimate_noise(images: np.ndarray) -> float:
    """Robust noise standard deviation of no-touch images ``[T, H, W]`` (image unit).

    Each pixel's temporal median is removed (the static reconstruction offset), then the
    median absolute deviation over all finite samples is scaled to a standard deviation, so a
    brief touch or a few outliers among the frames barely change it. With a single frame
    ``[H, W]`` the spatial median is removed instead.

    Raises:
        ValueError: no finite sample, or the noise is zero.
    """
    a = np.asarray(images, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"noise estimate needs images [T, H, W], got shape {a.shape}")
    a = np.where(np.isfinite(a), a, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels outside the sheet
        if a.shape[0] >= 3:
            centred = a - np.nanmedian(a, axis=0, keepdims=True)
        else:
            centred = a - np.nanmedian(a)
    values = np.abs(centred[np.isfinite(centred)])
    if values.size == 0:
        raise ValueError("noise estimate: no finite pixel in the images")
    sigma = MAD_TO_SIGMA * float(np.median(values))
    if not sigma > 0:
        raise ValueError("noise estimate: the images do not vary (zero noise)")
    return sigma


def estimate_noise_map(images: np.ndarray, window: int = 5) -> np.ndarray:
    """Per-pixel robust noise ``[H, W]`` of no-touch images ``[T, H, W]`` (image unit).

    EIT image noise is not uniform over the sheet. Each pixel's median absolute deviation over
    time (scaled to a standard deviation) is averaged over a ``window`` x ``window``
    neighbourhood (few frames give a noisy per-pixel estimate) and floored at half the global
    :func:`estimate_noise`. Pixels outside the sheet get the global value.
    """
    a = np.asarray(images, dtype=np.float64)
    if a.ndim != 3 or a.shape[0] < 3:
        raise ValueError(f"noise map needs >= 3 images [T, H, W], got shape {a.shape}")
    overall = estimate_noise(a)
    a = np.where(np.isfinite(a), a, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mad = np.nanmedian(np.abs(a - np.nanmedian(a, axis=0)), axis=0) * MAD_TO_SIGMA
    ok = np.isfinite(mad)
    total = ndimage.uniform_filter(np.where(ok, mad, 0.0), window, mode="constant")
    weight = ndimage.uniform_filter(ok.astype(float), window, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = total / weight
    smooth = np.where(ok & np.isfinite(smooth), smooth, overall)
    return np.maximum(smooth, 0.5 * overall)


MAX_NOISE_LAGS = 10
"""Longest lag (images) :func:`noise_sample_frames` measures a correlation at."""


def noise_sample_frames(images: np.ndarray, averaged: int = 1) -> float:
    """Consecutive no-touch images ``[T, H, W]`` per independent sample of their noise.

    A variance estimated from ``T`` images of stationary Gaussian noise whose images are
    correlated ``rho_k`` at lag ``k`` spreads like one from ``T / c`` independent images,
    ``c = 1 + 2 sum_k rho_k^2``. Measured: each pixel's lag-``k`` autocorrelation (its
    temporal mean removed), the median over the finite pixels, for ``k = 1 ..
    min(MAX_NOISE_LAGS, T // 4)``. Never below ``averaged`` (one sample per running mean of
    ``n`` frames, the count the START bars were set with): white frames alone give less,
    ``(2 n^2 + 1) / (3 n)`` (1.5 for two), and that margin is kept; a device whose frames
    wander in time gives more, and then the measured count is used.
    """
    a = np.asarray(images, dtype=np.float64)
    if a.ndim != 3:
        raise ValueError(f"noise_sample_frames needs images [T, H, W], got shape {a.shape}")
    floor = float(max(int(averaged), 1))
    flat = a.reshape(a.shape[0], -1)
    flat = flat[:, np.isfinite(flat).all(axis=0)]
    lags = min(MAX_NOISE_LAGS, a.shape[0] // 4)
    if flat.shape[1] == 0 or lags < 1:
        return floor
    x = flat - flat.mean(axis=0)
    var = (x * x).mean(axis=0)
    x, var = x[:, var > 0], var[var > 0]
    if var.size == 0:
        return floor
    rho = np.array([np.median((x[k:] * x[:-k]).mean(axis=0) / var) for k in range(1, lags + 1)])
    return max(floor, 1.0 + 2.0 * float(np.sum(rho**2)))


@dataclass(frozen=True)
class SegmentationConfig:
    """Thresholds of the hysteresis segmentation, as multiples of the noise ``sigma``.

    Each field is a :func:`~eit_skin.touch.settings.setting` (type, bounds, unit, meaning),
    offered as a parameter of the ``eit_classifier`` node. With Gaussian noise a pixel
    exceeds 6 sigma with probability 1e-9 per frame.
    """

    k_high: float = setting(
        6.0, "noise sigmas", "> 0", "contact seed threshold: a region needs a pixel above it"
    )
    k_low: float = setting(
        3.0, "noise sigmas", "> 0", "contact growth threshold: regions grow over pixels above it"
    )
    split_fraction: float = setting(
        0.5, "", "(0, 1)", "fraction of a region's peak at which separate peaks are split apart"
    )
    artifact_fraction: float = setting(
        0.2,
        "",
        "[0, 1)",
        "a region whose peak is below this fraction of the frame's largest value is a "
        "reconstruction artifact (sidelobe), not a contact",
    )
    min_pixels: int = setting(
        2, "pixels", ">= 1", "regions with fewer pixels above k_low are ignored"
    )

    def __post_init__(self) -> None:
        check_settings(self)
        if not self.k_low <= self.k_high:
            raise ValueError(f"need 0 < k_low <= k_high, got {self.k_low} and {self.k_high}")


@dataclass(frozen=True)
class Contact:
    """One contact region of one image.

    Attributes:
        centroid_m: ``(x, y)`` value-weighted centroid, m, patch frame.
        area_m2: area of the region's pixels, m^2.
        peak: largest value in the region (image unit, Pa for pressure).
        mean: mean value over the region (image unit).
        n_pixels: pixels in the region.
    """

    centroid_m: tuple[float, float]
    area_m2: float
    peak: float
    mean: float
    n_pixels: int

    @property
    def radius_m(self) -> float:
        """Radius of the disc of the same area, m."""
        return float(np.sqrt(self.area_m2 / np.pi))


class ContactSegmenter:
    """Segments contacts in ``[H, W]`` images on a regular pixel grid.

    Args:
        x: ``[W]`` pixel-centre x, m (uniform spacing).
        y: ``[H]`` pixel-centre y, m.
        noise_sigma: image noise standard deviation (image unit), > 0: a scalar or a
            per-pixel ``[H, W]`` map (:func:`estimate_noise_map`).
        config: thresholds.
    """

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        noise_sigma: float | np.ndarray,
        config: SegmentationConfig | None = None,
    ) -> None:
        self.x = np.asarray(x, dtype=np.float64)
        self.y = np.asarray(y, dtype=np.float64)
        if self.x.ndim != 1 or self.y.ndim != 1 or self.x.size < 2 or self.y.size < 2:
            raise ValueError("pixel coordinates x [W] and y [H] need at least 2 entries each")
        sigma = np.asarray(noise_sigma, dtype=np.float64)
        if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
            raise ValueError("noise_sigma must be finite and > 0")
        if sigma.ndim not in (0, 2) or (sigma.ndim == 2 and sigma.shape != (y.size, x.size)):
            raise ValueError(f"noise_sigma: a scalar or [H, W] = {(len(y), len(x))} map")
        self.noise_sigma = float(sigma) if sigma.ndim == 0 else sigma
        self.config = config or SegmentationConfig()
        self.pixel_area_m2 = float(abs(self.x[1] - self.x[0]) * abs(self.y[1] - self.y[0]))
        self._xx, self._yy = np.meshgrid(self.x, self.y)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.y.size, self.x.size)

    @property
    def high(self) -> float:
        return self.config.k_high * self.noise_sigma

    @property
    def low(self) -> float:
        return self.config.k_low * self.noise_sigma

    def labels(self, image: np.ndarray) -> tuple[np.ndarray, int]:
        """``([H, W] int32 labels, n)``: 0 is background, 1..n the contacts of ``image``."""
        img = np.asarray(image, dtype=np.float64)
        if img.shape != self.shape:
            raise ValueError(f"image shape {img.shape} does not match the grid {self.shape}")
        img = np.where(np.isfinite(img), img, -np.inf)
        top = float(img.max()) if img.size else -np.inf
        high = np.maximum(self.high, self.config.artifact_fraction * top)
        low = img > np.maximum(self.low, 0.5 * self.config.artifact_fraction * top)
        regions, n = ndimage.label(low, structure=_EIGHT)
        if n == 0:
            return regions, 0
        index = np.arange(1, n + 1)
        peaks = ndimage.maximum(img, regions, index)
        # seeds: pixels above the (per-pixel) high threshold
        seeded = ndimage.maximum((img > high).astype(np.int8), regions, index) > 0
        sizes = np.bincount(regions.ravel(), minlength=n + 1)[1:]
        keep = np.zeros(n + 1, dtype=bool)
        keep[1:] = seeded & (sizes >= self.config.min_pixels)
        regions = np.where(keep[regions], regions, 0)
        if not keep.any():
            return np.zeros_like(regions), 0
        # split every region at split_fraction of its own peak; nearest peak owns each pixel
        region_peak = np.zeros(n + 1)
        region_peak[1:] = peaks
        cores = (regions > 0) & (img > self.config.split_fraction * region_peak[regions])
        core_labels, n_cores = ndimage.label(cores, structure=_EIGHT)
        _, (iy, ix) = ndimage.distance_transform_edt(core_labels == 0, return_indices=True)
        parts = np.where(regions > 0, core_labels[iy, ix], 0).astype(np.int32)
        return parts, n_cores

    def segment(self, image: np.ndarray) -> list[Contact]:
        """Contacts of one image ``[H, W]``, strongest peak first."""
        return self.segment_with_labels(image)[0]

    def segment_with_labels(self, image: np.ndarray) -> tuple[list[Contact], np.ndarray]:
        """``(contacts, [H, W] int32 part labels)`` of one image (0: no contact)."""
        parts, n = self.labels(image)
        if n == 0:
            return [], parts
        img = np.where(np.isfinite(image), image, 0.0).astype(np.float64)
        flat = parts.ravel()
        w = np.where(flat > 0, np.clip(img.ravel(), 0.0, None), 0.0)
        count = np.bincount(flat, minlength=n + 1)[1:]
        wsum = np.bincount(flat, weights=w, minlength=n + 1)[1:]
        vsum = np.bincount(flat, weights=img.ravel(), minlength=n + 1)[1:]
        cx = np.bincount(flat, weights=w * self._xx.ravel(), minlength=n + 1)[1:]
        cy = np.bincount(flat, weights=w * self._yy.ravel(), minlength=n + 1)[1:]
        peak = ndimage.maximum(img, parts, np.arange(1, n + 1))
        contacts = [
            Contact(
                centroid_m=(float(cx[i] / wsum[i]), float(cy[i] / wsum[i])),
                area_m2=float(count[i] * self.pixel_area_m2),
                peak=float(peak[i]),
                mean=float(vsum[i] / count[i]),
                n_pixels=int(count[i]),
            )
            for i in range(n)
            if count[i] >= self.config.min_pixels and wsum[i] > 0
        ]
        contacts.sort(key=lambda c: -c.peak)
        return contacts, parts


@dataclass
class Track:
    """A contact followed over frames.

    Attributes:
        id: track id, unique per tracker.
        contact: latest contact.
        first_seen_s, last_seen_s: times of the first and latest frame it was seen, s.
        start_m: ``(x, y)`` centroid when first seen, m.
        missed: consecutive frames without a match.
        frames: frames it was seen in.
    """

    id: int
    contact: Contact
    first_seen_s: float
    last_seen_s: float
    start_m: tuple[float, float]
    missed: int = 0
    frames: int = 1
    path: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.contact.centroid_m)


class ContactTracker:
    """Keeps contact ids over frames by gated nearest-neighbour assignment.

    Args:
        gate_m: largest centroid jump between consecutive frames that keeps an id, m.
        max_missed: frames a track may go unseen before it is dropped.
    """

    def __init__(self, gate_m: float, max_missed: int = 2) -> None:
        if not gate_m > 0:
            raise ValueError(f"gate_m must be > 0, got {gate_m}")
        if max_missed < 0:
            raise ValueError(f"max_missed must be >= 0, got {max_missed}")
        self.gate_m = float(gate_m)
        self.max_missed = int(max_missed)
        self.tracks: list[Track] = []
        self._next_id = 1

    def update(self, t_s: float, contacts: list[Contact]) -> list[Track]:
        """Match this frame's contacts to the tracks; returns the tracks seen in this frame."""
        matched_tracks: set[int] = set()
        matched_contacts: set[int] = set()
        if self.tracks and contacts:
            a = np.array([tr.position for tr in self.tracks])
            b = np.array([c.centroid_m for c in contacts])
            d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
            rows, cols = linear_sum_assignment(np.where(d <= self.gate_m, d, 1e6))
            for r, c in zip(rows, cols, strict=True):
                if d[r, c] <= self.gate_m:
                    tr = self.tracks[r]
                    tr.contact = contacts[c]
                    tr.last_seen_s = t_s
                    tr.missed = 0
                    tr.frames += 1
                    tr.path.append((t_s, *contacts[c].centroid_m))
                    matched_tracks.add(r)
                    matched_contacts.add(c)
        survivors = []
        for i, tr in enumerate(self.tracks):
            if i not in matched_tracks:
                tr.missed += 1
                if tr.missed > self.max_missed:
                    continue
            survivors.append(tr)
        for j, c in enumerate(contacts):
            if j not in matched_contacts:
                tr = Track(self._next_id, c, t_s, t_s, c.centroid_m, path=[(t_s, *c.centroid_m)])
                self._next_id += 1
                survivors.append(tr)
        self.tracks = survivors
        return [tr for tr in self.tracks if tr.missed == 0]

    def reset(self) -> None:
        """Forget every track (ids keep counting up)."""
        self.tracks = []


LEARN_FRACTION = 0.6
"""Default ``learn_fraction`` of :class:`PooledDetector` (``ClassifierConfig.learn_fraction``):
the pooled noise is learnt only from images whose z-scores all stay below this fraction of the
detector threshold (pure noise nearly always does: its largest pooled z-score over a sheet is
about 2, rarely above 3.5)."""


class PooledDetector:
    """Early touch detector: the image pooled over a fingertip-sized kernel, in its own noise.

    A fingertip's reconstructed image is a blob much wider than a pixel, while part of the image
    noise changes from pixel to pixel; a Gaussian-weighted mean over the sheet (a matched filter
    for a blob of about the kernel's width; normalised convolution, pixels outside the sheet
    left out) keeps the blob and averages that noise down. The pooled image is thresholded in
    units of ITS noise ``z = pooled / sigma_pooled`` (per-pixel map estimated from no-touch
    frames exactly like the image noise, but by standard deviations). Each image's median over
    the sheet is removed first: pooling averages pixel noise down but keeps a sheet-wide
    offset (drift the baseline has not caught up with yet) whole; a touch covers far less
    than half of the sheet.

    Persistence: per pixel, ``run`` counts consecutive frames with ``z > k`` at that pixel or
    one of its 8 neighbours in the previous frame (a touch may drift by a pixel per frame);
    a detection is ``run.max() >= frames``, checked by the caller. A first crossing whose
    neighbourhood was above ``k / 2`` in the previous frame, with the two z-scores averaging
    ``k`` or more, counts that frame too (run 2): a press rising fast from below ``k`` is
    detected a frame earlier, while two frames of noise must still average ``k`` (about
    ``k sqrt(2/3)`` sigmas of the two-frame sum for the classifier's 2-frame running mean).
    That bar holds for the calibrated noise only: the caller clears :attr:`rising` while the
    noise is not (an electrode left out, a sheet that flickers), and two crossings are needed.

    Args:
        inside: ``[H, W]`` bool, pixels on the sheet.
        kernel_px: standard deviation of the Gaussian kernel, pixels (> 0).
        k: threshold, multiples of the pooled image's noise (> 0).
        frames_per_sample: frames in each image's running mean (the classifier's
            ``average_frames``): the fewest images per independent noise sample the noise
            estimate counts (:func:`noise_sample_frames`, measured at calibration).
        learn_fraction: only images whose z-scores all stay below ``learn_fraction * k``
            teach the noise (:attr:`quiet`), in (0, 1].

    Attributes:
        rising: whether a rising first crossing counts the frame before (default True).
    """

    def __init__(
        self,
        inside: np.ndarray,
        kernel_px: float,
        k: float,
        frames_per_sample: int = 1,
        learn_fraction: float = LEARN_FRACTION,
    ) -> None:
        inside = np.asarray(inside, dtype=bool)
        if inside.ndim != 2 or not inside.any():
            raise ValueError("PooledDetector: inside must be an [H, W] mask with a True pixel")
        if not kernel_px > 0 or not k > 0:
            raise ValueError(f"kernel_px and k must be > 0, got {kernel_px} and {k}")
        if not 0 < learn_fraction <= 1:
            raise ValueError(f"learn_fraction must be in (0, 1], got {learn_fraction}")
        self.inside = inside
        self.kernel_px = float(kernel_px)
        self.k = float(k)
        self.frames_per_sample = max(int(frames_per_sample), 1)
        self.learn_fraction = float(learn_fraction)
        self._weight = ndimage.gaussian_filter(
            inside.astype(np.float64), self.kernel_px, mode="constant"
        )
        self.noise: np.ndarray | None = None
        self._noise_var: np.ndarray | None = None
        self._noise_floor = 0.0
        self.count = NoiseCount(0, self.frames_per_sample)  # samples behind the noise map
        self.pooled = np.full(inside.shape, np.nan)
        self.z = np.zeros(inside.shape)
        self.run = np.zeros(inside.shape, dtype=np.int64)
        self.rising = True

    def pool(self, images: np.ndarray) -> np.ndarray:
        """Gaussian-weighted mean of ``images`` ``[..., H, W]`` over the sheet (NaN outside).

        Each image's median over the sheet is removed first.
        """
        a = np.asarray(images, dtype=np.float64)
        a = np.where(self.inside & np.isfinite(a), a, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN image
            a = a - np.nanmedian(a, axis=(-2, -1), keepdims=True)
        a = np.where(np.isfinite(a), a, 0.0)
        sigma = (0.0,) * (a.ndim - 2) + (self.kernel_px, self.kernel_px)
        total = ndimage.gaussian_filter(a, sigma, mode="constant")
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.inside, total / self._weight, np.nan)

    def learn_noise(self, images: np.ndarray) -> None:
        """Noise map of the pooled image from >= 3 no-touch (baseline-free) frames ``[T, H, W]``.

        Each pixel's standard deviation over the frames (floored at half the global robust
        :func:`estimate_noise`), not its MAD: a pooled pixel's few calibration values are
        smooth in time, and their MAD put single pixels at 0.23 of their noise (idle small
        disc, one-step NOSER: a false push right after calibration); a touch among them only
        raises the estimate, which learning then brings down. :meth:`follow_noise` keeps
        learning it. Neighbouring pooled pixels share most of their noise, so few frames
        estimate the whole map too low or too high together: the
        map used is inflated by two standard errors of its estimate,
        :attr:`~eit_skin.touch.noise_count.NoiseCount.inflation` (``T`` frames count as
        ``T / c`` samples, ``c`` the :func:`noise_sample_frames` of the pooled maps: x1.41
        after 0.5 s at 50 Hz, x1.06 after ~20 s of learning).
        """
        self.learn_pooled_noise(self.pool(images))

    def learn_pooled_noise(self, pooled: np.ndarray) -> None:
        """:meth:`learn_noise` from already pooled no-touch maps ``[T, H, W]``.

        E.g. the raw frames' :class:`~eit_skin.touch.frame_evidence.TouchFilter` statistic.
        """
        pooled = np.where(self.inside, np.asarray(pooled, dtype=np.float64), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # pixels off the sheet
            var = np.nanvar(pooled, axis=0, ddof=1)
        self._noise_floor = 0.5 * estimate_noise(pooled)
        self._noise_var = np.where(np.isfinite(var), var, self._noise_floor**2)
        self.count = NoiseCount(
            pooled.shape[0], noise_sample_frames(pooled, self.frames_per_sample), efficiency=1.0
        )
        self._set_noise()
        self.reset()

    @property
    def sample_frames(self) -> float:
        """Consecutive images per independent sample of the pooled noise (calibration)."""
        return self.count.sample_frames

    def _set_noise(self) -> None:
        sigma = np.maximum(np.sqrt(self._noise_var), self._noise_floor)
        self.noise = sigma * self.count.inflation

    def update(self, signal: np.ndarray) -> int:
        """Pool one baseline-free image ``[H, W]``; the longest run (frames) of ``z > k``."""
        return self._step(self.pool(signal))  # pooled maps are NaN off the sheet already

    def update_pooled(self, pooled: np.ndarray) -> int:
        """:meth:`update` from an already pooled map ``[H, W]``; the longest run of ``z > k``.

        The map is of the kind given to :meth:`learn_pooled_noise`.
        """
        return self._step(np.where(self.inside, np.asarray(pooled, dtype=np.float64), np.nan))

    def _step(self, pooled: np.ndarray) -> int:
        """One float64 map ``[H, W]``, NaN off the sheet; the longest run of ``z > k``."""
        if self.noise is None:
            raise RuntimeError("PooledDetector.update before calibrate")
        self.pooled = pooled
        # the previous frame's neighbourhood: needed by the rising-press rule only
        before = ndimage.maximum_filter(self.z, size=3, mode="constant") if self.rising else None
        with np.errstate(invalid="ignore"):
            self.z = np.where(self.inside, self.pooled / self.noise, 0.0)
        hit = self.z > self.k
        run = ndimage.maximum_filter(self.run, size=3, mode="constant")
        # a rising touch: a previous frame above k / 2 whose z-score and this one's average k
        # or more counts as a crossing (one frame earlier for a press that starts fast)
        if before is not None:
            rising = hit & (run == 0) & (before > 0.5 * self.k) & (before + self.z >= 2 * self.k)
            run = run + rising
        self.run = np.where(hit, run + 1, 0)
        return int(self.run.max())

    @property
    def quiet(self) -> bool:
        """No pooled z-score of the latest image above ``learn_fraction * k``.

        Only such frames teach the noise: a touch building up below ``k`` is no noise.
        """
        return bool(np.max(self.z) <= self.learn_fraction * self.k)

    @property
    def hit(self) -> bool:
        """Some pixel of the latest pooled image is above ``k`` noise sigmas."""
        return bool(self.run.max() > 0)

    def follow_noise(self, alpha: float) -> None:
        """Learn the noise from the latest pooled image (nothing touching, :attr:`quiet`).

        Its square joins the variance map by :meth:`~eit_skin.touch.noise_count.NoiseCount.learn`
        (a running mean while few samples were seen, then weight ``alpha`` per frame).
        """
        if self._noise_var is None or not alpha > 0:
            return
        weight = self.count.learn(alpha)
        ok = np.isfinite(self.pooled)
        self._noise_var[ok] += weight * (self.pooled[ok] ** 2 - self._noise_var[ok])
        self._set_noise()

    def reset(self) -> None:
        """Forget the runs (e.g. after a touch, until the pooled image falls silent again)."""
        self.run = np.zeros(self.inside.shape, dtype=np.int64)
        self.z = np.zeros(self.inside.shape)
