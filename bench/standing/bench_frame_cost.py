"""Where a reconstruction node's CPU per frame goes, at many patches per process.

The same three-process set-up as ``bench_skin.py``'s throughput runs (K face patches at
100 Hz in one worker process pinned to CPU 0, a feeder and a sink on CPU 1), run once per
stage of the node's per-frame work (``bench_skin.staged_node``): the frame only received,
then also an image published, then the node as shipped. The
differences between the stages are what each part costs in that process (caches shared by
K patches, DDS threads included).

Writes bench/frame_cost.md. Run:
``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_frame_cost`` (about 4 minutes).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from bench.header import run_header
from bench.standing import bench_skin

#: What each stage adds to the one before (report rows).
ADDS = {
    "receive": "take the frame from DDS as CDR bytes, read and check it (`_on_frame`)",
    "publish": "publish a 32FC1 image (the face grid, 64 x 45) as its CDR bytes",
    "full": "the per-frame step (compiled kernel: relative change, contact test, drift, "
    "physical image; the fault window, and a fault check each second) and the node's "
    "bookkeeping",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", type=int, default=50)
    parser.add_argument("--runs", type=int, default=2, help="runs of every stage")
    parser.add_argument("--seconds", type=float, default=20.0, help="window of each run")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("frame_cost.md"))
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp(prefix="eit_bench_frame_cost_"))
    cache = workdir / "cache"
    bench_skin.build_cache(cache, ["face"])
    frames = bench_skin.simulated_frames("face", 500)["pressure"]
    k = args.patches
    runs: dict[str, list[dict[str, float]]] = {stage: [] for stage in bench_skin.STAGES}
    for _ in range(args.runs):  # stages interleaved: a slow stretch of the machine hits all
        for stage in bench_skin.STAGES:
            r = bench_skin.throughput(k, args.seconds, workdir, cache, frames, stage)
            runs[stage].append(r)
            print(f"{stage}: {r['cpu_ms']:.3f} ms CPU per frame", flush=True)
    median = {stage: float(np.median([r["cpu_ms"] for r in rs])) for stage, rs in runs.items()}
    rows = []
    before = 0.0
    for stage, rs in runs.items():
        cpu = " / ".join(f"{r['cpu_ms']:.3f}" for r in rs)
        adds = median[stage] - before
        rows.append(f"| {stage} | {ADDS[stage]} | {cpu} ms | **{adds:+.3f} ms** |")
        before = median[stage]
    io = median["publish"]
    lines = [
        "# Where a frame's CPU goes: one process, many patches",
        "",
        f"{run_header()}",
        "",
        f"{k} face patches at 100 Hz in one worker process on one core, fed and drained by "
        "two other processes on the other core, as in `bench/standing/skin.md`. Each stage is the "
        "node cut after that part of its per-frame work (`bench_skin.staged_node`); the "
        "worker's CPU per frame (all its threads) over a window of "
        f"{args.seconds:.0f} s, {args.runs} runs per stage, interleaved. Latencies are in "
        "`bench/standing/skin.md`: a cut node's are not a node's.",
        "",
        "| stage | adds | worker CPU per frame, each run | adds (median) |",
        "|---|---|---|---|",
        *rows,
        "",
        f"Receiving a frame and publishing an image cost **{io:.3f} ms** per frame before any "
        f"imaging: {100 * io / median['full']:.0f} % of the shipped node's "
        f"{median['full']:.3f} ms. Issue 16 asks for a p99 under 5 ms at 50 patches; the "
        "machine runs the same code up to 1.5-1.85x slower for up to a few hundred "
        "milliseconds (`bench/standing/skin.md`), and a worker only stays ahead of its frames "
        "through "
        "such a stretch while 50 x 100 x (CPU per frame) x slowdown stays under 1000 ms: "
        "0.108-0.133 ms per frame. What that leaves for the imaging itself is "
        f"{0.108 - io:.3f}-{0.133 - io:.3f} ms against the "
        f"{median['full'] - io:.3f} ms it takes (the compiled step and the Python around it).",
        "",
    ]
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
