"""Reconstruction speed against error: eit_skin vs pyEIT JAC on the same disk meshes and data.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_reconstruction [--quick]
[--gn-only | --gn-node | --online-only | --frame-only] [--json OUT.json]``;
writes ``bench/standing/reconstruction.md`` and ``bench/standing/reconstruction.png``.

* Data: simulated once on a finer mesh (h = 1.2 mm, ~23k triangles) than any reconstruction
  mesh; 30 targets (radius 5 % R, conductivity x2) at 0..0.9 R, three angles each; noise 1 %
  of the RMS difference signal.
* Same meshes for both packages: pyEIT gets our nodes and triangles and a point electrode at
  each electrode's middle boundary node; our frames are mapped to pyEIT's measurement order
  (pyEIT's ``std`` parser measures ``V(m+1) - V(m)``, ours ``V(m) - V(m+1)``: sign flipped).
* Figures of merit (GREIT, :mod:`eit_skin.inverse.figures_of_merit`) on the same 64 x 64 pixel grid.
* Timings: build once per mesh (pyEIT's 11k build takes minutes); frame times are the median
  of repeated calls (other engineers use the same 2 cores).
* Inverse-mesh sweep: fixed fine forward mesh, coarser inverse meshes (``inverse_mesh=``).
* Gauss-Newton (``--gn-only`` runs just this part and rewrites only its section of the
  report): 5 iterations on a x20 target, NOSER and Laplace priors; the one-off call with the
  unknowns on the forward mesh, and a reusable :class:`GaussNewtonSolver` (built once per
  mesh, like the one-step matrix) with the unknowns on a coarse parameter mesh (edge 0.16 R,
  416 triangles: the coarsest inverse mesh of the sweep that meets PE <= 2 % R). Per frame:
  wall and CPU time (median of repeats) and the per-iteration split into forward solves
  (factorisation + potentials), Jacobian (field-pair products) and the rest.
* Online Gauss-Newton (``--online-only`` runs just this part): accuracy per millisecond of
  cold and warm-started variants on a press sequence at 100 Hz, against five cold
  iterations per frame.
* ``--json OUT.json``: one row per mesh (:data:`JSON_KEYS`; null where not measured).
* Frame -> image (``--frame-only`` runs just the per-mesh table, without Gauss-Newton,
  sweep or plot, and rewrites only the report's first section): ours
  (the node's planned step, ``pipeline.frame_plan``) and pyEIT's ``solve`` followed by the
  same unit, clip and gather onto the same pixels, so both produce the same image.
* Gauss-Newton in the node (``--gn-node`` runs just this part and rewrites only its section):
  the shipped arm, face and elbow layers switched to ``method: gauss_newton`` and imaged
  frame by frame through ``LayerImager.relative_change`` (the reconstruction node's call) on
  the simulator's demo scenario, pinned to one core; sustained frames/s per layer and per
  patch, wall and CPU.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.phantoms import disc_centres, simulate_discs
from eit_skin.inverse.figures_of_merit import figures_of_merit
from eit_skin.inverse.gauss_newton import FitOptions, GaussNewtonSolver, WarmStart
from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.greit import greit_matrix
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
from eit_skin.inverse.one_step import ReconstructionMatrix, imaging_jacobian, reference_scale
from eit_skin.inverse.priors import make_prior
from eit_skin.patch.loading import load_patch
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from eit_skin.pipeline.builder import LayerImager, with_method
from eit_skin.pipeline.frame_kernel import frame_step
from eit_skin.pipeline.frame_plan import FrameChecks, FramePlan
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator

R = 0.05
#: Frame -> image: a unit factor (e.g. Pa per unit relative change) and the pipeline's clip.
UNIT, FLOOR = 1.0e4, -0.9e4
NOISE_FIGURE = 0.3  # Laplace prior: the noise-figure study's value (config/elbow.yaml)
GREIT_NOISE_FIGURE = DEFAULT_NOISE_FIGURE["greit"]  # trained matrix, the shipped value
OUT = Path(__file__).resolve().parent
SIZES = [0.0066, 0.0047, 0.0036, 0.0033, 0.0023, 0.0016]  # 0.7k, 1.3k, 2.2k, 2.7k, 5.4k, 11k
SWEEP = [0.012, 0.010, 0.008, 0.0066, 0.0047, 0.0033]  # inverse h over a 2.3 mm forward mesh
GN_PARAMETER_H = 0.008  # 0.16 R, 416 triangles: the sweep's coarsest mesh with PE <= 2 % R
GN_TARGET = np.array([-0.3, 0.4]) * R  # x20 conductance, radius 0.2 R
GN_REPEATS = 9
GN_NODE_PATCHES = ("arm", "face", "elbow")  # the shipped configs
GN_NODE_RATE_HZ = 10.0  # demo scenario sampled at this rate: 164 frames per layer
ONLINE_FRAMES = 40  # 0.4 s of a press at 100 Hz
ONLINE_RATE_HZ = 100.0
#: (label, warm start, step tolerance, relinearise distance, max iterations); the first row
#: is the reference: five cold Gauss-Newton iterations per frame (the reconstructor before)
ONLINE_CONFIGS = [
    ("cold, 5 GN iterations", False, 0.0, 0.0, 5),
    ("cold, 3 GN iterations", False, 0.0, 0.0, 3),
    ("cold, 2 GN iterations", False, 0.0, 0.0, 2),
    ("cold, 1 GN iteration (one-step + 1 solve)", False, 0.0, 0.0, 1),
    ("warm, GN steps, step test 0.01", True, 0.01, 0.0, 5),
    ("warm, quasi-Newton 0.3, step test 0.01", True, 0.01, 0.3, 5),
    ("warm, quasi-Newton 0.5, step test 0.01 (default)", True, 0.01, 0.5, 5),
    ("warm, quasi-Newton 0.5, step test 0.03", True, 0.03, 0.5, 5),
    ("warm, quasi-Newton 1.0, step test 0.03", True, 0.03, 1.0, 5),
    ("warm, fixed Jacobian, 1 step per frame", True, 0.0, 1e9, 1),
]


def loaded() -> bool:
    """Whether other jobs load the machine: 1-min load average above half the CPUs."""
    return hasattr(os, "getloadavg") and os.getloadavg()[0] > 0.5 * (os.cpu_count() or 1)


def median_time(fn, n):
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def interleaved_medians(fns, n):
    """Median time, s, of each of ``fns`` called in turn ``n`` times: on a shared machine the
    load hits every candidate alike, so their ratio holds even when the absolute times do not.
    """
    times = [[] for _ in fns]
    for _ in range(n):
        for fn, t_fn in zip(fns, times, strict=True):
            t = time.perf_counter()
            fn()
            t_fn.append(time.perf_counter() - t)
    return [float(np.median(t_fn)) for t_fn in times]


def copy_bandwidth() -> float:
    """Memory bandwidth of this core, bytes/s: ``np.copyto`` of 64 MiB (read + write), median
    of 5 (the floor a frame's bytes can be moved at; caches do not hold 128 MiB)."""
    src = np.ones(16 * 2**20, dtype=np.float32)
    dst = np.empty_like(src)
    return 2 * src.nbytes / median_time(lambda: np.copyto(dst, src), 5)


def memory_floor_s(rm, grid, n_channels: int, batch: int, bandwidth: float) -> float:
    """Least time, s, to move one frame's bytes at ``bandwidth``: the merged matrix read once
    per call of ``batch`` frames, the frame (float64 ``[M]``) read and the float32 ``[H, W]``
    image written."""
    matrix = rm.merged.matrix.nbytes
    return (matrix / batch + 8 * n_channels + 4 * grid.inside.size) / bandwidth


def merit(grid, values, phantoms):
    """max PE / R, mean RES, mean RNG, max SD over the phantoms."""
    imgs = grid.to_image(values)
    f = [
        figures_of_merit(im, grid.x, grid.y, c, sign=1.0)
        for im, (c, _) in zip(imgs, phantoms, strict=True)
    ]
    return (
        max(x.position_error_m for x in f) / R,
        float(np.mean([x.resolution for x in f])),
        float(np.mean([x.ringing for x in f])),
        max(x.shape_deformation for x in f),
    )


def frame_to_image(rm, grid, v0):
    """(one, many): frame ``[M]`` / frames ``[T, M]`` V -> pressure images of ``UNIT`` Pa per
    relative change against ``v0``: one frame by its plan (the node's step,
    :mod:`eit_skin.pipeline.frame_plan`), ``T`` frames by one product and the grid."""
    plan, step, checks = FramePlan.build(rm, grid, UNIT, None), frame_step(), FrameChecks()
    low, high = RELATIVE_CHANGE_RANGE

    def many(frames):
        return grid.to_image(UNIT * np.clip(rm.reconstruct(frames, v0), low, high))

    return (lambda frame: step(plan, frame, v0, checks).image), many


def greit_case(mesh, protocol, frames, v0, phantoms, grid, bandwidth: float = float("nan")):
    """The shipped method (GREIT-trained matrix) on ``mesh``: build, times, error.

    Frames ``[T, M]`` V, phantoms ``[(c, v)]``. Returns a dict: ``forward``, ``matrix``,
    ``build_s``; ``frame_s`` / ``batched_s`` (per frame): frame -> image (pixels of ``grid``,
    a unit factor, the clip at -0.9 of the pipeline, NaN outside: one float32 product,
    :func:`frame_to_image`); ``element_frame_s`` / ``element_batched_s``: frame
    -> element values only (:meth:`ReconstructionMatrix.reconstruct`, pyEIT's output);
    ``image_error``: max |float32 image - float64 chain| / max |image| over the frames;
    ``merit``: :func:`merit` of the element values; ``frame_floor_s`` / ``batched_floor_s``:
    :func:`memory_floor_s` at ``bandwidth`` bytes/s (NaN if not given).
    """
    t = time.perf_counter()
    fwd = ForwardModel(mesh, protocol, 1e-4)
    rm = greit_matrix(imaging_jacobian(fwd), mesh, noise_figure=GREIT_NOISE_FIGURE)
    build = time.perf_counter() - t
    unit, floor = UNIT, FLOOR
    one, many = frame_to_image(rm, grid, v0)
    exact = np.asarray(rm.matrix, dtype=np.float64) @ ((frames - v0) / reference_scale(v0)).T
    exact = grid.to_image(np.maximum(unit * exact.T, floor))
    fast = np.stack([one(f) for f in frames])
    return {
        "forward": fwd,
        "matrix": rm,
        "build_s": build,
        "frame_s": median_time(lambda: one(frames[0]), 50),
        "batched_s": median_time(lambda: many(frames), 10) / len(frames),
        "element_frame_s": median_time(lambda: rm.reconstruct(frames[0], v0), 50),
        "element_batched_s": median_time(lambda: rm.reconstruct(frames, v0), 10) / len(frames),
        "image_error": float(np.nanmax(np.abs(fast - exact)) / np.nanmax(np.abs(exact))),
        "merit": merit(grid, rm.reconstruct(frames, v0), phantoms),
        "frame_floor_s": memory_floor_s(rm, grid, v0.size, 1, bandwidth),
        "batched_floor_s": memory_floor_s(rm, grid, v0.size, len(frames), bandwidth),
    }


def pyeit_case(mesh, protocol, frames, v0, phantoms, grid):
    """pyEIT 1.2.4 JAC on ``mesh``: build s, element frame s, frame -> image s, merit.

    Element frame: ``solver.solve`` (volts -> element values, all pyEIT gives). Frame ->
    image: the same output as eit_skin's frame -> image (the float32 pixel image of ``grid``
    with the unit factor, the clip and NaN outside the sheet) made from pyEIT's element
    values by the cheapest route numpy offers (a unit multiply, ``np.maximum`` and
    :meth:`ImageGrid.to_image`'s gather), so the two frame -> image times compare like with
    like.
    """
    from pyeit.eit import jac
    from pyeit.eit import protocol as pprot
    from pyeit.mesh import PyEITMesh

    el_pos = np.array([e[len(e) // 2, 0] for e in mesh.electrode_edges])
    pm = PyEITMesh(node=mesh.nodes, element=mesh.triangles, perm=1.0, el_pos=el_pos, ref_node=0)
    prot = pprot.create(16, dist_exc=1, step_meas=1, parser_meas="std")
    # our channel and sign for each of pyEIT's (injection, n, m) measurements
    ours = {(int(k), int(p), int(m)): i for i, (k, p, m) in enumerate(protocol.measurements)}
    idx, sign = [], []
    for k in range(prot.ex_mat.shape[0]):
        for n, m in prot.meas_mat[k]:
            if (k, int(n), int(m)) in ours:
                idx.append(ours[(k, int(n), int(m))])
                sign.append(1.0)
            else:
                idx.append(ours[(k, int(m), int(n))])
                sign.append(-1.0)
    idx, sign = np.array(idx), np.array(sign)
    solver = jac.JAC(pm, prot)
    t = time.perf_counter()
    solver.setup(p=0.5, lamb=0.01, method="kotre", perm=1.0, jac_normalized=True)
    build = time.perf_counter() - t
    f_py = frames[:, idx] * sign
    v0_py = v0[idx] * sign
    frame_t = median_time(lambda: solver.solve(f_py[0], v0_py, normalize=True), 30)
    ds = np.real(solver.solve(f_py, v0_py, normalize=True)).T  # [T, N]
    # pyEIT's sign convention: make a conductive target positive
    sign = -1.0 if np.sum(ds[0]) < 0 else 1.0
    ds = sign * ds
    unit, floor = sign * UNIT, FLOOR

    def image():  # the cheapest numpy route: unit and clip in place, one casting copy, gather
        x = solver.solve(f_py[0], v0_py, normalize=True)  # float64 [N] (real data: real)
        np.multiply(x, unit, out=x)
        np.maximum(x, floor, out=x)
        return grid.to_image(x)

    image_t = median_time(image, 30)
    return build, frame_t, image_t, merit(grid, ds, phantoms), image


class TimedForward:
    """A forward model whose ``voltages`` and ``jacobian_basis`` calls are timed (wall, s)."""

    def __init__(self, forward):
        self._forward = forward
        self.solve_s = 0.0
        self.jacobian_s = 0.0

    def __getattr__(self, name):
        return getattr(self._forward, name)

    def voltages(self, sigma):
        t = time.perf_counter()
        out = self._forward.voltages(sigma)
        self.solve_s += time.perf_counter() - t
        return out

    def jacobian_basis(self, sigma):
        t = time.perf_counter()
        out = self._forward.jacobian_basis(sigma)
        self.jacobian_s += time.perf_counter() - t
        return out


def gn_case(fwd, large, v0):
    """Gauss-Newton timings and outcome on one forward mesh, NOSER and Laplace priors."""
    pmesh = disk_mesh(R, h_m=GN_PARAMETER_H)
    out = []
    for kind in ("noser", "laplace"):
        full_prior = kind if kind == "noser" else make_prior(kind, fwd.mesh)
        one_off = median_time(
            lambda p=full_prior: GaussNewtonSolver(fwd, 1.0, p, 0.01).difference(
                large, v0, options=FitOptions(max_iterations=5, tolerance=0.0)
            ),
            GN_REPEATS,
        )
        timed = TimedForward(fwd)
        t = time.perf_counter()
        solver = GaussNewtonSolver(timed, 1.0, kind, 0.01, parameter_mesh=pmesh)
        setup = time.perf_counter() - t
        runs = []
        for _ in range(GN_REPEATS):
            timed.solve_s = timed.jacobian_s = 0.0
            t, c = time.perf_counter(), time.process_time()
            gn = solver.difference(large, v0, options=FitOptions(max_iterations=5, tolerance=0.0))
            runs.append(
                (time.perf_counter() - t, time.process_time() - c, timed.solve_s, timed.jacobian_s)
            )
        runs.sort()
        wall, cpu, solve, jac = runs[len(runs) // 2]
        cpu = float(np.median([r[1] for r in runs]))
        k = int(np.argmax(gn.parameter_change))
        r = gn.relative_residuals
        out.append(
            {
                "prior": kind,
                "forward": fwd.mesh.n_triangles,
                "parameters": pmesh.n_triangles,
                "one_off_ms": one_off * 1e3,
                "setup_ms": setup * 1e3,
                "wall_ms": wall * 1e3,
                "cpu_ms": cpu * 1e3,
                "solve_ms": solve * 1e3 / gn.iterations,
                "jacobian_ms": jac * 1e3 / gn.iterations,
                "rest_ms": (wall - solve - jac) * 1e3 / gn.iterations,
                "iterations": gn.iterations,
                "forward_solves": gn.forward_solves,
                "residual": float(r[-1] / r[0]),
                "peak": float(gn.parameter_change[k]),
                "location": float(np.linalg.norm(pmesh.centroids[k] - GN_TARGET) / R),
            }
        )
        print(out[-1], flush=True)
    return out


def gn_section(gn_rows) -> list[str]:
    """Markdown lines of the Gauss-Newton section of the report."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "## Gauss-Newton",
        "",
        f"5 iterations (tolerance 0, h = 0.01) on a x20, 0.2 R target at (-0.3, 0.4) R; "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; median of "
        f"{GN_REPEATS} runs; 1-min load average {load:.1f} on {os.cpu_count()} cores at the "
        "end of the run (this benchmark included; wall times grow with other load, CPU time "
        "less so). One-off: a `GaussNewtonSolver` built per call with the unknowns on the "
        "forward mesh (builds everything per call). Solver: `GaussNewtonSolver` built once "
        "(setup column), unknowns on the coarse parameter mesh, then `difference()` per frame; "
        "the per-iteration split is wall time of the forward solves (factorisation + "
        "potentials, one per iteration when the full step is accepted), of the Jacobian "
        "(field-pair products, reused factorisation) and of everything else (sparse/dense "
        "linear algebra of the dual step, line search bookkeeping). Location: distance of the "
        "largest parameter from the target centre.",
        "",
        "| forward triangles | parameter triangles | prior | one-off ms | solver setup ms "
        "| per frame ms (wall) | per frame ms (CPU) | per iteration: forward solve / Jacobian "
        "/ rest ms | iterations (forward solves) | residual r5/r0 | peak x | location / R |",
        "|" + "---|" * 12,
    ]
    for g in gn_rows:
        lines.append(
            f"| {g['forward']} | {g['parameters']} | {g['prior']} | {g['one_off_ms']:.0f} | "
            f"{g['setup_ms']:.0f} | {g['wall_ms']:.1f} | {g['cpu_ms']:.1f} | "
            f"{g['solve_ms']:.1f} / {g['jacobian_ms']:.1f} / {g['rest_ms']:.1f} | "
            f"{g['iterations']} ({g['forward_solves']}) | {g['residual']:.4f} | "
            f"{g['peak']:.1f} | {g['location']:.3f} |"
        )
    return lines


def replace_section(report: Path, section: list[str]) -> None:
    """Rewrite only the section headed ``section[0]`` of an existing report (or add it)."""
    text = report.read_text() if report.exists() else "# Reconstruction benchmark\n"
    lines = text.split("\n")
    section = [*section, ""]
    if section[0] in lines:
        a = lines.index(section[0])
        b = next(
            (i for i in range(a + 1, len(lines)) if lines[i].startswith(("## ", "!["))), len(lines)
        )
        lines[a:b] = section
    else:
        at = next((i for i, x in enumerate(lines) if x.startswith("![")), len(lines))
        lines[at:at] = section
    report.write_text("\n".join(lines))


def pin_to_one_core() -> int:
    """Pin this process to one of its allowed CPUs (the least loaded is unknown: the last)."""
    cpu = max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu


def gn_node_case(patch_name: str, rate_hz: float) -> list[dict]:
    """Every layer of a shipped patch switched to gauss_newton, imaged frame by frame.

    The node's path: ``LayerImager.build`` (no cache), then ``relative_change(frame,
    reference, flags)`` for every frame of the simulator's demo scenario (touches, holds,
    quiet frames, drift, ADC noise), with the simulator's pre-touch reference.
    """
    patch = load_patch(config_path(patch_name))
    rec = SkinSimulator(patch, "demo", rate_hz=rate_hz, seed=0).run()
    rows = []
    for layer in patch.layers:
        t, c = time.perf_counter(), time.process_time()
        imager = LayerImager.build(with_method(layer, "gauss_newton"), cache_dir=None)
        setup = (time.perf_counter() - t, time.process_time() - c)
        solver = imager.reconstructor.solver
        fit, iterations = solver.difference, []

        def counted(*a, fit=fit, iterations=iterations, **k):
            out = fit(*a, **k)
            iterations.append((out.iterations, out.forward_solves))
            return out

        solver.difference = counted
        lr = rec.layers[layer.name]
        wall, cpu = [], []
        for frame, flags in zip(lr.frames, lr.flags, strict=True):
            t, c = time.perf_counter(), time.process_time()
            imager.relative_change(frame, lr.reference, flags)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        it, solves = np.array(iterations).T
        rows.append(
            {
                "patch": patch_name,
                "layer": layer.name,
                "forward": solver.forward.mesh.n_triangles,
                "parameters": imager.mesh.n_triangles,
                "h": imager.reconstructor.hyperparameter,
                "max_iterations": imager.reconstructor.max_iterations,
                "frames": len(wall),
                "setup_s": setup,
                "wall_s": float(np.sum(wall)),
                "cpu_s": float(np.sum(cpu)),
                "median_ms": float(np.median(wall)) * 1e3,
                "p95_ms": float(np.quantile(wall, 0.95)) * 1e3,
                "iterations": float(it.mean()),
                "full": float(np.mean(it == imager.reconstructor.max_iterations)),
                "solves": float(solves.mean()),
            }
        )
        print(rows[-1], flush=True)
    return rows


def gn_node_section(rows, cpu: int | None, rate_hz: float) -> list[str]:
    """Markdown lines of the Gauss-Newton-in-the-node section of the report."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "## Gauss-Newton in the node",
        "",
        "Sustained rate of the reconstruction node's per-frame path with every layer of the "
        "shipped patches switched to `method: gauss_newton` (`pipeline.builder.with_method`: "
        "Laplace prior, `h` chosen for the method's default noise figure on the first "
        "linearised step, `max_iterations` 5, tolerance 1e-3 of the measured change): "
        "`LayerImager.relative_change(frame, reference, flags)` for every frame of the "
        f"simulator's demo scenario at {rate_hz:g} Hz (touches, holds, quiet frames, drift, "
        "ADC noise; pre-touch reference), one call per frame as the node makes it. "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, process "
        f"pinned to CPU {cpu}; 1-min load average {load:.1f} on {os.cpu_count()} cores at the "
        "end (this benchmark included; other jobs shared the machine, so wall time is an upper "
        "bound and CPU time the better figure). Per patch: frames of every layer imaged in "
        "turn on the one core, `frames / sum of the layers' total time`. Not included: "
        "reference tracking, conversion to images and publishing (one-step-sized costs). "
        "Command: `OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_reconstruction "
        "--gn-node`.",
        "",
        "| patch | layer | forward triangles | parameter triangles | h | frames | setup s "
        "(wall / CPU) | per frame ms: median / p95 (wall) | mean iterations (share at max) "
        "| mean forward solves | layer frames/s (wall) | layer frames/s (CPU) |",
        "|" + "---|" * 12,
    ]
    for r in rows:
        lines.append(
            f"| {r['patch']} | {r['layer']} | {r['forward']} | {r['parameters']} | "
            f"{r['h']:.4g} | {r['frames']} | {r['setup_s'][0]:.2f} / {r['setup_s'][1]:.2f} | "
            f"{r['median_ms']:.1f} / {r['p95_ms']:.1f} | {r['iterations']:.2f} "
            f"({r['full']:.0%}) | {r['solves']:.2f} | {r['frames'] / r['wall_s']:.1f} | "
            f"{r['frames'] / r['cpu_s']:.1f} |"
        )
    lines += [
        "",
        "| patch | layers | patch frames/s (wall) | patch frames/s (CPU) |",
        "|---|---|---|---|",
    ]
    for patch in dict.fromkeys(r["patch"] for r in rows):
        mine = [r for r in rows if r["patch"] == patch]
        n = mine[0]["frames"]
        lines.append(
            f"| {patch} | {len(mine)} | {n / sum(r['wall_s'] for r in mine):.1f} | "
            f"{n / sum(r['cpu_s'] for r in mine):.1f} |"
        )
    return lines


def gn_node_rows(rate_hz: float) -> tuple[list[dict], int]:
    """``(rows, cpu)``: :func:`gn_node_case` of every shipped patch, pinned to one core."""
    allowed = os.sched_getaffinity(0)
    cpu = pin_to_one_core()
    try:
        rows = [row for name in GN_NODE_PATCHES for row in gn_node_case(name, rate_hz)]
    finally:
        os.sched_setaffinity(0, allowed)
    return rows, cpu


def moving_press(fine, v0, frames: int, rate_hz: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(centre m, frame [M] V)`` of a press at ``rate_hz`` on the data mesh, 1 % noise.

    A 0.2 R disk is pressed in over 0.1 s (conductance x1 -> x20) while it slides 0.5 R in
    0.4 s (a finger at ~6 cm/s on a 5 cm sheet) from (-0.3, 0.4) R.
    """
    rng = np.random.default_rng(5)
    out = []
    for k in range(frames):
        t = (k + 1) / rate_hz  # the first frame already shows the press
        c = (np.array([-0.3, 0.4]) + np.array([0.45, -0.2]) * t / 0.4) * R
        sig = np.ones(fine.mesh.n_triangles)
        sig[np.linalg.norm(fine.mesh.centroids - c, axis=1) < 0.2 * R] = 1 + 19 * min(1, t / 0.1)
        v = fine.voltages(sig)
        out.append((c, v + rng.normal(0, 0.01 * np.sqrt(np.mean((v - v0) ** 2)), v.size)))
    return out


def peak_and_centre(x: np.ndarray, mesh) -> tuple[float, np.ndarray]:
    """Largest value and the area-weighted centre of gravity (m) of the quarter-max set."""
    big = x >= 0.25 * x.max()
    w = x[big] * mesh.areas[big]
    return float(x.max()), (mesh.centroids[big] * w[:, None]).sum(axis=0) / w.sum()


def online_gn_case(fwd, press, v0) -> list[dict]:
    """Accuracy per millisecond of Gauss-Newton variants on the press sequence, one mesh.

    The reconstructor's own solver (Laplace prior, ``h`` for the default noise figure,
    416-triangle parameter mesh) runs every configuration of :data:`ONLINE_CONFIGS` over
    the sequence; errors are against five cold iterations on the same frame: peak (relative)
    and quarter-max centre (fraction of R), the max over the frames.
    """
    pmesh = disk_mesh(R, h_m=GN_PARAMETER_H)
    rec = GaussNewtonReconstructor.build(fwd, 1.0, "laplace", parameter_mesh=pmesh)
    solver = rec.solver
    frames = [v for _, v in press]
    ref = [
        solver.difference(v, v0, options=FitOptions(max_iterations=5)).parameter_change
        for v in frames
    ]
    ref_pc = [peak_and_centre(x, pmesh) for x in ref]
    out = []
    for label, warm_on, step_tol, relin, iters in ONLINE_CONFIGS:
        stats = []
        for _ in range(3):  # the first pass warms caches; median of the per-frame times
            warm = WarmStart() if warm_on else None
            wall, cpu, res = [], [], []
            for v in frames:
                t, c = time.perf_counter(), time.process_time()
                options = FitOptions(iters, step_tolerance=step_tol, relinearise=relin)
                r = solver.difference(v, v0, None, options, warm)
                wall.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
                res.append(r)
            stats.append((np.array(wall), np.array(cpu), res))
        wall = np.median([w for w, _, _ in stats[1:]], axis=0)
        cpu = np.median([c for _, c, _ in stats[1:]], axis=0)
        res = stats[-1][2]
        pe, ce = [], []
        for r, (peak, centre) in zip(res, ref_pc, strict=True):
            p, c = peak_and_centre(r.parameter_change, pmesh)
            pe.append(abs(p / peak - 1))
            ce.append(float(np.linalg.norm(c - centre)) / R)
        out.append(
            {
                "forward": fwd.mesh.n_triangles,
                "parameters": pmesh.n_triangles,
                "label": label,
                "mean_ms": float(wall.mean()) * 1e3,
                "median_ms": float(np.median(wall)) * 1e3,
                "p95_ms": float(np.quantile(wall, 0.95)) * 1e3,
                "cpu_ms": float(cpu.mean()) * 1e3,
                "peak_error": float(max(pe)),
                "centre_error": float(max(ce)),
                "solves": float(np.mean([r.forward_solves for r in res])),
                "linearisations": float(np.mean([r.linearisations for r in res])),
                "default": "(default)" in label,
            }
        )
        print(out[-1], flush=True)
    return out


def online_section(rows) -> list[str]:
    """Markdown lines of the online Gauss-Newton section (accuracy per millisecond)."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "## Online Gauss-Newton: accuracy per millisecond",
        "",
        f"A press sequence at {ONLINE_RATE_HZ:g} Hz ({ONLINE_FRAMES} frames: a 0.2 R disk "
        "pressed in over 0.1 s to x20 while it slides 0.5 R in 0.4 s, 1 % noise, data mesh as "
        "above) imaged frame by frame by `GaussNewtonSolver.difference` of the reconstructor "
        "(`GaussNewtonReconstructor.build`: Laplace prior, `h` for the default noise figure "
        "0.3, 416-triangle parameter mesh) in each configuration. Errors are against five cold "
        "Gauss-Newton iterations on the same frame (what the reconstructor did per frame "
        "before): peak = relative error of the largest value, centre = distance of the "
        "quarter-max centre of gravity, fraction of R; max over the frames. Times per frame, "
        "wall (mean / median / p95) and CPU (mean), median of two passes; solves = forward "
        "factorisations, linearisations = Jacobians + normal matrices per frame (the one at "
        f"sigma0 is precomputed). OPENBLAS_NUM_THREADS="
        f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; 1-min load average {load:.1f} "
        f"on {os.cpu_count()} cores when written (loaded: other jobs shared the machine, wall "
        "times are upper bounds). The reconstructor's default (warm start, step test 0.01, "
        "linearisation kept within |d ln sigma| <= 0.5) is marked.",
        "",
        "| forward triangles | configuration | ms/frame wall: mean / median / p95 | CPU ms "
        "| max peak error | max centre error / R | solves | linearisations |",
        "|" + "---|" * 8,
    ]
    for r in rows:
        lines.append(
            f"| {r['forward']} | {r['label']} | {r['mean_ms']:.1f} / {r['median_ms']:.1f} / "
            f"{r['p95_ms']:.1f} | {r['cpu_ms']:.1f} | {r['peak_error']:.3f} | "
            f"{r['centre_error']:.3f} | {r['solves']:.2f} | {r['linearisations']:.2f} |"
        )
    return lines


def large_contrast_case(fine):
    """Voltages ``[M]`` of the x20, 0.2 R target on the data mesh."""
    sig = np.ones(fine.mesh.n_triangles)
    sig[np.linalg.norm(fine.mesh.centroids - GN_TARGET, axis=1) < 0.2 * R] = 20.0
    return fine.voltages(sig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="three small meshes, short sweep")
    ap.add_argument("--no-pyeit-above", type=int, default=10**9, help="skip pyEIT above N")
    ap.add_argument("--gn-only", action="store_true", help="only the Gauss-Newton section")
    ap.add_argument(
        "--gn-node", action="store_true", help="only the Gauss-Newton-in-the-node section"
    )
    ap.add_argument(
        "--online-only", action="store_true", help="only the online Gauss-Newton section"
    )
    ap.add_argument("--json", type=Path, help="also write the per-mesh rows to this JSON file")
    ap.add_argument(
        "--frame-only",
        action="store_true",
        help="only the per-mesh frame table (no Gauss-Newton, sweep or plot): rewrites that "
        "section of reconstruction.md",
    )
    args = ap.parse_args()
    if args.gn_node:
        rows, cpu = gn_node_rows(GN_NODE_RATE_HZ)
        replace_section(OUT / "reconstruction.md", gn_node_section(rows, cpu, GN_NODE_RATE_HZ))
        return
    protocol = build_protocol(ProtocolSpec(), 16)
    fine = ForwardModel(disk_mesh(R, h_m=0.0012), protocol, 1e-4)
    v0 = fine.voltages(1.0)
    large = large_contrast_case(fine)
    sizes = SIZES[:3] if args.quick else SIZES
    if args.online_only:
        press = moving_press(fine, v0, ONLINE_FRAMES, ONLINE_RATE_HZ)
        online = []
        for h in sizes:
            online += online_gn_case(ForwardModel(disk_mesh(R, h_m=h), protocol, 1e-4), press, v0)
        replace_section(OUT / "reconstruction.md", online_section(online))
        return
    if args.gn_only:
        gn_rows = []
        for h in SIZES[:3] if args.quick else SIZES:
            gn_rows += gn_case(ForwardModel(disk_mesh(R, h_m=h), protocol, 1e-4), large, v0)
        replace_section(OUT / "reconstruction.md", gn_section(gn_rows))
        return
    centres = disc_centres(R)
    sim = simulate_discs(fine, centres, 0.05 * R, 2.0, 0.01, np.random.default_rng(0))
    frames = sim.frames
    phantoms = list(zip(centres, frames, strict=True))
    print(f"data mesh {fine.mesh.n_triangles} triangles, {len(phantoms)} phantoms", flush=True)
    bandwidth = copy_bandwidth()
    print(f"copy bandwidth {bandwidth / 1e9:.1f} GB/s", flush=True)
    press = moving_press(fine, v0, ONLINE_FRAMES, ONLINE_RATE_HZ)
    rows, gn_rows, online, records = [], [], [], []
    for h in sizes:
        mesh = disk_mesh(R, h_m=h)
        grid = ImageGrid.build(mesh, 64)
        g = greit_case(mesh, protocol, frames, v0, phantoms, grid, bandwidth)
        fwd, build, frame_t, batch_t, ours = (
            g["forward"],
            g["build_s"],
            g["frame_s"],
            g["batched_s"],
            g["merit"],
        )
        t = time.perf_counter()
        fwd_l = ForwardModel(mesh, protocol, 1e-4)
        rm_l = ReconstructionMatrix.build(fwd_l, prior="laplace", noise_figure=NOISE_FIGURE)
        build_l = time.perf_counter() - t
        lap = merit(grid, rm_l.reconstruct(frames, v0), phantoms)
        if args.frame_only:
            gn_ms, on = [(float("nan"), 0)] * 2, []
        else:
            gn = gn_case(fwd, large, v0)
            gn_rows += gn
            gn_ms = [(g["wall_ms"], g["iterations"]) for g in gn]  # reusable solver, per frame
            on = online_gn_case(fwd, press, v0)
            online += on
        if mesh.n_triangles <= args.no_pyeit_above:
            py_build, py_frame, py_image, py, py_fn = pyeit_case(
                mesh, protocol, frames, v0, phantoms, grid
            )
            # the ratio from interleaved calls (ours, pyEIT's, ours, ...): same load on both
            rm = g["matrix"]
            one = frame_to_image(rm, grid, v0)[0]
            frame_t, py_image = interleaved_medians([lambda one=one: one(frames[0]), py_fn], 200)
        else:
            py_build, py_frame, py_image, py = None, None, None, (None,) * 4
        records.append(
            json_row(
                triangles=mesh.n_triangles,
                build_s=build,
                frame_ms=frame_t * 1e3,
                batched_frame_ms=batch_t * 1e3,
                gn_frame_ms=next((r["mean_ms"] for r in on if r["default"]), None),
                max_pe_r=ours[0],
                pyeit_build_s=py_build,
                pyeit_frame_ms=None if py_image is None else py_image * 1e3,
                pyeit_max_pe_r=py[0],
            )
        )
        nan = float("nan")
        py_build = nan if py_build is None else py_build
        py_frame = nan if py_frame is None else py_frame
        py_image = nan if py_image is None else py_image
        py = tuple(nan if x is None else x for x in py)
        row = (mesh.n_triangles, build, frame_t * 1e3, batch_t * 1e3, gn_ms[0][0], gn_ms[0][1])
        row += (*ours, py_build, py_frame * 1000.0, *py, build_l, *lap, *gn_ms[1])
        row += (g["element_frame_s"] * 1e3, g["element_batched_s"] * 1e3, g["image_error"])
        row += (py_image * 1e3, g["frame_floor_s"] * 1e3, g["batched_floor_s"] * 1e3)
        rows.append(row)
        print("  ".join(f"{x:.4g}" for x in row), flush=True)
    if args.frame_only:
        if args.json is not None:
            write_json(args.json, records)
        replace_section(
            OUT / "reconstruction.md",
            frame_section(rows, args.quick, fine.mesh.n_triangles, bandwidth, frame_only=True),
        )
        return
    sweep = []
    fwd = ForwardModel(disk_mesh(R, h_m=0.0023), protocol, 1e-4)
    for h in SWEEP[:3] if args.quick else SWEEP:
        inv = disk_mesh(R, h_m=h)
        grid = ImageGrid.build(inv, 64)
        t = time.perf_counter()
        rm = greit_matrix(
            imaging_jacobian(fwd, inverse_mesh=inv), inv, noise_figure=GREIT_NOISE_FIGURE
        )
        build = time.perf_counter() - t
        row = (h / R, inv.n_triangles, build, *merit(grid, rm.reconstruct(frames, v0), phantoms))
        sweep.append(row)
        print("sweep", "  ".join(f"{x:.4g}" for x in row), flush=True)
    if args.json is not None:
        write_json(args.json, records)
    node = (*gn_node_rows(GN_NODE_RATE_HZ), GN_NODE_RATE_HZ)
    write_report(
        rows,
        sweep,
        gn_rows,
        online,
        node,
        fwd.mesh.n_triangles,
        fine.mesh.n_triangles,
        args.quick,
        bandwidth,
    )


#: Keys of one ``--json`` row: times in s / ms, position error as a fraction of R; null
#: where not measured (pyEIT skipped above ``--no-pyeit-above``). ``frame_ms`` and
#: ``pyeit_frame_ms`` are both frame -> image (the same pixel image, unit and mask).
JSON_KEYS = (
    "triangles",
    "build_s",
    "frame_ms",
    "batched_frame_ms",
    "gn_frame_ms",
    "max_pe_r",
    "pyeit_build_s",
    "pyeit_frame_ms",
    "pyeit_max_pe_r",
)


def json_row(**values: float | int | None) -> dict:
    """One mesh's row with exactly :data:`JSON_KEYS`; NaN and missing values become null.

    ``triangles`` is an int, every other value a float or None.
    """
    unknown = set(values) - set(JSON_KEYS)
    if unknown:
        raise ValueError(f"unknown JSON keys {sorted(unknown)}")
    row: dict = {}
    for key in JSON_KEYS:
        v = values.get(key)
        if v is None or not np.isfinite(v):
            row[key] = None
        else:
            row[key] = int(v) if key == "triangles" else float(v)
    return row


def write_json(path: Path, rows: list[dict]) -> None:
    """Write the rows (:func:`json_row`) to ``path`` as one strict JSON list."""
    import json

    Path(path).write_text(json.dumps(rows, indent=1, allow_nan=False) + "\n")


def frame_section(
    rows, quick: bool, data_n: int, bandwidth: float, frame_only: bool = False
) -> list[str]:
    """The report's first section: machine, method and the per-mesh frame table."""
    only = " (this section only; the sections below are from an earlier run)"
    flags = "".join(f" {a}" for a in sys.argv[1:] if a.startswith("--") and a != "--json")
    lines = [
        "# Reconstruction benchmark",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"1-min load average {os.getloadavg()[0]:.1f} when written (includes this run"
        f"{'; LOADED: shared with other jobs, times are upper bounds' if loaded() else ''}), "
        f"Python {platform.python_version()}, numpy "
        f"{np.__version__}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}"
        f". Mode: {'--quick' if quick else 'full'}. Command: `OPENBLAS_NUM_THREADS=1 "
        f".venv/bin/python -m bench.standing.bench_reconstruction{flags}`"
        f"{only if frame_only else ''}"
        f", {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.",
        "",
        f"Data simulated on a {data_n}-triangle mesh (never a reconstruction mesh), 1 % noise; "
        "30 targets (radius 5 % R, conductivity x2) at 0..0.9 R. eit_skin: GREIT-trained "
        f"matrix (`method: greit`), noise figure {GREIT_NOISE_FIGURE} (build/frame/PE/RES/RNG/SD "
        f"columns); Laplace prior at noise figure {NOISE_FIGURE} for comparison; "
        "pyEIT 1.2.4 JAC: kotre, p = 0.5, lambda = 0.01, "
        "normalized Jacobian and data, same mesh, point electrodes at the electrodes' middle "
        "nodes. Build: once per mesh (includes the forward model and Jacobian for both). Frame: "
        "median of 50 (30 for pyEIT's element frame) single-frame calls; frame->image, ours and "
        "pyEIT's: median of 200 interleaved calls (ours, pyEIT's, ours, ...) so that the "
        "machine's load weighs on both alike; batched: 30 frames in one call, "
        "median of 10, per frame. Frame->image, both sides: one frame of volts and the "
        "reference in, a new float32 64 x 64 image out, with a unit factor, the pipeline's "
        "clip and NaN outside the sheet; ours: the node's planned step (`FramePlan`, the "
        "compiled kernel: `(v - ref) / s_ref` with the reciprocal channels merged, 208 -> 104 "
        "inputs, one float32 `sgemv`, clip, unit, one gather); pyEIT's: its "
        "`solve(v, v0, normalize=True)` (`(v - v0) / |v0|`, `-H dv`), the unit and the clip "
        "in place on its float64 element values, then `ImageGrid.to_image` (one casting copy "
        "into a NaN-padded float32 row and the same gather onto the same pixels), i.e. the "
        "same output as ours; element frame: volts to element values only (`reconstruct`, "
        "what pyEIT's `solve` gives); float32 image error: max deviation from the float64 "
        "chain over max |image|; frame / pyEIT: our frame->image time over pyEIT's "
        "frame->image time. Our matrix is float32, column-major, [N, 104]; pyEIT's float64, "
        "row-major, [N, 208]. Gauss-Newton: see its sections below. "
        "PE = GREIT position error (max over targets, fraction of R); RES = GREIT resolution "
        "(mean); RNG = GREIT ringing (EIDORS definition, mean); SD = shape deformation (max). "
        f"Memory floor: the least time to move one frame's bytes at this core's copy bandwidth "
        f"({bandwidth / 1e9:.1f} GB/s, `np.copyto` of 64 MiB): the merged float32 matrix "
        "(read once per call: per frame single, over 30 frames batched), the float64 frame "
        "in and the float32 image out; x floor = measured time over that floor.",
        "",
        "| triangles | build s | frame->image ms | batched image ms/frame | frame / pyEIT "
        "| element frame ms | batched element ms/frame | float32 image error | max PE | RES "
        "| RNG | SD | Laplace build s | Laplace PE | Laplace RES | Laplace RNG | pyEIT build s "
        "| pyEIT frame ms | pyEIT frame->image ms | pyEIT max PE | pyEIT RES | pyEIT RNG "
        "| pyEIT SD | memory floor: frame / batched µs | x floor: frame / batched |",
        "|" + "---|" * 25,
    ]
    for r in rows:
        lines.append(
            f"| {r[0]} | {r[1]:.3f} | {r[2]:.3f} | {r[3]:.4f} | {r[2] / r[26]:.2f} | "
            f"{r[23]:.3f} | {r[24]:.4f} | {r[25]:.1e} | {r[6]:.4f} | {r[7]:.3f} | "
            f"{r[8]:.2f} | {r[9]:.2f} | {r[16]:.3f} | {r[17]:.4f} | {r[18]:.3f} | {r[19]:.2f} | "
            f"{r[10]:.2f} | {r[11]:.3f} | {r[26]:.3f} | {r[12]:.4f} | {r[13]:.3f} | {r[14]:.2f} | "
            f"{r[15]:.2f} | {r[27] * 1e3:.1f} / {r[28] * 1e3:.1f} | "
            f"{r[2] / r[27]:.1f} / {r[3] / r[28]:.1f} |"
        )
    return lines


def write_report(rows, sweep, gn_rows, online, node, sweep_fwd, data_n, quick, bandwidth):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.array(rows, dtype=float)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    ax[0].loglog(a[:, 0], a[:, 1], "o-", label="eit_skin build")
    ax[0].loglog(a[:, 0], a[:, 10], "s-", label="pyEIT JAC build")
    ax[0].loglog(a[:, 0], a[:, 4] / 1e3, "^-", label="eit_skin 5 GN iterations (NOSER, solver)")
    ax[0].loglog(a[:, 0], a[:, 2] / 1e3, "o:", label="eit_skin frame->image")
    ax[0].loglog(a[:, 0], a[:, 26] / 1e3, "s:", label="pyEIT frame->image")
    ax[0].set_xlabel("triangles")
    ax[0].set_ylabel("seconds")
    ax[0].legend(fontsize=8)
    ax[1].plot(a[:, 1], a[:, 6] * 100, "o-", label="eit_skin max PE")
    ax[1].plot(a[:, 10], a[:, 12] * 100, "s-", label="pyEIT max PE")
    ax[1].plot(a[:, 1], a[:, 7] * 100, "o--", label="eit_skin mean RES")
    ax[1].plot(a[:, 10], a[:, 13] * 100, "s--", label="pyEIT mean RES")
    ax[1].set_xscale("log")
    ax[1].set_xlabel("build time, s")
    ax[1].set_ylabel("% R (PE), % (RES)")
    ax[1].legend(fontsize=8)
    s = np.array(sweep, dtype=float)
    ax[2].plot(s[:, 1], s[:, 3] * 100, "o-", label="max PE, % R")
    ax[2].plot(s[:, 1], s[:, 4] * 100, "s-", label="mean RES, %")
    ax[2].axhline(2.0, color="k", lw=0.5)
    ax[2].set_xscale("log")
    ax[2].set_xlabel(f"inverse-mesh triangles (forward mesh {sweep_fwd})")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "reconstruction.png", dpi=90)
    lines = frame_section(rows, quick, data_n, bandwidth)
    lines += [
        "",
        f"## Inverse-mesh sweep (forward mesh {sweep_fwd} triangles, same data)",
        "",
        "| inverse h / R | inverse triangles | build s | max PE | RES | RNG | SD |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sweep:
        lines.append(
            f"| {r[0]:.3f} | {r[1]} | {r[2]:.3f} | {r[3]:.4f} | {r[4]:.3f} | {r[5]:.2f} | "
            f"{r[6]:.2f} |"
        )
    lines += ["", *gn_section(gn_rows), "", *online_section(online), "", *gn_node_section(*node)]
    lines += ["", "![speed and error](reconstruction.png)", ""]
    (OUT / "reconstruction.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
