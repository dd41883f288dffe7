"""Is a tank's depth enough to move a 2-D image's blobs outwards? A 3-D check for real_data.md.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.studies.real_data_3d_check [SET] [H ...]``
(default ``ottawa_ph1`` and half-heights 0.02 0.06 0.15 m; the 0.15 m tank takes about two
minutes and 2 GB for its factorisations). Prints, per tank, where eit_skin's shipped chain
(the set's patch file, 2-D, the set's own reference and noise weighting as in
``bench_real_data.py``) puts the blob of an insulating ball simulated in 3-D.

The 3-D model: a cylinder of the patch's radius and height ``2 H``, the electrode ring in its
middle plane, uniform conductivity, linear tetrahedra on a jittered grid of pitch 8 mm
(Delaunay), point electrodes (the drive current enters at the electrode's wall node and the
voltage is read there: no measured pair touches a driven electrode in the sets this is meant
for). The ball (radius ``truth_r`` of the set) sits in the electrode plane at the set's
documented positions (single targets only), conductivity 1/1000 of the saline. Each frame is
``(V_ball, V_empty)`` of the 3-D model in the set's measurement order (magnitudes where the
patch says ``sign: -1``), imaged by the 2-D chain. A thin tank (``H`` = the ball radius) is
the 2-D control. Each frame is also imaged by pyEIT JAC as ``bench_real_data.py`` runs it
(its distmesh, its examples' settings, the same pixel grid), so the two tools' blobs can be
compared on a tank whose only departure from 2-D is its height.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl
from scipy.spatial import Delaunay

from bench.standing import real_data_scoring as scoring
from bench.standing.bench_real_data import DATA, run_pyeit, sheet_radius
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager

PITCH = 0.008  # m, grid pitch of the tetrahedral mesh
BALL_CONTRAST = 1e-3  # ball conductivity / saline conductivity


def cylinder_mesh(radius: float, half_height: float, n_el: int, pitch: float):
    """(nodes [n, 3], tetrahedra [T, 4], electrode nodes [n_el]) of a jittered-grid cylinder."""
    rng = np.random.default_rng(0)
    g = np.arange(-radius, radius + 1e-9, pitch)
    z = np.arange(-half_height, half_height + 1e-9, pitch)
    xx, yy, zz = np.meshgrid(g, g, z, indexing="ij")
    inner = np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()])
    inner = inner[np.hypot(inner[:, 0], inner[:, 1]) < radius - 0.5 * pitch]
    inner[:, :2] += rng.uniform(-0.05 * pitch, 0.05 * pitch, (len(inner), 2))
    n_wall = int(np.ceil(2 * np.pi * radius / pitch))
    n_wall += (-n_wall) % n_el  # electrodes on wall nodes of the middle ring
    a = 2 * np.pi * np.arange(n_wall) / n_wall
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    wall = np.concatenate([np.column_stack([ring, np.full(n_wall, h)]) for h in z])
    nodes = np.vstack([wall, inner])
    middle = int(np.argmin(np.abs(z)))
    electrodes = middle * n_wall + np.arange(0, n_wall, n_wall // n_el)
    tets = Delaunay(nodes).simplices
    keep = np.abs(np.linalg.det(edges(nodes, tets))) > 1e-12 * pitch**3
    return nodes, tets[keep], electrodes


def edges(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``[T, 3, 3]`` edge vectors from each tetrahedron's first node."""
    v = nodes[tets]
    return np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], v[:, 3] - v[:, 0]], axis=1)


class Tank3d:
    """P1 FEM of the cylinder: voltages of the set's protocol for an element conductivity."""

    def __init__(self, nodes, tets, electrodes, ex_mat, meas_mat) -> None:
        e = edges(nodes, tets)
        volume = np.abs(np.linalg.det(e)) / 6.0
        inv = np.linalg.inv(e)  # rows of inv^T are the basis gradients of nodes 1..3
        grad = np.concatenate([-inv.sum(axis=2, keepdims=True), inv], axis=2)  # [T, 3, 4]
        self.local = np.einsum("tdi,tdj->tij", grad, grad) * volume[:, None, None]
        self.rows = np.repeat(tets, 4, axis=1).ravel()
        self.cols = np.tile(tets, (1, 4)).ravel()
        self.n = len(nodes)
        self.centroids = nodes[tets].mean(axis=1)
        self.electrodes = electrodes
        self.ex_mat, self.meas_mat = ex_mat, meas_mat
        self.ground = int(np.argmin(nodes[:, 2]))  # a bottom node (the ring is in the middle)

    def voltages(self, sigma: np.ndarray) -> np.ndarray:
        """``[M]`` V(plus) - V(minus) of every measurement (unit current, arbitrary units)."""
        k = sp.csr_matrix(
            ((self.local * sigma[:, None, None]).ravel(), (self.rows, self.cols)),
            shape=(self.n, self.n),
        )
        keep = np.ones(self.n, dtype=bool)
        keep[self.ground] = False
        rhs = np.zeros((self.n, len(self.ex_mat)))
        inj = np.arange(len(self.ex_mat))
        rhs[self.electrodes[self.ex_mat[:, 0]], inj] += 1.0
        rhs[self.electrodes[self.ex_mat[:, 1]], inj] -= 1.0
        u = np.zeros_like(rhs)
        u[keep] = spl.splu(k[keep][:, keep].tocsc()).solve(rhs[keep])
        ue = u[self.electrodes]  # [n_el, n_inj]
        m = self.meas_mat
        return ue[m[:, 1], m[:, 0]] - ue[m[:, 2], m[:, 0]]


def blob_text(image: np.ndarray, grid) -> str:
    """The strongest insulating blob's centre in mm and its distance from the centre."""
    xy, _ = scoring.blobs(image, grid.x, grid.y, -1.0)
    if not len(xy):
        return "no blob"
    return f"{np.round(1e3 * xy[0]).astype(int)} r {1e3 * np.linalg.norm(xy[0]):.0f}"


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "ottawa_ph1"
    heights = [float(h) for h in sys.argv[2:]] or [0.02, 0.06, 0.15]
    layer = load_patch(DATA / f"{name}.yaml").layers[0]
    data = scoring.load_set(DATA / f"{name}.npz")
    with np.load(DATA / f"{name}.npz") as raw:
        repeated = raw.get("reference_frames")
    imager = LayerImager.build(layer, cache_dir=None)
    imager.use_reference(data.reference, repeated, data.frames)
    radius = sheet_radius(layer)
    ball = float(np.max(np.load(DATA / f"{name}.npz")["truth_r"]))
    single = [t[0] for t in data.truth_xy if np.isfinite(t).all(axis=1).sum() == 1]
    targets = np.unique(np.round(np.array(single), 6), axis=0)
    print(f"{name}: R {1e3 * radius:.0f} mm, ball r {1e3 * ball:.0f} mm, 2-D chain of the patch")
    for h in heights:
        t0 = time.perf_counter()
        nodes, tets, el = cylinder_mesh(radius, h, layer.n_electrodes, PITCH)
        tank = Tank3d(nodes, tets, el, data.ex_mat, data.meas_mat)
        v0 = tank.voltages(np.ones(len(tets)))
        r = np.corrcoef(np.abs(v0), np.abs(data.reference))[0, 1]
        cells = []
        for target in targets:
            inside = np.linalg.norm(tank.centroids - [target[0], target[1], 0.0], axis=1) < ball
            v = tank.voltages(np.where(inside, BALL_CONTRAST, 1.0))
            pair = (np.abs(v), np.abs(v0)) if imager.protocol.magnitude else (v, v0)
            image = imager.images(imager.relative_change(pair[0][None], pair[1]))[0]
            synthetic = replace(data, reference=pair[1], frames=pair[0][None])
            peer = run_pyeit(layer, synthetic, imager.grid)
            shown = [
                blob_text(im, g) for im, g in ((image, imager.grid), (peer.images[0], peer.grid))
            ]
            cells.append(f"{np.round(1e3 * target).astype(int)} -> {shown[0]} (pyEIT {shown[1]})")
        print(
            f"  tank height {2e3 * h:.0f} mm ({len(nodes)} nodes, {time.perf_counter() - t0:.0f} s;"
            f" measured reference vs this model r = {r:.4f}): " + "; ".join(cells),
            flush=True,
        )


if __name__ == "__main__":
    main()
