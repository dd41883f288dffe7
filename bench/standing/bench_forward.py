"""Forward-model speed and conditioning: prints a table (markdown), optionally writes it.

Usage: ``.venv/bin/python -m bench.standing.bench_forward [--out report.md]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol

REPO = Path(__file__).resolve().parents[2]


def best_of(fn, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def speed_rows() -> list[str]:
    layer = load_patch(REPO / "config" / "arm.yaml").layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    sigma0 = layer.material.sheet_conductance_s
    rows = []
    cases = [(f"arm/{layer.name} h={h * 1e3:.1f} mm", build_mesh(layer, h)) for h in (5e-3, 1.4e-3)]
    cases.append(("disk R=50 mm h=R/64", disk_mesh(0.05, 16, 0.2, 0.05 / 64)))
    for name, mesh in cases:
        t = time.perf_counter()
        model = ForwardModel(mesh, protocol, layer.contact_impedance_ohm_m, layer.current_a)
        t_init = time.perf_counter() - t
        rng = np.random.default_rng(0)

        def fresh_solve(model=model, rng=rng):
            model.solve(sigma0 * rng.uniform(0.9, 1.1, model.n_elements))

        sigma = sigma0 * np.ones(model.n_elements)
        model.solve(sigma)
        t_solve = best_of(fresh_solve)
        t_jac = best_of(lambda model=model, sigma=sigma: model.jacobian(sigma))
        cond = model.condition_estimate(sigma)
        rows.append(
            f"| {name} | {mesh.n_triangles} | {mesh.n_nodes} | {t_init * 1e3:.1f} | "
            f"{t_solve * 1e3:.1f} | {t_jac * 1e3:.1f} | {cond:.2e} |"
        )
    return rows


def conditioning_rows() -> list[str]:
    mesh = disk_mesh(0.05, 16, 0.2, 0.05 / 12)
    layer = load_patch(REPO / "config" / "arm.yaml").layers[0]
    protocol = build_protocol(layer.protocol, 16)
    inside = np.linalg.norm(mesh.centroids - [0.015, 0.0], axis=1) < 0.015
    rows = []
    for z in (1e-6, 1e-3, 1.0):
        model = ForwardModel(mesh, protocol, z, 1e-3)
        for contrast in (1e-4, 1.0, 1e4):
            sigma = np.where(inside, contrast, 1.0)
            K = model.system_matrix(sigma).toarray()
            d = 1 / np.sqrt(np.diag(K))
            cond_k, cond_sks = np.linalg.cond(K), np.linalg.cond(d[:, None] * K * d)
            est = model.condition_estimate(sigma)
            rows.append(f"| {z:g} | {contrast:g} | {cond_k:.2e} | {cond_sks:.2e} | {est:.2e} |")
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, help="also write the tables to this file")
    args = parser.parse_args()
    lines = [
        "Forward model speed (16 electrodes, adjacent protocol, 208 measurements; best of 5)",
        "",
        "| mesh | triangles | nodes | init ms | solve ms (new sigma) | jacobian ms | cond1 est |",
        "|---|---|---|---|---|---|---|",
        *speed_rows(),
        "",
        "Conditioning (disk R=50 mm, h=R/12, sigma=1 S, inclusion r=15 mm, 2-norm, dense)",
        "",
        "| z (ohm m) | contrast | cond(K) | cond(SKS) | cond1 est (SKS) |",
        "|---|---|---|---|---|",
        *conditioning_rows(),
    ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
