"""Touch classifier accuracy, false events and START latency on simulated, unseen sequences.

For every shipped patch: ``random`` touch scripts of the simulator with seeds never used while
tuning (tuning used seeds 0-3), every layer reconstructed with the patch's imager, classified
by :class:`~eit_skin.touch_classifier.TouchClassifier`; plus a no-touch recording (drift and
noise only) for the false-event rate. Prints the tables and writes ``bench/classifier.md``.

MEASURED IN SIMULATION ONLY: published EIT-skin and social-touch classifiers reach 60-80 % on
real people.

    .venv/bin/python bench/bench_classifier.py [--seconds 60] [--idle-seconds 60] [--seeds 101 102]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from eit_skin.imaging import LayerImager
from eit_skin.patch import load_patch
from eit_skin.resources import config_path
from eit_skin.simulator import SkinSimulator
from eit_skin.touch_classifier import LABELS, classify_stream

RATE_HZ = 50.0
LATENCY_TARGET_S = 0.150


def images(patch, recording, cache_dir):
    out = {}
    for layer in patch.layers:
        imager = LayerImager.build(layer, cache_dir=cache_dir)
        rec = recording.layers[layer.name]
        rel = imager.relative_change(rec.frames, rec.reference, rec.flags[0])
        out[layer.name] = (imager.physical(imager.images(rel)), imager.grid)
    return out


def classify(patch, recording, cache_dir):
    imgs = images(patch, recording, cache_dir)
    pressure, grid = imgs[patch.layers[0].name]
    stretch = imgs["stretch"][0] if "stretch" in imgs else None
    return classify_stream(recording.t, pressure, grid.x, grid.y, stretch)


def score(events, truth):
    """(true, predicted or None, start latency or None) per truth touch; unmatched END events."""
    ends = [e for e in events if e.state == "end"]
    starts = {e.touch_id: e for e in events if e.state == "start"}
    used, rows = set(), []
    for tr in truth:
        best, overlap = None, 0.0
        for e in ends:
            o = min(e.t_end_s, tr.t_end_s) - max(e.t_start_s, tr.t_start_s)
            if o > overlap and e.touch_id not in used:
                best, overlap = e, o
        if best is None:
            rows.append((tr.label, None, None))
            continue
        used.add(best.touch_id)
        rows.append((tr.label, best.label, starts[best.touch_id].t_s - tr.t_start_s))
    return rows, [e for e in ends if e.touch_id not in used]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", nargs="+", default=["arm", "face", "elbow"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[101, 102])
    parser.add_argument("--seconds", type=float, default=40.0, help="length of each random script")
    parser.add_argument("--idle-seconds", type=float, default=60.0)
    parser.add_argument("--cache-dir", default="build/cache")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("classifier.md"))
    args = parser.parse_args()
    report = [
        "# Touch classifier: accuracy in simulation",
        "",
        "**Measured in simulation only** (`bench/bench_classifier.py`): simulator `random` scripts",
        f"with seeds {args.seeds} (tuning used seeds 0-3), {args.seconds:g} s each, 50 Hz frames,",
        "noise, ADC quantisation and random sigma0 drift; reconstruction with each patch's",
        "one-step imager. Published EIT-skin and social-touch classifiers reach 60-80 % on",
        "real people; these numbers say nothing about real skins.",
        "",
        "| patch | touches | balanced accuracy | missed | false events / min (idle) | "
        "false events (touch runs) | START latency median / max (ms) | within 150 ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    matrices = []
    for name in args.patches:
        patch = load_patch(config_path(name))
        rows, extra, t0 = [], 0, time.time()
        for seed in args.seeds:
            rec = SkinSimulator(patch, "random", RATE_HZ, seed=seed, duration_s=args.seconds).run(
                duration_s=args.seconds
            )
            r, false = score(classify(patch, rec, args.cache_dir), rec.truth)
            rows += r
            extra += len(false)
        idle = SkinSimulator(patch, "idle", RATE_HZ, seed=args.seeds[0]).run(
            duration_s=args.idle_seconds
        )
        idle_events = [e for e in classify(patch, idle, args.cache_dir) if e.state == "end"]
        per_min = len(idle_events) / (args.idle_seconds / 60.0)
        cm = np.zeros((4, 5), dtype=int)  # last column: missed
        for true, pred, _ in rows:
            cm[LABELS.index(true), 4 if pred is None else LABELS.index(pred)] += 1
        recalls = [cm[i, i] / cm[i].sum() for i in range(4) if cm[i].sum()]
        balanced = float(np.mean(recalls)) if recalls else float("nan")
        lat = np.array([lt for _, _, lt in rows if lt is not None]) * 1e3
        within = float(np.mean(lat <= LATENCY_TARGET_S * 1e3)) if lat.size else float("nan")
        missed = int(cm[:, 4].sum())
        print(
            f"{name:6s} touches {len(rows):3d} balanced {balanced:6.1%} missed {missed} "
            f"idle false/min {per_min:.2f} extra {extra} latency median {np.median(lat):.0f} "
            f"max {lat.max():.0f} ms ({time.time() - t0:.0f} s)"
        )
        report.append(
            f"| {name} | {len(rows)} | {balanced:.1%} | {missed} | {per_min:.2f} | {extra} | "
            f"{np.median(lat):.0f} / {lat.max():.0f} | {within:.0%} |"
        )
        lines = [f"### {name}", "", "| true \\ predicted | " + " | ".join(LABELS) + " | missed |"]
        lines.append("|---" * 6 + "|")
        for i, label in enumerate(LABELS):
            lines.append(f"| {label} | " + " | ".join(str(v) for v in cm[i]) + " |")
        print("\n".join(lines))
        matrices += [*lines, ""]
    report += [
        "",
        "Targets: balanced accuracy >= 90 % per patch, <= 0.5 false events per minute of",
        "no-touch data, first START within 150 ms of onset. 'false events (touch runs)' counts",
        "END events in the touch scripts that match no true touch (split or spurious touches).",
        "",
        "## Confusion matrices (rows: true label)",
        "",
        *matrices,
    ]
    args.out.write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
