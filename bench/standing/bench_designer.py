"""How long one designer action takes: an electrode moved -> validated patch, mesh, accuracy map.

For each shipped 16-electrode patch (arm, face, elbow: their first layer) and the reconstruction
benchmark's disc, ``ACTIONS`` actions each move one electrode (a different one, by a different
distance, so nothing is reused from the action before) and are timed end to end through the
designer's own HTTP server (``POST /api/update``, what the page sends: validation, mesh,
preview prediction, JSON), pinned to one core with ``OPENBLAS_NUM_THREADS=1``. Reported:
median and largest wall time per action, the server's CPU time, and its split (mesh, build,
simulate, image) as the page shows it. Writes ``bench/standing/designer.md``.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_designer [--actions N]``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from bench.header import run_header
from eit_skin.design.server import start_server
from eit_skin.design.session import DesignSession
from eit_skin.resources import config_path

OUT = Path(__file__).resolve().parent / "designer.md"
ACTIONS = 12
DISC = """name: bench_disc
frame_id: bench_disc_link
layers:
  - name: pressure
    outline: {type: circle, radius: 0.05}
    electrodes: {count: 16, layout: even, width: 0.005, contact_impedance: 1.0e-4}
    current: 1.0e-3
    material: {quantity: pressure, sheet_conductance: 1.0, pressure_scale: 1.0e4}
    mesh: {max_edge: 0.0026, electrode_edge: 0.0026}
    solver: {method: greit, noise_figure: 0.13, image_pixels: 64}
"""


def post(url: str, body: dict) -> dict:
    request = urllib.request.Request(
        url, json.dumps(body).encode(), {"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(request, timeout=600) as response:
        return json.loads(response.read())


def moved(data: dict, fractions: list[float], k: int, shift: float) -> dict:
    """``data`` with electrode ``k`` moved by ``shift`` of the perimeter (as the page does)."""
    out = copy.deepcopy(data)
    electrodes = out["layers"][0]["electrodes"]
    for key in ("layout", "count", "start_angle_deg", "start_fraction"):
        electrodes.pop(key, None)
    values = list(fractions)
    values[k] = (values[k] + shift) % 1.0
    electrodes["positions"] = sorted(round(v, 6) for v in values)
    return out


def bench_patch(path: Path, actions: int) -> dict:
    session = DesignSession.open(path)
    server = start_server(session)
    try:
        state = json.loads(urllib.request.urlopen(server.url + "api/design", timeout=600).read())
        first = state["model"]
        fractions = [e["fraction"] for e in first["electrodes"]]
        gaps = np.diff(np.append(fractions, fractions[0] + 1.0))
        rows = []
        for i in range(actions):
            k = (3 * i + 1) % len(fractions)
            shift = (0.15 + 0.25 * (i % 3) / 3) * gaps[k]  # stays short of the next electrode
            data = moved(state["data"], fractions, k, shift)
            wall, cpu = time.perf_counter(), time.process_time()
            answer = post(server.url + "api/update", {"data": data, "layer_index": 0})
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            if not answer["ok"]:
                raise RuntimeError(f"{path.name}: {answer['error']}")
            rows.append((wall, cpu, answer["timings_s"]))
        walls = np.array([r[0] for r in rows])
        split = {
            key: float(np.median([r[2][key] for r in rows]))
            for key in ("mesh", "build", "simulate", "image")
        }
        return {
            "patch": session.data["name"],
            "triangles": first["mesh"]["n_triangles"],
            "targets": first["prediction"]["targets"],
            "median_s": float(np.median(walls)),
            "max_s": float(walls.max()),
            "cpu_s": float(np.median([r[1] for r in rows])),
            **split,
        }
    finally:
        server.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--actions", type=int, default=ACTIONS)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    folder = Path(tempfile.mkdtemp(prefix="bench_designer_"))
    try:
        paths = []
        for name in ("arm", "face", "elbow"):
            paths.append(folder / f"{name}.yaml")
            shutil.copy(config_path(name), paths[-1])
        paths.append(folder / "bench_disc.yaml")
        paths[-1].write_text(DISC)
        rows = [bench_patch(p, args.actions) for p in paths]
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    lines = [
        "# Designer: time of one action",
        "",
        f"{run_header()} Pinned to one core.",
        "",
        f"An action moves one electrode of the first layer along the outline ({args.actions} "
        "actions per patch, each a different electrode and distance) and is timed end to end "
        "through the designer's HTTP server (`POST /api/update`: validation, mesh, "
        "predicted-accuracy preview, JSON answer), as the page sends it. The split is the "
        "server's own (median), as the page shows it: mesh (the layer's mesh for the drawing), "
        "build (the reconstruction chain), simulate (the disc targets on the finer data mesh), "
        "image (imaging them, figures of merit, maps). Target: <= 1 s per action for a "
        "16-electrode patch on one core.",
        "",
        "| patch | triangles | targets | median s | max s | CPU s | mesh s | build s "
        "| simulate s | image s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['patch']} | {r['triangles']} | {r['targets']} | {r['median_s']:.2f} | "
            f"{r['max_s']:.2f} | {r['cpu_s']:.2f} | {r['mesh']:.3f} | {r['build']:.3f} | "
            f"{r['simulate']:.3f} | {r['image']:.3f} |"
        )
    OUT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
