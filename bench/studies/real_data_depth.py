"""A tank's third dimension in the model (issue 35): fitted depth, simulated ball, real tanks.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.studies.real_data_depth [PART ...]``
with parts ``sim`` (a ball in a simulated 3-D tank, about 5 min), ``real`` (the four real
tank sets, about 8 min), ``cost`` (build and per-frame cost, 1 min) and ``nodepth`` (1 min);
the first three by default.
Numbers and conclusions: ``real_data_depth.md`` beside this file.

* ``sim``: the 3-D check's tetrahedral cylinder (:mod:`bench.studies.real_data_3d_check`:
  point electrodes, a ball of the set's radius at its documented single-target positions,
  conductivity 1/1000) of half-height 0.02 m (the 2-D control) and 0.15 m. The depth is fitted
  to the simulated unloaded frame only (:func:`~eit_skin.fem.device_fit.fit_depth`), then the
  ball is imaged by the set's patch as shipped (2-D) and with that depth (``layers[].depth``).
* ``real``: every real tank set's depth fitted to its own unloaded reference (never to the
  targets), then the reconstruction node's chain (``bench_real_data.run_eit_skin``) with and
  without it, scored as ``bench_real_data.py`` scores (positions, blobs, artefact energy,
  tracks) beside pyEIT JAC.
* ``nodepth``: what a tank patch without a depth gets: the four tank sets imaged as 2-D
  sheets (their ``depth`` removed) by the package default and by the default it replaced
  (:data:`OLD_DEFAULT`), scored against pyEIT JAC with ``bench_real_data``'s goals.
* ``cost``: forward model build, one factorisation, Jacobian and the imager's build for the
  Ottawa patch, 2-D against the fitted depth; the per-frame cost of the one-step image.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from bench.standing import real_data_scoring as scoring
from bench.standing.bench_real_data import (
    DATA,
    candidate_images,
    candidate_layer,
    goal_failures,
    repeated_frames,
    run_eit_skin,
    run_pyeit,
    sheet_radius,
)
from bench.studies.real_data_3d_check import PITCH, Tank3d, blob_text, cylinder_mesh
from eit_skin.fem.device_fit import fit_depth, fit_device
from eit_skin.fem.elements import layer_depth
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import Layer
from eit_skin.pipeline.builder import LayerImager

TANKS = ("ottawa_ph1", "ottawa_ph3", "iirc_rotate", "sciospec_adjacent")
#: The package default before the depths were shipped: (method, prior, noise figure, weights),
#: model-error share.
OLD_DEFAULT = (("one_step", "noser", 0.13, "measured"), 1 / 4)
KEYS = ("median_m", "p90_m", "spurious", "artefact_energy", "consistency", "fit_residual_m")


def fitted_depth(layer: Layer, reference: np.ndarray) -> tuple[float | None, float, float]:
    """``(depth m or None, fit residual, 2-D fit residual)`` of a no-load frame."""
    protocol = layer.measured_protocol
    start = {
        "sheet_conductance_s": layer.material.sheet_conductance_s,
        "contact_impedance_ohm_m": layer.contact_impedance_ohm_m,
        "current_a": layer.current_a,
        "magnitude": protocol.magnitude,
    }
    mesh = build_mesh(layer)
    depth, fit = fit_depth(mesh, protocol, reference, layer.electrodes[0].width_m, **start)
    flat = fit_device(mesh, protocol, reference, **start)
    return depth, fit.residual, flat.residual


def score_text(data: scoring.RealSet, run, radius: float) -> str:
    s = scoring.score(data, run.images, run.grid.x, run.grid.y, run.grid.inside, radius)
    return ", ".join(
        f"{k.removesuffix('_m')} {1e3 * s[k] if k.endswith('_m') else s[k]:.3f}"
        for k in KEYS
        if k in s
    )


def part_sim() -> None:
    name = "ottawa_ph1"
    layer = load_patch(DATA / f"{name}.yaml").layers[0]
    data = scoring.load_set(DATA / f"{name}.npz")
    radius = sheet_radius(layer)
    ball = float(np.max(np.load(DATA / f"{name}.npz")["truth_r"]))
    single = [t[0] for t in data.truth_xy if np.isfinite(t).all(axis=1).sum() == 1]
    targets = np.unique(np.round(np.array(single), 6), axis=0)
    for half in (0.02, 0.15):
        t0 = time.perf_counter()
        nodes, tets, el = cylinder_mesh(radius, half, layer.n_electrodes, PITCH)
        tank = Tank3d(nodes, tets, el, data.ex_mat, data.meas_mat)
        v0 = np.abs(tank.voltages(np.ones(len(tets))))
        depth, residual, _ = fitted_depth(layer, v0)
        chains = {"2-D": layer, "depth": replace(layer, depth_m=depth)}
        imagers = {k: LayerImager.build(v, cache_dir=None) for k, v in chains.items()}
        cells = []
        for target in targets:
            inside = np.linalg.norm(tank.centroids - [target[0], target[1], 0.0], axis=1) < ball
            v = np.abs(tank.voltages(np.where(inside, 1e-3, 1.0)))
            shown = []
            for key, imager in imagers.items():
                imager.use_reference(v0, None, v[None])
                image = imager.images(imager.relative_change(v[None], v0))[0]
                shown.append(f"{key} {blob_text(image, imager.grid)}")
            peer = run_pyeit(layer, replace(data, reference=v0, frames=v[None]), imager.grid)
            shown.append(f"pyEIT {blob_text(peer.images[0], peer.grid)}")
            cells.append(f"{np.round(1e3 * target).astype(int)} -> " + ", ".join(shown))
        fitted = "none (2-D)" if depth is None else f"{1e3 * depth:.0f} mm"
        print(
            f"sim tank {2e3 * half:.0f} mm: fitted depth {fitted} (residual {residual:.4f}, "
            f"{time.perf_counter() - t0:.0f} s): " + "; ".join(cells),
            flush=True,
        )


def part_real() -> None:
    for name in TANKS:
        layer = load_patch(DATA / f"{name}.yaml").layers[0]
        data = scoring.load_set(DATA / f"{name}.npz")
        radius = sheet_radius(layer)
        t0 = time.perf_counter()
        depth, residual, flat = fitted_depth(replace(layer, depth_m=None), data.reference)
        fit_s = time.perf_counter() - t0
        flat_run = run_eit_skin(replace(layer, depth_m=None), data)
        print(
            f"{name}: fitted depth "
            f"{'none (2-D)' if depth is None else f'{1e3 * depth:.0f} mm'} "
            f"(residual {residual:.4f}, 2-D {flat:.4f}; {fit_s:.0f} s)",
            flush=True,
        )
        print(f"  2-D:   {score_text(data, flat_run, radius)}", flush=True)
        if depth is not None:
            deep = run_eit_skin(replace(layer, depth_m=depth), data)
            print(f"  depth: {score_text(data, deep, radius)}", flush=True)
        peer = run_pyeit(layer, data, flat_run.grid)
        print(f"  pyEIT: {score_text(data, peer, radius)}", flush=True)


def part_nodepth() -> None:
    for name in TANKS:
        layer = load_patch(DATA / f"{name}.yaml").layers[0]
        flat = replace(layer, depth_m=None)
        data = scoring.load_set(DATA / f"{name}.npz")
        radius = sheet_radius(layer)
        new = run_eit_skin(flat, data)
        peer = run_pyeit(flat, data, new.grid)
        pyeit = scoring.score(data, peer.images, peer.grid.x, peer.grid.y, peer.grid.inside, radius)
        old_layer = candidate_layer(flat, *OLD_DEFAULT[0])
        old = replace(
            new, images=candidate_images(old_layer, data, repeated_frames(data), OLD_DEFAULT[1])[0]
        )
        for tag, run in (("new default", new), ("old default", old)):
            s = scoring.score(data, run.images, run.grid.x, run.grid.y, run.grid.inside, radius)
            print(
                f"{name} 2-D, {tag}: {score_text(data, run, radius)}; "
                f"goals missed {goal_failures(s, pyeit)[0]}",
                flush=True,
            )
        print(f"{name} pyEIT: {score_text(data, peer, radius)}", flush=True)


def part_cost() -> None:
    layer = load_patch(DATA / "ottawa_ph1.yaml").layers[0]
    data = scoring.load_set(DATA / "ottawa_ph1.npz")
    deep = layer if layer.depth_m is not None else replace(layer, depth_m=0.28)
    for tag, lay in (("2-D", replace(layer, depth_m=None)), ("depth", deep)):
        mesh = build_mesh(lay)
        times = []
        for _ in range(3):
            t = time.perf_counter()
            model = ForwardModel(
                mesh,
                lay.measured_protocol,
                lay.contact_impedance_ohm_m,
                lay.current_a,
                layer_depth(lay),
            )
            t1 = time.perf_counter()
            model.voltages(1.0)
            t2 = time.perf_counter()
            model.jacobian(1.0)
            times.append((t1 - t, t2 - t1, time.perf_counter() - t2))
        build, solve, jac = np.median(times, axis=0)
        t = time.perf_counter()
        imager = LayerImager.build(lay, cache_dir=None)
        imager.use_reference(data.reference, None, data.frames)
        imager_s = time.perf_counter() - t
        frame = []
        for v in data.frames:
            t = time.perf_counter()
            imager.frame_images(v, data.reference)
            frame.append(time.perf_counter() - t)
        print(
            f"cost {tag}: {model.n_nodes} nodes; model {1e3 * build:.0f} ms, factorisation + "
            f"solve {1e3 * solve:.0f} ms, Jacobian {1e3 * jac:.0f} ms; imager build "
            f"{imager_s:.1f} s; per frame {1e3 * np.median(frame):.2f} ms",
            flush=True,
        )


def main() -> None:
    parts = sys.argv[1:] or ["sim", "real", "cost"]
    for part in parts:
        {"sim": part_sim, "real": part_real, "cost": part_cost, "nodepth": part_nodepth}[part]()


if __name__ == "__main__":
    main()
