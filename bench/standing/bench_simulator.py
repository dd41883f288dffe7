"""Simulator speed: precompute a 20 s scenario at 50 Hz per patch; prints a table and writes
bench/simulator_report.md. Run with OPENBLAS_NUM_THREADS=1 on a shared machine."""

from __future__ import annotations

import time
from pathlib import Path

from bench.header import run_header
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator

CASES = [("arm", "demo"), ("arm", "random"), ("face", "demo"), ("elbow", "elbow_bend")]
DURATION_S = 20.0
RATE_HZ = 50.0


def main() -> None:
    rows = []
    for patch_name, scenario in CASES:
        patch = load_patch(config_path(patch_name))
        t0 = time.perf_counter()
        sim = SkinSimulator(patch, scenario, rate_hz=RATE_HZ, seed=0, duration_s=DURATION_S)
        t1 = time.perf_counter()
        sim.frame(0)
        t2 = time.perf_counter()
        rec = sim.run(duration_s=DURATION_S)
        t3 = time.perf_counter()
        counts = sim.solve_counts()
        solves = " ".join(
            f"{n}:{c['direct']}d/{c['update']}u/{c['cached']}c" for n, c in counts.items()
        )
        rows.append(
            (
                patch_name,
                scenario,
                len(rec.t),
                t1 - t0,
                t2 - t1,
                t3 - t1,
                1e3 * (t3 - t1) / len(rec.t),
                solves,
            )
        )
        print(
            f"{patch_name:6s} {scenario:11s} {len(rec.t):5d} frames  setup {t1 - t0:5.2f} s  "
            f"first frame {1e3 * (t2 - t1):6.1f} ms  all {t3 - t1:6.2f} s  "
            f"({1e3 * (t3 - t1) / len(rec.t):5.2f} ms/frame)  {solves}"
        )
    lines = [
        "# Simulator benchmark",
        "",
        f"{run_header()} 20 s at {RATE_HZ:g} Hz per patch (all layers), seed 0, default "
        "settings (sim mesh 0.6 x max_edge). Solves per layer: d = direct sparse solve, "
        "u = low-rank (Woodbury) update, c = identical field reused.",
        "",
        "| patch | scenario | frames | setup s | first frame ms | all s | ms/frame | solves |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for p, s, n, setup, first, total, per, solves in rows:
        cells = (p, s, n, f"{setup:.2f}", f"{1e3 * first:.1f}", f"{total:.2f}", f"{per:.2f}")
        lines.append("| " + " | ".join(str(c) for c in cells) + f" | {solves} |")
    out = Path(__file__).with_name("simulator.md")
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
