"""Soak: the whole simulated robot (arm, face, elbow) at full rate; RSS and CPU per node.

Starts the node graph of ``robot_skin.launch.py`` (:func:`eit_skin.ros.node_graph.robot_nodes`,
simulators looping their touch script at 50 Hz) with :mod:`eit_skin.ros.bringup`, samples every
node process's resident memory and CPU time from /proc every ``--period`` seconds, stops the
nodes after ``--minutes`` by itself (SIGINT, then SIGKILL after 10 s) and writes a table and
the memory growth per minute (least-squares slope after ``--warmup`` seconds) to bench/soak.md.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.stress.bench_soak [--minutes 10]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="eit_bench_log_"))

from bench.header import run_header
from eit_skin.ros.bringup import start, stop
from eit_skin.ros.node_graph import robot_nodes

TICK_S = os.sysconf("SC_CLK_TCK")


def sample(pid: int) -> tuple[float, float] | None:
    """(RSS MiB, CPU seconds user+system) of a live process from /proc, or None."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    rss_kb = next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS"))
    fields = stat[stat.rindex(")") + 2 :].split()
    cpu = (int(fields[11]) + int(fields[12])) / TICK_S  # utime, stime
    return rss_kb / 1024.0, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="soak duration")
    parser.add_argument("--period", type=float, default=10.0, help="sampling period, s")
    parser.add_argument("--warmup", type=float, default=60.0, help="left out of the slope, s")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("soak.md"))
    args = parser.parse_args()
    log_dir = Path(tempfile.mkdtemp(prefix="eit_soak_"))
    nodes = [start(spec, log_dir) for spec in robot_nodes(sim=True, rate_hz=50.0, loop=True)]
    labels = [node.label for node in nodes]
    times: list[float] = []
    rows: list[list[tuple[float, float] | None]] = []
    t0 = time.monotonic()
    end = t0 + 60.0 * args.minutes
    try:
        while True:
            now = time.monotonic()
            times.append(now - t0)
            rows.append([sample(node.process.pid) for node in nodes])
            print(
                f"t={now - t0:6.0f} s  RSS "
                + " ".join("-" if s is None else f"{s[0]:.0f}" for s in rows[-1]),
                flush=True,
            )
            if now >= end:
                break
            time.sleep(max(0.0, min(args.period, end - time.monotonic())))
    finally:
        codes = stop(nodes)
    write_report(args, labels, np.array(times), rows, codes)


def write_report(args, labels, times, rows, codes) -> None:
    rss = np.array([[np.nan if s is None else s[0] for s in row] for row in rows])
    cpu = np.array([[np.nan if s is None else s[1] for s in row] for row in rows])
    late = times >= min(args.warmup, times[-1] / 2)
    lines = [
        "# Soak: the whole simulated robot at full rate",
        "",
        run_header(),
        "",
        "Nodes: driver (simulator, looping its touch script at 50 Hz), reconstruction and "
        "classifier of arm, face and elbow (`robot_nodes`, started by `ros/bringup.py`). "
        f"RSS (VmRSS) and CPU (utime+stime) from /proc every {args.period:g} s. Growth: "
        f"least-squares slope of RSS over the samples after {times[late][0]:.0f} s "
        "(start-up and matrix loading left out).",
        "",
        "| node | RSS start MiB | RSS end MiB | RSS max MiB | growth MiB/min | CPU % (mean) |"
        " exit |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for j, label in enumerate(labels):
        ok = late & np.isfinite(rss[:, j])
        slope = np.polyfit(times[ok] / 60.0, rss[ok, j], 1)[0] if ok.sum() >= 2 else np.nan
        finite = np.isfinite(cpu[:, j])
        span = times[finite][-1] - times[finite][0] if finite.sum() >= 2 else np.nan
        used = cpu[finite, j][-1] - cpu[finite, j][0] if finite.sum() >= 2 else np.nan
        lines.append(
            f"| {label} | {rss[0, j]:.1f} | {rss[-1, j]:.1f} | {np.nanmax(rss[:, j]):.1f} | "
            f"{slope:+.2f} | {100 * used / span:.1f} | {codes.get(label)} |"
        )
    lines += [
        "",
        "RSS per sample, MiB:",
        "",
        "| t s | " + " | ".join(labels) + " |",
        "|---:|" + "---:|" * len(labels),
    ]
    for t, row in zip(times, rss, strict=True):
        lines.append(f"| {t:.0f} | " + " | ".join(f"{v:.0f}" for v in row) + " |")
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
