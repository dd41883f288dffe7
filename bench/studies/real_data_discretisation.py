"""How far do the Ottawa figures move with choices that carry no information? (issue 35)

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.studies.real_data_discretisation``
(about two minutes of CPU, one core); writes ``bench/studies/real_data_discretisation.md``.

The goals of issue 35 still missed on the Ottawa phantoms compare eit_skin with pyEIT JAC by
1.1 / 1.3 mm of median position error (4 targets per set) and by 0.005 of artefact energy
(ottawa_ph1). This study asks whether such differences are the methods' or the
discretisation's: the same data, the same tools and settings as ``bench_real_data.py``,
imaged again with the whole model rotated about the tank's axis by ``ROTATIONS`` angles (the
electrodes, the ball positions and both tools' meshes turn with it; the data do not change,
as electrode ``i`` is still electrode ``i``). The physics is the same at every angle; what
changes is where the meshes' triangles and the pixel grid fall relative to the balls. A
figure that differs between two angles by more than between the tools cannot decide between
them.

Two element-to-pixel maps per tool: ``flat`` (each pixel takes the value of the element under
its centre: eit_skin's ``ImageGrid`` and the bench's pyEIT
images) and ``linear`` (element values averaged to the nodes, area-weighted, then
interpolated linearly inside each triangle: pyEIT's ``sim2pts`` with Gouraud shading, the
picture its examples draw), scored by ``bench/standing/real_data_scoring.py``.

Method swaps, each one difference between the tools on its own (flat map, every rotation):
eit_skin with equal channel weights (the Ottawa sets have no repeated frames, so the chain
weights the channels by the reciprocity of the one reference; pyEIT weights none; the
hyperparameter rule is otherwise the same), eit_skin on pyEIT's distmesh as its inverse mesh
(complete-electrode forward model unchanged), and both tools over their hyperparameter
(eit_skin ``h`` with the chain's weights; pyEIT ``lamb``, reported with the eit_skin ``h`` it
equals: ``h^2 = lamb M / trace(J R^-1 J^T)``, ``R = diag(J^T J)^0.5``, pyEIT's Jacobian).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.header import load_average, run_header
from bench.standing import real_data_scoring as scoring
from bench.standing.bench_real_data import (
    DATA,
    PYEIT_H0,
    PYEIT_SETUP,
    pyeit_protocol,
    repeated_frames,
    sheet_radius,
)
from eit_skin.fem.image_grid import ImageGrid, locate_points
from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.dispatch import make_reconstructor
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import LayerImager, forward_model

REPORT = Path(__file__).resolve().with_suffix(".md")
SETS = ("ottawa_ph1", "ottawa_ph3")
#: Rotations of the whole model, degrees: 24 steps of 15 degrees (every electrode gap, 22.5
#: degrees, is met at a different phase).
ROTATIONS = tuple(15.0 * k for k in range(24))
MAPS = ("flat", "linear")
#: Hyperparameter sweeps: eit_skin ``h`` (the chain's weights) and pyEIT JAC ``lamb``.
EIT_SKIN_H = (0.06, 0.1, 0.3)
PYEIT_LAMB = (0.003, 0.03, 0.1)


def rotated_layer(name: str, degrees: float):
    """The set's patch file with its electrode ring turned by ``degrees`` (counter-clockwise)."""
    text = (DATA / f"{name}.yaml").read_text()
    if text.count("start_angle_deg: 0.0") != 1:
        raise ValueError(f"{name}.yaml: expected one 'start_angle_deg: 0.0'")
    text = text.replace("start_angle_deg: 0.0", f"start_angle_deg: {degrees!r}")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.yaml"
        path.write_text(text)
        return load_patch(path).layers[0]


def rotated_set(data: scoring.RealSet, degrees: float) -> scoring.RealSet:
    """``data`` with its documented targets turned by ``degrees`` about the centre."""
    a = np.deg2rad(degrees)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return replace(data, truth_xy=data.truth_xy @ rot.T)


def linear_map(mesh: Mesh, grid: ImageGrid) -> np.ndarray:
    """``[H*W, N]`` dense map: element values -> area-weighted nodal mean -> linear in triangles.

    Pixels off the mesh are rows of NaN.
    """
    tri = mesh.triangles
    areas = np.abs(mesh.areas)
    n_nodes, n_el = len(mesh.nodes), len(tri)
    to_nodes = np.zeros((n_nodes, n_el))
    np.add.at(to_nodes, (tri.ravel(), np.repeat(np.arange(n_el), 3)), np.repeat(areas, 3))
    to_nodes /= to_nodes.sum(axis=1, keepdims=True)
    xx, yy = np.meshgrid(grid.x, grid.y)
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    owner = locate_points(mesh, pts)
    on = owner >= 0
    p = mesh.nodes[tri[owner[on]]]  # [P, 3, 2]
    e1, e2, q = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], pts[on] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    l1 = (q[:, 0] * e2[:, 1] - q[:, 1] * e2[:, 0]) / det
    l2 = (e1[:, 0] * q[:, 1] - e1[:, 1] * q[:, 0]) / det
    bary = np.column_stack([1.0 - l1 - l2, l1, l2])  # [P, 3]
    out = np.full((len(pts), n_el), np.nan)
    out[on] = np.einsum("pk,pkn->pn", bary, to_nodes[tri[owner[on]]])
    return out


def images(mesh: Mesh, values: np.ndarray, grid: ImageGrid, kind: str) -> np.ndarray:
    """``[T, H, W]`` images of element values ``[T, N]`` by the map ``kind``."""
    if kind == "flat":
        return grid.to_image(values)
    return (values @ linear_map(mesh, grid).T).reshape(-1, *grid.shape)


def chain_values(imager: LayerImager, data: scoring.RealSet) -> np.ndarray:
    """``[T, N]`` element values of the set's frames through ``imager`` as it stands."""
    return imager.relative_change(data.frames, data.reference)


def eit_skin_imager(layer, data: scoring.RealSet) -> tuple[LayerImager, LayerImager]:
    """The bench's chain (package default, reference check) with the channels weighted by
    their measured noise and with every channel weighted equally (``solver.channel_weights``)."""
    imager = LayerImager.build(layer, cache_dir=None)
    pair = tuple(
        replace(
            imager,
            layer=replace(imager.layer, solver=replace(imager.layer.solver, channel_weights=w)),
        )
        for w in ("measured", "equal")
    )
    for one in pair:
        one.use_reference(data.reference, repeated_frames(data), data.frames)
    return pair


def distmesh_imager(layer, data: scoring.RealSet, mesh: Mesh, grid: ImageGrid) -> LayerImager:
    """eit_skin's chain with ``mesh`` (pyEIT's) as the inverse mesh, imaged on ``grid``."""
    forward = forward_model(layer)
    sigma0 = layer.material.sheet_conductance_s
    rec = make_reconstructor(
        "one_step", forward, mesh=mesh, prior=layer.solver.prior, sigma0=sigma0
    )
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    imager = LayerImager(
        layer, protocol, mesh, rec.linearised, grid, False, rec, forward.voltages(sigma0)
    )
    imager.use_reference(data.reference, repeated_frames(data), data.frames)
    return imager


def pyeit_solver(layer, data: scoring.RealSet, lamb: float):
    """pyEIT JAC (its examples' distmesh and settings, ``lamb``) and its mesh."""
    from pyeit.eit import jac
    from pyeit.mesh import create

    radius = sheet_radius(layer)
    centres = np.array([e.center for e in layer.electrodes])
    pm = create(layer.n_electrodes, h0=PYEIT_H0, p_fix=centres / radius)
    mesh = Mesh(nodes=pm.node[:, :2] * radius, triangles=pm.element, electrode_edges=())
    solver = jac.JAC(pm, pyeit_protocol(data))
    solver.setup(**{**PYEIT_SETUP, "lamb": lamb})
    return solver, mesh


def pyeit_h(solver) -> float:
    """The eit_skin ``h`` that pyEIT's ``lamb`` equals on its own (unweighted) Jacobian."""
    j = solver.J
    k = (j / np.sqrt(np.diag(j.T @ j))) @ j.T
    return float(np.sqrt(solver.params["lamb"] * k.shape[0] / np.trace(k)))


def pyeit_values(solver, data: scoring.RealSet) -> np.ndarray:
    return np.real(solver.solve(data.frames, data.reference, normalize=True)).T


def rotation_figures(name: str, degrees: float) -> dict:
    """``{(tool, map): (median m, artefact energy)}`` of one rotation of one set."""
    layer = rotated_layer(name, degrees)
    data = rotated_set(scoring.load_set(DATA / f"{name}.npz"), degrees)
    radius = sheet_radius(layer)
    imager, equal = eit_skin_imager(layer, data)
    grid = imager.grid
    half = 0.5 * (grid.x[1] - grid.x[0])
    box = (grid.x[0] - half, grid.y[0] - half, grid.x[-1] + half, grid.y[-1] + half)
    solver, pmesh = pyeit_solver(layer, data, PYEIT_SETUP["lamb"])
    pgrid = ImageGrid.build(pmesh, layer.solver.image_pixels, bounding_box=box)
    runs = {
        "eit_skin": (chain_values(imager, data), imager.mesh, grid, MAPS),
        "pyEIT": (pyeit_values(solver, data), pmesh, pgrid, MAPS),
        "eit_skin, equal weights": (chain_values(equal, data), imager.mesh, grid, ("flat",)),
    }
    distmesh = distmesh_imager(layer, data, pmesh, pgrid)
    runs["eit_skin on pyEIT's mesh"] = (chain_values(distmesh, data), pmesh, pgrid, ("flat",))
    base = imager.matrix
    for h in EIT_SKIN_H:
        imager.matrix = imager.reconstructor = base.with_hyperparameter(h)
        runs[f"eit_skin h {h:g}"] = (chain_values(imager, data), imager.mesh, grid, ("flat",))
    for lamb in PYEIT_LAMB:
        other, _ = pyeit_solver(layer, data, lamb)
        runs[f"pyEIT lamb {lamb:g}"] = (pyeit_values(other, data), pmesh, pgrid, ("flat",))
    out = {"h": (base.hyperparameter, pyeit_h(solver))}
    for tool, (values, mesh, g, kinds) in runs.items():
        for kind in kinds:
            s = scoring.score(data, images(mesh, values, g, kind), g.x, g.y, g.inside, radius)
            out[(tool, kind)] = (s["median_m"], s["artefact_energy"])
    return out


def figures(name: str) -> dict:
    """``{(tool, map): [rotations, 2]}`` (median m, artefact energy) for one set."""
    per = [rotation_figures(name, degrees) for degrees in ROTATIONS]
    return {k: np.array([p[k] for p in per]) for k in per[0] if k in per[-1]}


def summary_rows(name: str, result: dict) -> list[str]:
    """Distribution over the rotations of each tool's figures, and the paired comparison."""
    rows = []
    for kind in MAPS:
        es, py = result[("eit_skin", kind)], result[("pyEIT", kind)]
        for col, what, unit in ((0, "median position error", 1e3), (1, "artefact energy", 1.0)):
            a, b = unit * es[:, col], unit * py[:, col]
            f = "{:.1f}" if col == 0 else "{:.3f}"
            rows.append(
                f"| {name} | {what} | {kind} | {f.format(a[0])} / {f.format(b[0])} | "
                f"{spread(a, f)} | {spread(b, f)} | {np.mean(a <= b):.2f} | "
                f"{f.format(np.mean(a - b))} +- {f.format(np.std(a - b) / np.sqrt(len(a)))} |"
            )
    return rows


def spread(values: np.ndarray, f: str) -> str:
    return f"{f.format(values.min())}-{f.format(values.max())} (mean {f.format(values.mean())})"


def swap_rows(name: str, result: dict) -> list[str]:
    """Every variant's figures (flat map): at 0 degrees, mean over the rotations, vs pyEIT."""
    py = result[("pyEIT", "flat")]
    rows = []
    for key, v in result.items():
        if key[1:] != ("flat",) or key[0] == "pyEIT":
            continue
        tool = key[0]
        rows.append(
            f"| {name} | {tool} | {1e3 * v[0, 0]:.1f} / {v[0, 1]:.3f} | "
            f"{1e3 * v[:, 0].mean():.1f} / {v[:, 1].mean():.3f} | "
            f"{np.mean(v[:, 0] <= py[:, 0]):.2f} / {np.mean(v[:, 1] <= py[:, 1]):.2f} |"
        )
    return rows


def main() -> None:
    start = time.time()
    load_before = load_average()
    lines = [
        "# Ottawa figures against discretisation: eit_skin and pyEIT JAC, model rotated",
        "",
        run_header(load_before),
        "",
        __doc__.split("\n\n", 1)[1].strip().replace("``", "`"),
        "",
        f"Rotations: {len(ROTATIONS)}, 0 to {ROTATIONS[-1]:g} degrees. Per set, figure and "
        "map: the value at 0 degrees (the bench's), the range and mean over the rotations, "
        "the fraction of rotations on which eit_skin's figure is <= pyEIT's, and the mean "
        "paired difference eit_skin - pyEIT +- its standard error (rotations are not "
        "independent samples of anything: the standard error only says how stable the mean is).",
        "",
        "| set | figure | map | at 0 degrees (eit_skin / pyEIT) | eit_skin over rotations | "
        "pyEIT over rotations | eit_skin <= pyEIT | mean difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    results = {}
    for name in SETS:
        results[name] = figures(name)
        lines += summary_rows(name, results[name])
        print(f"{name} done ({time.time() - start:.0f} s)", flush=True)
    lines += [
        "",
        "Method swaps (flat map; the hyperparameter sweeps keep the chain's channel weights). "
        "Columns: median position error mm / artefact energy at 0 degrees, the same as means "
        "over the rotations, and the fraction of rotations on which the variant's figure is <= "
        "pyEIT's (position / artefact energy). pyEIT JAC itself: "
        + "; ".join(
            f"{name} {1e3 * r[('pyEIT', 'flat')][0, 0]:.1f} / {r[('pyEIT', 'flat')][0, 1]:.3f} "
            f"at 0 degrees, {1e3 * r[('pyEIT', 'flat')][:, 0].mean():.1f} / "
            f"{r[('pyEIT', 'flat')][:, 1].mean():.3f} on average; h of the rule "
            f"{r['h'][:, 0].mean():.3f}, pyEIT's lamb 0.01 as an eit_skin h "
            f"{r['h'][:, 1].mean():.3f}"
            for name, r in results.items()
        )
        + ".",
        "",
        "| set | variant | at 0 degrees | mean over rotations | <= pyEIT (position / energy) |",
        "|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines += swap_rows(name, r)
    lines.append("")
    REPORT.write_text("\n".join(lines))
    print(f"wrote {REPORT}")


if __name__ == "__main__":
    main()
