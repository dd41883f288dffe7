"""Touch classifier accuracy, false events and START latency on simulated, unseen sequences.

For every shipped patch: ``random`` touch scripts of the simulator, every layer reconstructed
with the patch's imager (whatever ``solver.prior`` the config says), classified by
:class:`~eit_skin.touch.classifier.TouchClassifier`; plus a no-touch recording (drift and
noise only) for the false-event rate; for the elbow also touches with the joint held bent
(reference = the no-touch frames at that posture, i.e. posture-compensated), and on every patch
one run with a dead electrode (fault-tolerant reconstruction). Prints the tables and writes
``bench/standing/classifier.md``.

Seeds: TUNING (used while choosing features and thresholds) and EVALUATION (never looked at
while tuning) are disjoint; ``--set tuning`` scores the tuning seeds.

MEASURED IN SIMULATION ONLY: published EIT-skin and social-touch classifiers reach 60-80 % on
real people.

    .venv/bin/python -m bench.standing.bench_classifier [--set eval|tuning]
        [--patches arm face elbow]

Simulated images are cached in ``--data-dir`` (default /tmp/eit_skin_classifier_data) keyed by
the layer config's content hash, the seed and the length, so a config change re-simulates.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.header import run_header
from bench.standing.touch_scoring import balanced_accuracy, confusion, score
from eit_skin.frames import flagged_as_nan
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import Patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.sim.random_scenes import random_scenario
from eit_skin.sim.scenario import Scenario, SheetFrame
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import PostureTrack
from eit_skin.touch.classifier import TouchClassifier, classify_stream
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.events import LABELS
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.shapes import raw_patterns, single_contact_spread

RATE_HZ = 50.0
LATENCY_TARGET_S = 0.150
SECONDS = 40.0
IDLE_SECONDS = 150.0
BENT_ANGLE_RAD = 1.5
#: seeds of the random touch scripts (also noise and drift), per use; never overlapping.
#: The first evaluation set (101-107, bent 111-112, fault 121, idle 201) was looked at in the
#: START-latency failure analysis of the pooled detector, so it is retired (neither tuning nor
#: evaluation any more); the evaluation seeds below were first run with the final detector.
TUNING_SEEDS = (1, 2, 3, 4, 5, 6)
TUNING_BENT_SEEDS = (11,)
RETIRED_SEEDS = (101, 102, 103, 104, 105, 106, 107, 111, 112, 121, 201)
EVAL_SEEDS = (301, 302, 303, 304, 305, 306, 307)
EVAL_BENT_SEEDS = (311, 312)
EVAL_FAULT_SEEDS = (321,)
IDLE_SEEDS = {"tuning": 7, "eval": 401}
FAULT = "dead-electrode:5"


@dataclass
class Run:
    """Images and truth of one simulated recording."""

    t: np.ndarray
    pressure: np.ndarray
    stretch: np.ndarray | None
    x: np.ndarray
    y: np.ndarray
    truth: list[dict]
    volts: np.ndarray | None = None  # [T, M] V, the first (pressure) layer's raw frames


def _key(patch: Patch, kind: str, *parts) -> str:
    # "frames": the recordings keep the raw frames of the pressure layer (shape_z);
    # "flagged-nan": a fault recording's flagged channels are NaN in its frames and images, as
    # the nodes have them (the other kinds have no flagged channel: their data is unchanged)
    version = ["frames", "flagged-nan"] if kind == "fault" else ["frames"]
    text = json.dumps([[ly.content_hash for ly in patch.layers], *version, kind, *parts])
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def simulate(
    patch: Patch,
    kind: str,
    seed: int,
    seconds: float,
    data_dir: Path,
    cache_dir: Path,
) -> Run:
    """One recording (``kind``: touch, idle, bent, fault), simulated once and cached."""
    path = data_dir / f"{patch.name}-{kind}-{seed}-{_key(patch, kind, seed, seconds)}.npz"
    if path.is_file():
        with np.load(path) as d:
            stretch = d["stretch"] if d["stretch"].size else None
            truth = json.loads(str(d["truth"]))
            return Run(d["t"], d["pressure"], stretch, d["x"], d["y"], truth, d["volts"])
    faults = (FAULT,) if kind == "fault" else ()
    if kind == "idle":
        sim = SkinSimulator(patch, "idle", RATE_HZ, seed=seed)
    elif kind == "bent":
        script = random_scenario(seed, seconds, patch)
        frame = SheetFrame.of(patch)
        posture = PostureTrack(
            ((0.0, BENT_ANGLE_RAD),),
            crease_y_m=float(frame.center[1]),
            width_m=0.25 * float(2 * frame.half_extent[1]),
        )
        scenario = Scenario(script.name, script.touches, seconds, posture)
        sim = SkinSimulator(patch, scenario, RATE_HZ, seed=seed)
    else:
        sim = SkinSimulator(patch, "random", RATE_HZ, seed=seed, duration_s=seconds, faults=faults)
    rec = sim.run(duration_s=seconds)
    quiet = rec.t < (rec.truth[0].t_start_s if rec.truth else rec.t[-1] + 1)
    imgs, frames = {}, {}
    for layer in patch.layers:
        imager = LayerImager.build(layer, cache_dir=cache_dir)
        lr = rec.layers[layer.name]
        frames[layer.name] = flagged_as_nan(lr.frames, lr.flags)  # per frame, as the nodes
        # posture-compensated reference: the mean no-touch frame at the posture held
        reference = lr.frames[quiet].mean(axis=0) if kind == "bent" else lr.reference
        if kind == "fault":
            rel = imager.fault_tolerant().reconstruct(frames[layer.name], reference)
        else:
            rel = imager.relative_change(frames[layer.name], reference)
        imgs[layer.name] = (imager.physical(imager.images(rel)), imager.grid)
    pressure, grid = imgs[patch.layers[0].name]
    volts = frames[patch.layers[0].name]
    stretch = imgs["stretch"][0] if "stretch" in imgs else None
    truth = [{"label": tr.label, "t_start": tr.t_start_s, "t_end": tr.t_end_s} for tr in rec.truth]
    data_dir.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        t=rec.t,
        pressure=pressure,
        stretch=np.zeros(0) if stretch is None else stretch,
        x=grid.x,
        y=grid.y,
        truth=json.dumps(truth),
        volts=volts,
    )
    return Run(rec.t, pressure, stretch, grid.x, grid.y, truth, volts)


def evaluate(
    runs: list[Run],
    spread: np.ndarray,
    config: ClassifierConfig | None = None,
    channels=None,
    patterns=(None, None),
):
    """(rows, unmatched END events) over touch runs; ``channels``: the pressure layer's
    ``[M, E]`` channel-electrode map, given to hand the classifier the raw frames too;
    ``patterns``: ``(disc_rel, contact_rel)`` of their START filter (``raw_patterns``)."""
    rows, extra = [], 0
    for run in runs:
        classifier = TouchClassifier(
            run.x,
            run.y,
            config,
            contact_spread_m=spread,
            channel_electrodes=channels,
            disc_rel=None if channels is None else patterns[0],
            contact_rel=None if channels is None else patterns[1],
        )
        volts = None if channels is None else run.volts
        events = classify_stream(classifier, run.t, run.pressure, run.stretch, volts)
        r, false = score(events, run.truth)
        rows += r
        extra += len(false)
    return rows, extra


def matrix_lines(title: str, cm: np.ndarray) -> list[str]:
    lines = [f"### {title}", "", "| true \\ predicted | " + " | ".join(LABELS) + " | missed |"]
    lines.append("|---" * 6 + "|")
    for i, label in enumerate(LABELS):
        lines.append(f"| {label} | " + " | ".join(str(v) for v in cm[i]) + " |")
    return [*lines, ""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", nargs="+", default=["arm", "face", "elbow"])
    parser.add_argument("--set", choices=("eval", "tuning"), default="eval")
    parser.add_argument("--seconds", type=float, default=SECONDS, help="length of each script")
    parser.add_argument("--idle-seconds", type=float, default=IDLE_SECONDS)
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/eit_skin_classifier_data"))
    parser.add_argument("--cache-dir", type=Path, default=Path("/tmp/eit_skin_classifier_cache"))
    parser.add_argument(
        "--out", type=Path, default=None, help="report (eval: bench/standing/classifier.md)"
    )
    args = parser.parse_args()
    if args.out is None and args.set == "eval":
        args.out = Path(__file__).with_name("classifier.md")
    tuning = args.set == "tuning"
    seeds = TUNING_SEEDS if tuning else EVAL_SEEDS
    bent_seeds = TUNING_BENT_SEEDS if tuning else EVAL_BENT_SEEDS
    fault_seeds = () if tuning else EVAL_FAULT_SEEDS
    idle_seed = IDLE_SEEDS[args.set]
    table = [
        "| patch | touches (per label) | balanced accuracy | missed | false events / min "
        "(idle) | false events (touch runs) | START latency median / max (ms) | within 150 ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    extras_table = [
        "| patch | condition | touches | balanced accuracy | accuracy | missed |",
        "|---|---|---|---|---|---|",
    ]
    matrices: list[str] = []
    summary = {}
    for name in args.patches:
        patch = load_patch(config_path(name))
        t0 = time.time()

        def sim(kind, seed, seconds, patch=patch):
            return simulate(patch, kind, seed, seconds, args.data_dir, args.cache_dir)

        imager = LayerImager.build(patch.layers[0], args.cache_dir)
        spread = single_contact_spread(imager)
        channels = channel_electrodes(imager.protocol)
        patterns = raw_patterns(patch.layers[0], imager)  # the node's START filter
        runs = [sim("touch", s, args.seconds) for s in seeds]
        rows, extra = evaluate(runs, spread, None, channels, patterns)
        idle = sim("idle", idle_seed, args.idle_seconds)
        idle_events = [
            e
            for e in classify_stream(
                TouchClassifier(
                    idle.x,
                    idle.y,
                    contact_spread_m=spread,
                    channel_electrodes=channels,
                    disc_rel=patterns[0],
                    contact_rel=patterns[1],
                ),
                idle.t,
                idle.pressure,
                idle.stretch,
                idle.volts,
            )
            if e.state == "end"
        ]
        per_min = len(idle_events) / (args.idle_seconds / 60.0)
        cm = confusion(rows)
        balanced = balanced_accuracy(cm)
        lat = np.array([r[2] for r in rows if r[2] is not None]) * 1e3
        within = float(np.mean(lat <= LATENCY_TARGET_S * 1e3)) if lat.size else float("nan")
        missed = int(cm[:, 4].sum())
        per_label = "/".join(str(int(v)) for v in cm.sum(axis=1))
        print(
            f"{name:6s} touches {len(rows):3d} ({per_label}) balanced {balanced:6.1%} missed "
            f"{missed} idle false/min {per_min:.2f} extra {extra} latency median "
            f"{np.median(lat):.0f} max {lat.max():.0f} ms ({time.time() - t0:.0f} s)",
            flush=True,
        )
        table.append(
            f"| {name} | {len(rows)} ({per_label}) | {balanced:.1%} | {missed} | {per_min:.2f} | "
            f"{extra} | {np.median(lat):.0f} / {lat.max():.0f} | {within:.0%} |"
        )
        lines = matrix_lines(name, cm)
        print("\n".join(lines), flush=True)
        matrices += lines
        summary[name] = {"balanced": balanced, "per_min": per_min, "lat_max": float(lat.max())}
        conditions = []
        if name == "elbow":
            title = f"bent {BENT_ANGLE_RAD:g} rad, posture reference"
            conditions.append((title, "bent", bent_seeds))
        if fault_seeds:
            conditions.append((f"{FAULT}, fault-tolerant imaging", "fault", fault_seeds))
        for title, kind, kind_seeds in conditions:
            runs = [sim(kind, s, args.seconds) for s in kind_seeds]
            rows_c, _ = evaluate(runs, spread, None, channels, patterns)
            cm_c = confusion(rows_c)
            acc = float(np.trace(cm_c[:, :4]) / max(cm_c.sum(), 1))
            line = (
                f"| {name} | {title} (seeds {list(kind_seeds)}) | {len(rows_c)} | "
                f"{balanced_accuracy(cm_c):.1%} | {acc:.1%} | {int(cm_c[:, 4].sum())} |"
            )
            print(line, flush=True)
            print("\n".join(matrix_lines(f"{name}, {title}", cm_c)), flush=True)
            extras_table.append(line)
            matrices += matrix_lines(f"{name}, {title}", cm_c)
    if args.out is None:
        return
    cfg = ClassifierConfig()
    report = [
        "# Touch classifier: accuracy in simulation",
        "",
        "**Measured in simulation only.** Published EIT-skin and social-touch classifiers reach",
        "60-80 % on real people; these numbers say nothing about real skins, real fingers or",
        "real drift. They only show that the features separate the four labels as the simulator",
        "models them.",
        "",
        f"{run_header()} Data: simulator",
        f"`random` scripts ({args.seconds:g} s each, 50 Hz frames, random positions, speeds,",
        "forces, contact radii, ADC noise and quantisation, random sigma0 drift), every layer",
        "reconstructed with the patch's imager as configured (solver prior per layer: "
        + ", ".join(
            f"{n}: {'/'.join(ly.solver.prior for ly in load_patch(config_path(n)).layers)}"
            for n in args.patches
        )
        + ").",
        "",
        "* **Tuning seeds** (looked at while choosing features and thresholds): "
        f"{list(TUNING_SEEDS)},",
        f"  elbow bent {list(TUNING_BENT_SEEDS)}, idle {IDLE_SEEDS['tuning']}.",
        f"* **Evaluation seeds** (this report; never used for tuning): {list(EVAL_SEEDS)}, elbow",
        f"  bent {list(EVAL_BENT_SEEDS)}, dead electrode {list(EVAL_FAULT_SEEDS)}, idle "
        f"{IDLE_SEEDS['eval']} ({args.idle_seconds:g} s of no-touch data per patch).",
        f"* **Retired seeds** {list(RETIRED_SEEDS)}: the previous evaluation set; it was looked",
        "  at while analysing the START latency of weak touches, so it no longer counts as unseen.",
        "",
        *table,
        "",
        "Targets: balanced accuracy >= 90 % per patch, <= 0.5 false events per minute of",
        "no-touch data, first START within 150 ms of onset. 'false events (touch runs)' counts",
        "END events in the touch scripts that match no true touch (split or spurious touches).",
        "",
        "Notes:",
        "",
        "* 100 % here means the four simulated touch kinds are geometrically distinct (a",
        "  simulated grab always spreads 3-5 fingers over 30-90 mm, a simulated pinch always",
        "  closes by 50-70 %); real touches are not that tidy. Expect far less on people.",
        "* START comes from the pooled (matched-filter) detector: the image averaged over a",
        f"  Gaussian kernel of {cfg.detect_kernel:g} single-finger spreads, above "
        f"{cfg.k_detect:g} sigmas of ITS noise for {cfg.start_frames}",
        "  frames. On the knit patches (face, elbow: ~90-200 Pa image noise) a weak 1-2 N finger",
        "  with a 0.3 s force ramp reaches it 50-100 ms before a single pixel crosses the 6-sigma",
        "  segmentation threshold (which alone gave up to ~200 ms on the tuning seeds).",
        "  Latency is counted from the first frame of force (onset of the simulated ramp).",
        "",
        "Extra conditions (not part of the targets above):",
        "",
        *extras_table,
        "",
        "## Confusion matrices (rows: true label)",
        "",
        *matrices,
    ]
    args.out.write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
