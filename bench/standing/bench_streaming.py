"""Offline streaming: peak RSS and throughput of ``eit-skin reconstruct`` against file length.

A frames file of T frames (a short simulated elbow push, repeated; written block by block so
this script stays small too) is reconstructed by ``eit-skin reconstruct`` in a child process;
its peak resident memory comes from ``os.wait4`` (ru_maxrss of that child alone), its
throughput from the wall time. Writes bench/streaming.md.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_streaming [--frames 1e4 1e5 3e5]
        [--work-dir build/bench_streaming]

At 1e6 frames the input takes ~1.7 GB and the output ~18 GB of disk in the work folder
(default: a new temporary folder); both are deleted after each run.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.header import run_header
from eit_skin.io.npz import NpzStreamWriter
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator


def make_file(path: Path, n_frames: int, source: dict, block: int = 4096) -> None:
    """``n_frames`` frames: the source's frames repeated, times at 50 Hz."""
    frames = source["frames"]
    m = frames.shape[1]
    arrays = {
        "reference": ((m,), np.float64),
        "frames": ((n_frames, m), np.float64),
        "t": ((n_frames,), np.float64),
    }
    with NpzStreamWriter(path, arrays) as writer:
        writer.append(reference=source["reference"])
        for start in range(0, n_frames, block):
            k = np.arange(start, min(start + block, n_frames))
            writer.append(frames=frames[k % len(frames)], t=k / 50.0)


def run_child(command: list[str]) -> tuple[float, float]:
    """(peak RSS MiB, wall s) of one child process."""
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{command} failed")
    return usage.ru_maxrss / 1024.0, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=float, nargs="+", default=[1e4, 1e5, 3e5])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("streaming.md"))
    parser.add_argument(
        "--work-dir", type=Path, default=None, help="folder for the files (default: a temp one)"
    )
    args = parser.parse_args()
    if args.work_dir is not None:
        args.work_dir.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="eit_bench_stream_", dir=args.work_dir))
    patch = load_patch(config_path("elbow"))
    SkinSimulator(patch, "push", rate_hz=50.0, seed=11).run().save(work)
    with np.load(work / "pressure.npz") as d:
        source = {"reference": d["reference"], "frames": d["frames"]}
    eit = [sys.executable, "-m", "eit_skin.cli.main"]
    rows = []
    for n in (int(x) for x in args.frames):
        src, out = work / "in.npz", work / "out.npz"
        make_file(src, n, source)
        command = [*eit, "reconstruct", "--patch", "elbow", "--frames", str(src), "--out", str(out)]
        rss, wall = run_child(command)
        rows.append((n, src.stat().st_size / 1e6, out.stat().st_size / 1e6, rss, wall))
        print(f"{n} frames: peak RSS {rss:.0f} MiB, {n / wall:.0f} frames/s", flush=True)
        src.unlink()
        out.unlink()
    lines = [
        "# Offline streaming: `eit-skin reconstruct` memory against file length",
        "",
        run_header(),
        "",
        "Elbow pressure layer (M = 208), default block of 4096 frames, method and cache of the "
        "patch (matrix cached before the first run). Peak RSS: ru_maxrss of the reconstruct "
        "child alone (os.wait4). Throughput: frames / wall time of the whole command "
        "(start-up, imaging, packing the npz).",
        "",
        "| frames | input MB | output MB | peak RSS MiB | wall s | frames/s |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for n, size_in, size_out, rss, wall in rows:
        lines.append(
            f"| {n:.0e} | {size_in:.0f} | {size_out:.0f} | {rss:.0f} | {wall:.1f} "
            f"| {n / wall:.0f} |"
        )
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
