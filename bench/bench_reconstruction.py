"""Reconstruction speed against error: eit_skin vs pyEIT JAC on the same disk meshes.

Run: ``.venv/bin/python bench/bench_reconstruction.py [--quick]``; writes
``bench/REPORT.md`` and ``bench/reconstruction.png``. Data for the error columns are
simulated on a finer mesh (h = 2 mm, ~30k triangles) than any reconstruction mesh; noise
is 1 % of the RMS difference signal; position error is the max over targets at
0..0.9 R, three angles each (GREIT centre-of-gravity distance, fraction of R).
pyEIT gets the same nodes and triangles (its point electrodes at each electrode's first
node); only its build and per-frame times are measured.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from eit_skin.figures_of_merit import figures_of_merit
from eit_skin.forward import ForwardModel
from eit_skin.gauss_newton import gauss_newton_difference
from eit_skin.image_grid import ImageGrid
from eit_skin.priors import make_prior
from eit_skin.protocol import ProtocolSpec, build_protocol
from eit_skin.reconstruction import ReconstructionMatrix
from test.forward_meshes import disk_mesh

R = 0.05
OUT = Path(__file__).resolve().parent


def best_of(fn, n=3):
    times = []
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def pyeit_times(mesh):
    try:
        from pyeit.eit import jac, protocol
        from pyeit.mesh import PyEITMesh
    except ImportError:
        return float("nan"), float("nan")
    el_pos = np.array([e[0, 0] for e in mesh.electrode_edges])
    pm = PyEITMesh(node=mesh.nodes, element=mesh.triangles, perm=1.0, el_pos=el_pos, ref_node=0)
    prot = protocol.create(16, dist_exc=1, step_meas=1, parser_meas="std")
    solver = jac.JAC(pm, prot)
    t = time.perf_counter()
    solver.setup(p=0.5, lamb=0.01, method="kotre")
    build = time.perf_counter() - t
    v0 = np.ones(solver.H.shape[1])
    v1 = v0 * 1.01
    frame, _ = best_of(lambda: solver.solve(v1, v0, normalize=True), 20)
    return build, frame


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="small meshes, pyEIT up to 3k only")
    args = ap.parse_args()
    protocol = build_protocol(ProtocolSpec(), 16)
    fine = ForwardModel(disk_mesh(R, h_m=0.002), protocol, 1e-4)
    v0 = fine.voltages(1.0)
    rng = np.random.default_rng(0)
    phantoms = []
    for rf in np.linspace(0, 0.9, 10):
        for a in (0.2, 1.3, 2.9):
            c = np.array([rf * R * np.cos(a), rf * R * np.sin(a)])
            sig = np.ones(fine.mesh.n_triangles)
            sig[np.linalg.norm(fine.mesh.centroids - c, axis=1) < 0.05 * R] = 2.0
            v = fine.voltages(sig)
            v = v + rng.normal(0, 0.01 * np.sqrt(np.mean((v - v0) ** 2)), v.size)
            phantoms.append((c, v))
    sizes = [0.008, 0.006, 0.0045] if args.quick else [0.008, 0.006, 0.0045, 0.003, 0.0022]
    rows = []
    for h in sizes:
        mesh = disk_mesh(R, h_m=h)
        fwd = ForwardModel(mesh, protocol, 1e-4)
        build, rm = best_of(
            lambda fwd=fwd: ReconstructionMatrix.build(fwd, prior="laplace", noise_figure=0.3), 1
        )
        frames = np.stack([v for _, v in phantoms])
        frame_t, _ = best_of(lambda rm=rm, frames=frames: rm.reconstruct(frames[0], v0), 20)
        batch_t, xs = best_of(lambda rm=rm, frames=frames: rm.reconstruct(frames, v0), 5)
        grid = ImageGrid.build(mesh, 64)
        imgs = grid.to_image(xs)
        pe = max(
            figures_of_merit(im, grid.x, grid.y, c, sign=1).position_error_m / R
            for im, (c, _) in zip(imgs, phantoms, strict=True)
        )
        res = np.mean(
            [
                figures_of_merit(im, grid.x, grid.y, c, sign=1).resolution
                for im, (c, _) in zip(imgs, phantoms, strict=True)
            ]
        )
        prior = make_prior("laplace", mesh)
        big = phantoms[12][1]
        t = time.perf_counter()
        gn = gauss_newton_difference(
            fwd, big, v0, prior=prior, hyperparameter=0.03, max_iterations=5, tolerance=0.0
        )
        gn_t = (time.perf_counter() - t) / max(gn.iterations, 1)
        py_build, py_frame = (
            pyeit_times(mesh)
            if (not args.quick or mesh.n_triangles < 3500)
            else (float("nan"), float("nan"))
        )
        row = (
            mesh.n_triangles,
            build,
            frame_t * 1e3,
            batch_t / len(frames) * 1e3,
            gn_t * 1e3,
            gn.iterations,
            pe,
            res,
            py_build,
            py_frame * 1e3,
        )
        rows.append(row)
        print("  ".join(f"{x:.4g}" for x in row), flush=True)
    write_report(rows, args.quick)


def write_report(rows, quick):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.array(rows, dtype=float)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].loglog(a[:, 0], a[:, 1], "o-", label="eit_skin build")
    ax[0].loglog(a[:, 0], a[:, 8], "s-", label="pyEIT JAC build")
    ax[0].loglog(a[:, 0], a[:, 4] / 1e3, "^-", label="eit_skin GN iteration")
    ax[0].set_xlabel("triangles")
    ax[0].set_ylabel("seconds")
    ax[0].legend()
    ax[1].plot(a[:, 0], a[:, 6] * 100, "o-", label="max position error, % R")
    ax[1].plot(a[:, 0], a[:, 7] * 100, "s-", label="mean resolution, %")
    ax[1].set_xscale("log")
    ax[1].set_xlabel("triangles (inverse mesh)")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(OUT / "reconstruction.png", dpi=100)
    lines = [
        "# Reconstruction benchmark",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"Python {platform.python_version()}, numpy {np.__version__}. "
        f"Mode: {'--quick' if quick else 'full'}.",
        "",
        "Laplace prior, hyperparameter by noise figure 0.3; data simulated on a 30k-triangle "
        "mesh, 1 % noise; 30 targets (5 % R radius, conductivity x2) at 0..0.9 R.",
        "",
        "| triangles | build s | frame ms | batched ms/frame | GN iter ms | GN iters "
        "| max PE (R) | mean RES | pyEIT build s | pyEIT frame ms |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r[0]} | {r[1]:.3f} | {r[2]:.3f} | {r[3]:.4f} | {r[4]:.1f} | {r[5]} | "
            f"{r[6]:.4f} | {r[7]:.3f} | {r[8]:.3f} | {r[9]:.3f} |"
        )
    lines += ["", "![speed and error](reconstruction.png)", ""]
    (OUT / "REPORT.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
