"""How much of a close pinch's closing the raw frames carry, against what the images keep.

Issue 18 asks for close pinches (two fingers 15 mm apart closing to 5 mm) to be told from
pushes; on the face patch the classifier's image features miss most of them. This benchmark
asks whether the information is there at all. For every pinch of the REPORT seed's
``close_pinch`` and ``edge_pinch`` scenes of each patch:

* **frames (oracle bound)**: the noise-free voltage change from the start to the end of the
  closing, ``dv = v(t1) - v(t0)``, whitened by each channel's noise (from the scene's quiet
  frames), after projecting out what a push could also do: its own amplitude (the mean
  pattern), a 1 mm move in x and in y, 30 % more force, a 20 % larger contact, and a
  sheet-wide drift (the reference). ``|dv_perp| / sigma`` is the part of one frame's change
  that only a closing explains; a least-squares trend over the ``n`` closing frames has
  ``t ~ |dv_perp| / sigma * sqrt(n / 12)``. The true pattern is known here (the simulator's
  own model), so this is an upper bound on any detector.
* **frames (measured)**: a detector that could run: the scene's noisy frames, minus the
  reference (mean of the first 25 frames), each channel divided by its noise; over the
  touch's plateau (amplitude >= 80 % of its largest, the amplitude being the projection on
  the touch's mean pattern) every channel is fitted by least squares on ``[1, a, a^2,
  t - mean t]``; the time coefficients, with the sheet-wide (reference) pattern removed,
  give ``chi2 = |c_t|^2 / var(c_t)`` over ``M - 1`` channels, reported as ``z = (chi2 / s2 -
  (M - 1)) / sqrt(2 (M - 1))`` (``s2``: the fit's residual variance, ~1). A still push has
  ``z ~ N(0, 1)``; a shape that changes over the plateau (a closing pinch) a large ``z``. The
  pushes of the same patch are listed for the false-alarm side. Their simulated fingers hold
  still: a real finger that rolls or slides also changes the pattern, so a rule built on this
  needs the centroid's motion as a further regressor.
* **images**: the classifier's trend statistic of the blob's major axis (``trend``, the same
  kind of t; its rule asks ``>= pinch_trend``) and its decision, from the scene's images
  as imaged by the reconstruction pipeline (:mod:`bench_hard_scenes`).

MEASURED IN SIMULATION ONLY; no time is measured.

    .venv/bin/python -m bench.studies.bench_pinch_information [--patches face] [--out F]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from bench.header import run_header
from bench.standing import bench_hard_scenes as scenes
from bench.standing.touch_scoring import match
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.sim.drift import NO_DRIFT
from eit_skin.sim.scenario import Scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.classifier import classifier_layers
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.shapes import single_contact_spread

SEED = scenes.SEEDS["report"][0]
NUISANCE_MOVE_M = 1e-3
NUISANCE_FORCE = 1.3
NUISANCE_RADIUS = 1.2


def clean_volts(patch, layer: str, stimulus, t: float) -> np.ndarray:
    """``[M]`` noise-free, drift-free voltages of ``layer`` with only ``stimulus``, V."""
    script = Scenario("one", (stimulus,), stimulus.t_end_s + stimulus.settle_s + 1.0)
    return SkinSimulator(patch, script, scenes.RATE_HZ, drift=NO_DRIFT).clean_voltages(layer, t)


def closing_beyond_push(patch, layer: str, stimulus, sigma: np.ndarray) -> tuple[float, float, int]:
    """``(|dv|, |dv_perp|, n)``: the closing's change and its part no push explains, in noise
    units per frame, and the frames of the closing at the scene's rate."""
    t0 = stimulus.t_start_s + stimulus.ramp_s
    t1 = t0 + 0.7 * (stimulus.duration_s - 2.0 * stimulus.ramp_s)

    def mean_pattern(s) -> np.ndarray:
        return 0.5 * (clean_volts(patch, layer, s, t0) + clean_volts(patch, layer, s, t1))

    va, vb = clean_volts(patch, layer, stimulus, t0), clean_volts(patch, layer, stimulus, t1)
    ref = SkinSimulator(patch, Scenario("none", (), 1.0), scenes.RATE_HZ, drift=NO_DRIFT).reference(
        layer
    )
    mean = 0.5 * (va + vb)
    x, y = stimulus.position
    variants = [
        dataclasses.replace(stimulus, position=(x + NUISANCE_MOVE_M, y)),
        dataclasses.replace(stimulus, position=(x, y + NUISANCE_MOVE_M)),
        dataclasses.replace(stimulus, force_n=stimulus.force_n * NUISANCE_FORCE),
        dataclasses.replace(stimulus, radius_m=stimulus.radius_m * NUISANCE_RADIUS),
    ]
    nuisance = [mean - ref, ref, *(mean_pattern(s) - mean for s in variants)]
    basis, _ = np.linalg.qr(np.column_stack([n / sigma for n in nuisance]))
    delta = (vb - va) / sigma
    perp = delta - basis @ (basis.T @ delta)
    return (
        float(np.linalg.norm(delta)),
        float(np.linalg.norm(perp)),
        int((t1 - t0) * scenes.RATE_HZ),
    )


def shape_change_z(frames_v: np.ndarray, t_s: np.ndarray, touch: slice | np.ndarray) -> float:
    """Still-touch shape-change z-score of the frames ``touch`` of ``frames_v`` ``[T, M]`` V at
    ``t_s`` ``[T]`` s (see the module docstring); the first 25 frames are the reference."""
    quiet = frames_v[:25]
    sigma = np.std(np.diff(quiet, axis=0), axis=0) / np.sqrt(2.0)
    reference = quiet.mean(axis=0)
    drift = reference / sigma
    drift /= np.linalg.norm(drift)
    x = (frames_v[touch] - reference) / sigma
    t = t_s[touch]
    mean = x.mean(axis=0)
    a = x @ (mean / np.linalg.norm(mean))
    plateau = a >= 0.8 * a.max()
    x, a, t = x[plateau], a[plateau], t[plateau]
    design = np.column_stack([np.ones(a.size), a, a * a, t - t.mean()])
    coef = np.linalg.lstsq(design, x, rcond=None)[0]
    var_t = np.linalg.inv(design.T @ design)[3, 3]
    c_t = coef[3] - drift * (drift @ coef[3])
    resid = x - design @ coef
    s2 = float((resid**2).sum()) / ((a.size - design.shape[1]) * x.shape[1])
    dof = x.shape[1] - 1
    return float((c_t @ c_t / var_t / s2 - dof) / np.sqrt(2.0 * dof))


def patch_rows(name: str, data: Path, cache: Path) -> list[str]:
    patch = load_patch(config_path(name))
    layer, _ = classifier_layers(patch)
    imager = LayerImager.build(layer, cache_dir=cache)
    spread = single_contact_spread(imager)
    electrodes = np.array([e.center for e in layer.electrodes])
    pinch_trend = ClassifierConfig().pinch_trend
    rows = []
    for scene in ("close_pinch", "edge_pinch", "light_push", "electrode_push"):
        sim = scenes._simulator(patch, scene, SEED, scenes.SECONDS)
        rec = sim.run(duration_s=scenes.SECONDS)
        frames = rec.layers[layer.name].frames
        sigma = np.std(np.diff(frames[:25], axis=0), axis=0) / np.sqrt(2.0)
        run = scenes.simulate(patch, scene, SEED, scenes.SECONDS, data, cache)
        features: dict = {}
        events = scenes.classify(
            run, imager.grid.x, imager.grid.y, spread, electrodes, None, True, features
        )
        for stimulus, truth, event in zip(
            sim.scenario.touches, run.truth, match(events, run.truth), strict=True
        ):
            during = (rec.t >= truth["t_start"]) & (rec.t <= truth["t_end"])
            z = shape_change_z(frames, rec.t, during)
            if stimulus.label == "pinch":
                whole, perp, n = closing_beyond_push(patch, layer.name, stimulus, sigma)
                bound = f"{whole:.1f} | {perp:.1f} | {perp * np.sqrt(n / 12):.0f}"
            else:
                bound = "- | - | -"
            if event is None:
                image = "missed"
            else:
                f = features[event.touch_id]
                image = f"{f.trend:.1f} {'>=' if f.trend >= pinch_trend else '<'} {pinch_trend:g}"
            label = "-" if event is None else event.label
            rows.append(
                f"| {name} | {scene} | {truth['t_start']:.1f} | {bound} | {z:.1f} | {image} | "
                f"{label} |"
            )
            print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", nargs="+", default=["arm", "face", "elbow"])
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/eit_skin_hard_scenes"))
    parser.add_argument("--cache-dir", type=Path, default=Path("/tmp/eit_skin_classifier_cache"))
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).with_name("pinch_information.md")
    )
    args = parser.parse_args()
    rows = [
        "| patch | scene | touch at (s) | closing dv / sigma per frame | beyond a push | "
        "frames: trend t (bound) | frames: shape-change z | images: trend t | decided |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in args.patches:
        rows += patch_rows(name, args.data_dir, args.cache_dir)
    text = [
        "# How much of a close pinch the frames carry, and the images keep",
        "",
        f"{run_header()} Seed {SEED} (the",
        "hard-scene benchmark's report seed; its docstring defines every column). Simulation",
        "only: the bound uses the simulator's own noise-free model, so it is what an ideal",
        "detector could reach, not what a real one does.",
        "",
        *rows,
        "",
    ]
    args.out.write_text("\n".join(text))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
