"""Which statistic should START a touch: the pooled image, or a matched filter on the raw frames?

Issue 18 asks every START within 100 ms of contact; the face patch's light central pushes
come last (docs/classifier.md). The early START detector thresholds the reconstructed image
pooled over a fingertip-sized Gaussian (``PooledDetector``), in its own per-pixel noise. Under
white channel noise the linear statistic that best tells a fingertip at pixel ``p`` from
noise is the whitened change projected on that disc's own whitened boundary pattern
(``J disc_p |v_ref| / sigma``, the relative Jacobian in volts: the matched filter), with the
sheet-wide drift pattern (the reference) projected out; the regularised image keeps only a
smoothed part of it. A real sheet's electrodes also change their contact impedance while
nothing touches (sweat, creep, a connector); the third statistic projects the 16 patterns of
those changes out too (``contacts out``: the model's ``dV/dz_l`` per electrode, as relative
changes; a physical nuisance, no constant). This benchmark asks which would be the better
START statistic, on the simulator's scenes and on real recordings, with everything else the
same:

* both are linear in the frames' change; both are divided by their own per-pixel RMS over
  the same no-touch *calibration* frames, each map's median over the sheet removed (as the
  pooled detector does), and evaluated on *other* no-touch frames (the false-alarm side)
  and on touch frames (the detection side);
* a detection here is one map with a pixel above ``k`` (no persistence): the fraction of
  no-touch maps that fire and of touch maps that fire, at ``k`` = 4, 5.5 (the classifier's
  ``k_detect``) and 7: two points of each statistic's ROC, where the low-false-alarm end
  is what a controller needs (0.3 false events per minute at 50-100 frames a second is
  about 1e-4 per frame).

Sets (disc radius: the classifier's 6 mm fingertip on the patches, the target's radius on
the tanks and the hydrogel):

* ``sim <patch> <scene>``: the REPORT seed's ``light_push`` (the slowest STARTs) and
  ``electrode_push`` (where the contact patterns take most) scenes of
  ``bench_hard_scenes`` (frames and images as that benchmark makes them: LayerProcessor,
  the node's pipeline); 2-frame
  running means as the classifier sees them; no-touch frames 0.5 s away from any touch,
  first half calibration, second half false-alarm side; touch maps 40-100 ms after each
  touch's first frame of force (where a START within 100 ms is decided).
* ``sciospec_adjacent`` (real saline tank; the cup's size is not documented, the disc is
  a tenth of the tank's radius): its 20 object-free repeated frames give 19
  frame-to-frame differences (calibration and false-alarm side alike: too few to split, so
  its tails are not measured); the touch maps are every frame minus the last object-free one.
* ``hydrogel_ohmc16`` (real hydrogel skin pressed by a robot arm): the frame before each
  press (``ups``) differenced with the one before the previous press (first 50 of those:
  calibration; the other 449: false-alarm side; this "noise" includes what the gel kept of
  the previous press); touch maps ``downs - ups`` of presses 51-500 (10-20 mm deep).

No time is measured.

    .venv/bin/python -m bench.studies.bench_start_statistic [--out bench/studies/start_statistic.md]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.header import load_average, run_header
from bench.standing import bench_hard_scenes as scenes
from bench.standing import real_data_scoring as scoring
from eit_skin.inverse.channel_noise import difference_noise
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.touch.classifier import classifier_layers
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import PooledDetector
from eit_skin.touch.frame_evidence import TouchFilter
from eit_skin.touch.shapes import FINGER_RADIUS_M, raw_patterns, single_contact_spread

REAL = Path(__file__).resolve().parents[2] / "data" / "real"
THRESHOLDS = (4.0, 5.5, 7.0)
SEED = scenes.SEEDS["report"][0]
QUIET_MARGIN_S = 0.5
TOUCH_WINDOW_S = (0.04, 0.10)
#: Simulated scenes: the slowest STARTs, and touches where the contact patterns matter most.
SIM_SCENES = ("light_push", "electrode_push")


@dataclass
class Maps:
    """One statistic's maps ``[T, P]`` (pixels on the sheet) of one set."""

    calibration: np.ndarray
    quiet: np.ndarray
    touch: np.ndarray


def matched_maps(
    disc, inside, sigma, reference, changes: list[np.ndarray], nuisance: np.ndarray | None = None
) -> list[np.ndarray]:
    """Matched-filter maps ``[T, P]`` (pixels ``inside``) of each ``[T, M]`` change (volts).

    The classifier's own filter (``TouchFilter``): ``disc`` ``[H, W, M]`` and ``nuisance``
    ``[M, K]`` are relative changes, times ``|reference|`` volts; the changes are whitened by
    ``sigma``; the sheet-wide drift pattern (the reference) and the span of ``nuisance`` are
    projected out.
    """
    start = TouchFilter(disc, inside, nuisance)
    return [start.statistic(change / sigma, sigma, reference)[:, inside] for change in changes]


def statistics(pooled, disc, inside, contacts, sigma, reference, changes) -> dict[str, Maps]:
    """The three statistics' maps of one set (``changes``: calibration, no-touch, touch)."""
    return {
        "pooled image": Maps(*pooled),
        "matched filter": Maps(*matched_maps(disc, inside, sigma, reference, changes)),
        "matched filter, contacts out": Maps(
            *matched_maps(disc, inside, sigma, reference, changes, contacts)
        ),
    }


def pooled_detector(imager: LayerImager, radius_m: float) -> PooledDetector:
    """The classifier's START detector for ``imager``'s grid: a Gaussian kernel of
    ``detect_kernel`` times the median spread of a disc of ``radius_m`` (m)."""
    inside = np.asarray(imager.grid.inside, dtype=bool)
    spread = single_contact_spread(imager, radius_m=radius_m)
    pixel = float(abs(imager.grid.x[1] - imager.grid.x[0]))
    kernel = ClassifierConfig().detect_kernel * float(np.median(spread[inside])) / pixel
    return PooledDetector(inside, kernel, ClassifierConfig().k_detect)


def pooled_maps(detector: PooledDetector, inside, images: list[np.ndarray]) -> list[np.ndarray]:
    """Pooled-image maps ``[T, P]`` (``PooledDetector.pool``: median removed, kernel mean)."""
    return [detector.pool(a)[:, inside] for a in images]


def normalised(maps: Maps, sign: float) -> Maps:
    """Signed, median-free maps in units of their RMS over the calibration maps."""

    def centred(z):
        z = sign * z
        return z - np.median(z, axis=1, keepdims=True)

    cal = centred(maps.calibration)
    rms = np.sqrt(np.mean(cal**2, axis=0))
    return Maps(cal / rms, centred(maps.quiet) / rms, centred(maps.touch) / rms)


def row(name: str, statistic: str, maps: Maps, tails: bool) -> str:
    quiet = maps.quiet.max(axis=1)
    touch = maps.touch.max(axis=1)
    fire = " | ".join(f"{np.mean(quiet > k):.3f} / {np.mean(touch > k):.3f}" for k in THRESHOLDS)
    noise = (
        f"{np.median(quiet):.2f} / {np.quantile(quiet, 0.99):.2f} / {quiet.max():.2f}"
        if tails
        else f"{np.median(quiet):.2f} / - / -"
    )
    above = (
        f"{np.mean(touch > np.quantile(quiet, 0.99)):.3f} / {np.mean(touch > quiet.max()):.3f}"
        if tails
        else "- / -"
    )
    return (
        f"| {name} | {statistic} | {len(quiet)} / {len(touch)} | {noise} | "
        f"{np.quantile(touch, 0.1):.1f} / {np.median(touch):.1f} | {fire} | {above} |"
    )


def running_mean2(a: np.ndarray) -> np.ndarray:
    """Mean of each frame ``[T, ...]`` and the one before (the first alone): index-aligned."""
    return np.concatenate([a[:1], 0.5 * (a[1:] + a[:-1])])


def simulated(patch_name: str, scene: str, data_dir: Path, cache: Path) -> dict[str, Maps]:
    patch = load_patch(config_path(patch_name))
    layer, _ = classifier_layers(patch)
    imager = LayerImager.build(layer, cache_dir=cache)
    run = scenes.simulate(patch, scene, SEED, scenes.SECONDS, data_dir, cache)
    t = run.t
    near = np.zeros(t.size, dtype=bool)
    touch = np.zeros(t.size, dtype=bool)
    for tr in run.truth:
        near |= (t >= tr["t_start"] - QUIET_MARGIN_S) & (t <= tr["t_end"] + QUIET_MARGIN_S)
        touch |= (t >= tr["t_start"] + TOUCH_WINDOW_S[0]) & (t <= tr["t_start"] + TOUCH_WINDOW_S[1])
    n_cal = int(ClassifierConfig().calibration_s * scenes.RATE_HZ)
    quiet = np.flatnonzero(~near & (np.arange(t.size) >= n_cal))
    half = len(quiet) // 2
    cal_idx, quiet_idx, touch_idx = quiet[:half], quiet[half:], np.flatnonzero(touch)
    inside = np.asarray(imager.grid.inside, dtype=bool)
    images = running_mean2(run.pressure.astype(np.float64))
    baseline = np.nanmedian(images[:n_cal], axis=0)
    detector = pooled_detector(imager, FINGER_RADIUS_M)
    pooled = pooled_maps(
        detector, inside, [images[i] - baseline for i in (cal_idx, quiet_idx, touch_idx)]
    )
    volts = run.volts.astype(np.float64)
    reference = volts[:n_cal].mean(axis=0)
    sigma = difference_noise(volts[:n_cal])
    changes = running_mean2(volts - reference)
    disc, contacts = raw_patterns(layer, imager, FINGER_RADIUS_M)
    sets = [changes[i] for i in (cal_idx, quiet_idx, touch_idx)]
    return statistics(pooled, disc, inside, contacts, sigma, reference, sets)


def real(name: str) -> tuple[dict[str, Maps], float]:
    data = scoring.load_set(REAL / f"{name}.npz")
    with np.load(REAL / f"{name}.npz") as raw:
        extra = {k: raw[k] for k in raw.files}
    layer = load_patch(REAL / f"{name}.yaml").layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    if name == "sciospec_adjacent":
        repeated = extra["reference_frames"]
        cal = quiet = np.diff(repeated, axis=0)
        touch = data.frames - repeated[-1]
    else:  # hydrogel_ohmc16
        repeated = None
        steps = np.diff(extra["ups"], axis=0)
        cal, quiet = steps[:50], steps[50:]
        touch = (extra["downs"] - extra["ups"])[51:]
    imager.use_reference(data.reference, repeated, data.frames)
    reference = data.reference
    radius = float(np.ravel(extra["truth_r"])[0])
    if not np.isfinite(radius):  # the cup's size is not documented: a tenth of the tank
        radius = 0.1 * float(np.linalg.norm(layer.outline, axis=1).max())
    inside = np.asarray(imager.grid.inside, dtype=bool)

    def images(change):
        return imager.images(imager.relative_change(reference + change, reference)).astype(float)

    detector = pooled_detector(imager, radius)
    pooled = pooled_maps(detector, inside, [images(c) for c in (cal, quiet, touch)])
    disc, contacts = raw_patterns(layer, imager, radius)  # with a magnitude device's signs
    # channel noise: the repeated object-free frames, else the first 51 pre-press frames
    sigma = difference_noise(repeated if repeated is not None else extra["ups"][:51])
    sets = statistics(pooled, disc, inside, contacts, sigma, reference, [cal, quiet, touch])
    return sets, data.expected_sign


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", nargs="+", default=["arm", "face", "elbow"])
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/eit_skin_hard_scenes"))
    parser.add_argument("--cache-dir", type=Path, default=Path("/tmp/eit_skin_classifier_cache"))
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("start_statistic.md"))
    args = parser.parse_args()
    load = load_average()
    head = " | ".join(f"fire at k = {k:g}: no-touch / touch" for k in THRESHOLDS)
    lines = [
        f"| set | statistic | maps no-touch / touch | no-touch max-z median / p99 / max | "
        f"touch max-z p10 / median | {head} | touch above no-touch p99 / max |",
        "|---" * (6 + len(THRESHOLDS)) + "|",
    ]
    for name in args.patches:
        for scene in SIM_SCENES:
            for statistic, maps in simulated(name, scene, args.data_dir, args.cache_dir).items():
                lines.append(row(f"sim {name} {scene}", statistic, normalised(maps, 1.0), True))
                print(lines[-1], flush=True)
    for name in ("sciospec_adjacent", "hydrogel_ohmc16"):
        sets, sign = real(name)
        for statistic, maps in sets.items():
            tails = name != "sciospec_adjacent"
            lines.append(row(name, statistic, normalised(maps, sign), tails))
            print(lines[-1], flush=True)
    report = [
        "# START statistic: pooled image against matched filters on the raw frames",
        "",
        f"{run_header(load)} Its docstring has the method; no time is measured.",
        f"Simulated sets: the REPORT seed ({SEED}) of `bench_hard_scenes`' "
        f"{' and '.join(f'`{s}`' for s in SIM_SCENES)}; real",
        "sets: `data/real/` (other groups' devices).",
        "",
        *lines,
        "",
    ]
    args.out.write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
