"""The package default on bench/standing/reconstruction.md's simulator, beside the default it
replaced.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.studies.real_data_default_simulator``
(about a
minute). Prints one Markdown row per inverse mesh of ``bench_reconstruction.py``'s per-mesh
table: max PE (fraction of R), mean RES, mean RNG, max SD of the one-step matrix with the
package default (:class:`~eit_skin.patch.model.SolverSpec`'s prior at the method's default
noise figure, chosen by leaving one set out in ``bench/standing/real_data.md``) and with the default
before issue 35's choice (Laplace prior at noise figure 0.3). Same data as that table: a
19766-triangle data mesh, 30 targets (radius 5 % R, conductivity x2) at 0..0.9 R, 1 % noise,
seed 0. The model-error rule does not bind on simulated references (misfit 0.1-0.2 %), so the
matrix is the noise-figure choice alone, unweighted, as in that table's Laplace columns.
"""

from __future__ import annotations

import numpy as np

from bench.standing.bench_reconstruction import SIZES, R, merit
from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.phantoms import disc_centres, simulate_discs
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.patch.model import SolverSpec
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

#: The one-step default before issue 35's leave-one-set-out choice: (prior, noise figure).
BEFORE = ("laplace", 0.3)


def main() -> None:
    protocol = build_protocol(ProtocolSpec(), 16)
    fine = ForwardModel(disk_mesh(R, h_m=0.0012), protocol, 1e-4)
    v0 = fine.voltages(1.0)
    centres = disc_centres(R)
    frames = simulate_discs(fine, centres, 0.05 * R, 2.0, 0.01, np.random.default_rng(0)).frames
    phantoms = list(zip(centres, frames, strict=True))
    now = (SolverSpec().prior, DEFAULT_NOISE_FIGURE[SolverSpec().method])
    print(f"data mesh {fine.mesh.n_triangles} triangles, {len(phantoms)} phantoms")
    print(
        f"| triangles | {now[0]} NF {now[1]:g}: max PE | RES | RNG | SD | "
        f"{BEFORE[0]} NF {BEFORE[1]:g}: max PE | RES | RNG | SD |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for h in SIZES:
        mesh = disk_mesh(R, h_m=h)
        grid = ImageGrid.build(mesh, 64)
        fwd = ForwardModel(mesh, protocol, 1e-4)
        cells = []
        for prior, nf in (now, BEFORE):
            rm = ReconstructionMatrix.build(fwd, prior=prior, noise_figure=nf)
            pe, res, rng, sd = merit(grid, rm.reconstruct(frames, v0), phantoms)
            cells.append(f"{pe:.4f} | {res:.3f} | {rng:.2f} | {sd:.2f}")
        print(f"| {mesh.n_triangles} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
