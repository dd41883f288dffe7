"""Model only what a scene needs: the coarsest model that meets a layer's accuracy target.

A layer may give ``solver.accuracy_target`` (:class:`~eit_skin.patch.model.AccuracyTarget`:
position error in percent of the sheet's equivalent radius ``R = sqrt(area / pi)``, and
optionally amplitude error) instead of mesh sizes. :func:`choose_model` walks a fixed
ladder of candidate models from coarse to fine, builds each exactly as the reconstruction
builds a layer (the ``build`` callable: :meth:`~eit_skin.pipeline.builder.LayerImager.build`),
images the package's own simulated phantom set with it and keeps the first candidate that
meets the target with a margin. The choice and every tried rung are cached as JSON keyed by
the layer's content hash, so the reconstruction node, the offline commands and ``eit-skin
tune`` share one chosen model (docs/reconstruction.md, *Accuracy target*).

The ladder (all lengths scale with ``R``, so the rule is the same for any sheet):

* forward mesh edge ``FORWARD_EDGES_R * R``, coarse to fine (each rung about doubles the
  triangle count), electrode edge ``ELECTRODE_EDGE_FRACTION`` of it (at least the loader's
  default, a quarter of the narrowest electrode);
* the inverse (imaging) mesh is the forward mesh: an inverse mesh twice as coarse as the
  forward one (the Jacobian mapped onto it) was measured worse than the forward mesh alone
  at every rung, and a forward mesh twice as fine as the inverse one did not help either
  (docs/reconstruction.md, *Accuracy target*);
* at each mesh, image pixels for a pitch of ``1 / PIXELS_PER_EDGE`` of the mesh edge along
  the outline's long side, fewest first (at least ``MIN_PIXELS``): the pixel count moves the
  position error as much as the mesh does;
* ``gauss_newton`` only: at each mesh and pixel count, ``max_iterations`` from
  ``ITERATIONS``, fewest first (higher caps are skipped once raising the cap did not lower a
  targeted figure).

Phantom set: discs of radius ``TARGET_RADIUS_R * R``, conductance x
``TARGET_CONTRAST``, centres in the sheet (not in a hole; a target may overlap holes, as
``eit-skin tune``'s do: a hole grid leaves no room otherwise) and at least ``EDGE_CLEARANCE``
target radii from the outline, simulated on a data mesh finer than every candidate (edge
``DATA_EDGE_FRACTION`` of the finest forward edge, at most ``DATA_EDGE_PER_TARGET_RADIUS``
target radii: no inverse crime), white noise of ``NOISE`` x the RMS difference signal.
Selection: centres on a hexagonal lattice of about ``SELECTION_LATTICE`` points over the sheet
(those clear of the outline) plus a ring at the clearance inside the outline with the
lattice's pitch (near the outline the error is largest and a lattice samples it least),
noise seed :data:`SELECTION_SEED`; a held-out set
(:func:`phantom_set` with ``held_out=True``) draws ``HELD_OUT_PHANTOMS`` random centres and
noise with another seed, for checking a choice.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.fem.image_grid import locate_points
from eit_skin.fem.mesh import build_mesh
from eit_skin.fem.phantoms import DiscPhantoms, simulate_discs
from eit_skin.inverse.figures_of_merit import figures_of_merit
from eit_skin.inverse.greit import target_centres
from eit_skin.patch import geometry
from eit_skin.patch.mesh_budget import estimate_cost
from eit_skin.patch.model import AccuracyTarget, Layer, MeshSpec, PatchError

#: Bumped whenever the ladder, the phantom set or the rule changes (stale choices rebuild).
SELECTOR_VERSION = "2"
#: Forward mesh edges, fractions of the equivalent radius R, coarse to fine.
FORWARD_EDGES_R = (0.3, 0.21, 0.15, 0.106, 0.075, 0.053)
#: Electrode edge: this fraction of the forward edge, but no finer than the loader's default
#: (a quarter of the narrowest electrode) and no coarser than the forward edge.
ELECTRODE_EDGE_FRACTION = 0.25
#: Pixels per mesh edge along the long side of the outline, fewest first; fewest pixels.
PIXELS_PER_EDGE = (2.0, 4.0)
MIN_PIXELS = 16
#: Gauss-Newton iteration caps tried at each mesh and pixel count, fewest first.
ITERATIONS = (1, 2, 3, 5)
#: A candidate is chosen when its errors are at most this fraction of the target (the margin
#: covers another noise draw and other target positions: the held-out check).
SELECTION_MARGIN = 0.9
SELECTION_LATTICE = 48
HELD_OUT_PHANTOMS = 24
TARGET_RADIUS_R = 0.10
TARGET_CONTRAST = 2.0
NOISE = 0.01
EDGE_CLEARANCE = 1.5
DATA_EDGE_FRACTION = 0.7
DATA_EDGE_PER_TARGET_RADIUS = 0.4
SELECTION_SEED = 0
HELD_OUT_SEED = 1
#: Timed frames per candidate (median), for the reported frame cost only.
FRAME_REPEATS = 5

Build = Callable[[Layer], Any]
"""Layer (no target) -> its imager, built as the reconstruction builds it (no cache)."""
Simulate = Callable[[Layer, Any], Any]
"""(layer, mesh) -> the layer's forward model on that mesh (the simulator's physics)."""


@dataclass(frozen=True)
class Candidate:
    """One rung of the ladder.

    Attributes:
        forward_edge_m: forward mesh ``max_edge``, m.
        inverse_edge_m: inverse (imaging) mesh edge, m (equal to the forward edge: one mesh).
        image_pixels: pixels along the long side of the image.
        max_iterations: Gauss-Newton iteration cap, or ``None`` for a linear method.
    """

    forward_edge_m: float
    inverse_edge_m: float
    image_pixels: int
    max_iterations: int | None = None

    def layer(self, layer: Layer) -> Layer:
        """``layer`` with this candidate's sizes and no target (an explicit layer)."""
        width = min(e.width_m for e in layer.electrodes)
        same = self.inverse_edge_m == self.forward_edge_m
        electrode = max(width / 4.0, ELECTRODE_EDGE_FRACTION * self.forward_edge_m)
        mesh = MeshSpec(
            self.forward_edge_m,
            min(self.forward_edge_m, electrode),
            layer.mesh.min_angle_deg,
            None if same else self.inverse_edge_m,
        )
        solver = replace(layer.solver, accuracy_target=None, image_pixels=self.image_pixels)
        if self.max_iterations is not None:
            solver = replace(solver, max_iterations=self.max_iterations)
        return replace(layer, mesh=mesh, solver=solver)

    def describe(self) -> str:
        if self.inverse_edge_m == self.forward_edge_m:
            text = f"mesh {self.forward_edge_m * 1e3:.3g} mm, {self.image_pixels} px"
        else:
            text = (
                f"forward {self.forward_edge_m * 1e3:.3g} mm, inverse "
                f"{self.inverse_edge_m * 1e3:.3g} mm, {self.image_pixels} px"
            )
        return text if self.max_iterations is None else f"{text}, {self.max_iterations} it"


@dataclass(frozen=True)
class Evaluation:
    """A candidate measured on the phantom set.

    Attributes:
        candidate: the rung.
        forward_triangles: triangles of its forward mesh.
        inverse_elements: elements of its imaging mesh (the unknowns of Gauss-Newton).
        pixels: pixels of its image, ``H * W``.
        max_position_error: largest position error over the phantoms, fraction of R (inf: a
            phantom imaged as nothing).
        mean_position_error: fraction of R.
        max_amplitude_error: largest ``|amplitude response - 1|`` over the phantoms.
        build_s: wall time to build its chain (mesh, forward model, matrix, grid), s.
        frame_ms: median wall time of one frame -> image, ms (Gauss-Newton: a cold fit).
        memory_mib: estimated peak memory of its forward assembly (the mesh budget), MiB.
        meets: whether it meets the target with the selection margin.
    """

    candidate: Candidate
    forward_triangles: int
    inverse_elements: int
    pixels: int
    max_position_error: float
    mean_position_error: float
    max_amplitude_error: float
    build_s: float
    frame_ms: float
    memory_mib: float
    meets: bool

    def row(self) -> str:
        return (
            f"{self.candidate.describe():<40} {self.forward_triangles:>6}"
            f" {self.inverse_elements:>6} {self.pixels:>6} {self.max_position_error:>8.2%}"
            f" {self.mean_position_error:>8.2%}"
            f" {self.max_amplitude_error:>8.1%} {self.build_s:>7.2f} {self.frame_ms:>8.2f}"
            f" {self.memory_mib:>6.0f}  {'yes' if self.meets else 'no'}"
        )


@dataclass(frozen=True)
class ModelChoice:
    """The coarsest model meeting a layer's accuracy target, and every rung tried.

    Attributes:
        layer: the layer with the target.
        ladder: the candidates evaluated, coarse to fine (the walk stops at the choice).
        chosen: index in ``ladder`` of the choice.
        radius_m: the sheet's equivalent radius R, m.
        data_triangles: triangles of the mesh the phantoms were simulated on.
        n_phantoms: phantoms of the selection set.
        from_cache: read from the choice cache (no phantom imaged).
    """

    layer: Layer
    ladder: tuple[Evaluation, ...]
    chosen: int
    radius_m: float
    data_triangles: int
    n_phantoms: int
    from_cache: bool = False

    @property
    def choice(self) -> Evaluation:
        return self.ladder[self.chosen]

    @property
    def resolved(self) -> Layer:
        """The explicit layer of the choice (what the reconstruction builds)."""
        return self.choice.candidate.layer(self.layer)

    def lines(self) -> list[str]:
        """The ladder as a table and the choice, one line each."""
        target = self.layer.solver.accuracy_target
        assert target is not None
        amplitude = (
            ""
            if target.amplitude_error_percent is None
            else f", amplitude error <= {target.amplitude_error_percent:g} %"
        )
        out = [
            f"layer {self.layer.name}: accuracy target position error <= "
            f"{target.position_error_percent:g} % R{amplitude} (R = {self.radius_m * 1e3:.1f} mm;"
            f" chosen at <= {SELECTION_MARGIN:.0%} of it on {self.n_phantoms} phantoms, radius "
            f"{TARGET_RADIUS_R:.0%} R, x{TARGET_CONTRAST:g}, {NOISE:.0%} noise, "
            f"{self.data_triangles}-triangle data mesh)"
            + (" [from cache]" if self.from_cache else ""),
            f"{'candidate':<40} {'fwd tri':>6} {'inv el':>6} {'pixels':>6} {'max PE':>8}"
            f" {'mean PE':>8} {'max AE':>8} {'build s':>7} {'frame ms':>8} {'MiB':>6}  meets",
        ]
        out += [e.row() for e in self.ladder]
        c = self.choice
        out.append(
            f"chosen: {c.candidate.describe()} ({c.forward_triangles} forward triangles, "
            f"{c.inverse_elements} elements, {c.pixels} pixels): max PE "
            f"{c.max_position_error:.2%} R, build {c.build_s:.2f} s, frame {c.frame_ms:.2f} ms; "
            f"model {self.resolved.content_hash[:16]}"
        )
        return out


@dataclass(frozen=True, eq=False)
class PhantomSet(DiscPhantoms):
    """Simulated small targets of one layer: its disc phantoms and where they were made.

    Attributes:
        radius_m: the sheet's equivalent radius R, m.
        data_triangles: triangles of the data mesh.
    """

    radius_m: float
    data_triangles: int


def equivalent_radius(layer: Layer) -> float:
    """``sqrt(area / pi)`` of the sheet (holes excluded), m."""
    return math.sqrt(layer.area_m2 / math.pi)


def ladder(layer: Layer) -> list[Candidate]:
    """The candidates for ``layer``, coarse to fine (see the module doc)."""
    radius = equivalent_radius(layer)
    extent = float(np.ptp(layer.outline, axis=0).max())
    gauss_newton = layer.solver.method == "gauss_newton"
    out = []
    for fraction in FORWARD_EDGES_R:
        edge = fraction * radius
        for per_edge in PIXELS_PER_EDGE:
            pixels = max(MIN_PIXELS, math.ceil(per_edge * extent / edge))
            for iterations in ITERATIONS if gauss_newton else (None,):
                out.append(Candidate(edge, edge, pixels, iterations))
    return out


def phantom_set(layer: Layer, simulate: Simulate, held_out: bool = False) -> PhantomSet:
    """The layer's phantoms: for selection (lattice centres) or held out (random, other seed)."""
    radius = equivalent_radius(layer)
    target_r = TARGET_RADIUS_R * radius
    data_edge = min(
        DATA_EDGE_FRACTION * FORWARD_EDGES_R[-1] * radius, DATA_EDGE_PER_TARGET_RADIUS * target_r
    )
    data_mesh = build_mesh(Candidate(data_edge, data_edge, MIN_PIXELS).layer(layer))
    model = simulate(layer, data_mesh)
    rng = np.random.default_rng(HELD_OUT_SEED if held_out else SELECTION_SEED)
    clearance = EDGE_CLEARANCE * target_r
    if held_out:
        lo, hi = layer.outline.min(axis=0), layer.outline.max(axis=0)
        points = rng.uniform(lo, hi, size=(200 * HELD_OUT_PHANTOMS, 2))
    else:
        pitch = math.sqrt(2.0 * layer.area_m2 / (math.sqrt(3.0) * SELECTION_LATTICE))
        ring = _inner_ring(layer, clearance, pitch)
        points = np.concatenate([target_centres(data_mesh, SELECTION_LATTICE), ring])
    inside = locate_points(data_mesh, points) >= 0
    points = points[inside & (_outline_distance(layer, points) >= (1 - 1e-9) * clearance)]
    if points.shape[0] == 0:
        raise ValueError(f"layer {layer.name}: no room for a simulated target")
    centres = points[:HELD_OUT_PHANTOMS] if held_out else points
    sigma0 = layer.material.sheet_conductance_s
    sim = simulate_discs(model, centres, target_r, TARGET_CONTRAST, NOISE, rng, sigma0)
    return PhantomSet(
        centres, sim.frames, sim.reference, sim.change_integral, radius, data_mesh.n_triangles
    )


def evaluate(
    layer: Layer,
    candidate: Candidate,
    phantoms: PhantomSet,
    build: Build,
    explicit: Layer | None = None,
) -> Evaluation:
    """Build ``candidate`` for ``layer`` and measure it on ``phantoms``.

    ``explicit``: measure this explicit layer instead (e.g. a shipped config's sizes, for
    comparison; ``candidate`` then only labels it).
    """
    target = layer.solver.accuracy_target
    concrete = candidate.layer(layer) if explicit is None else explicit
    started = time.perf_counter()
    imager = build(concrete)
    build_s = time.perf_counter() - started
    values = _images(imager, phantoms.frames, phantoms.reference)
    grid, mesh = imager.grid, imager.mesh
    pictures = grid.to_image(values)
    errors = []
    for picture, centre in zip(pictures, phantoms.centres, strict=True):
        try:
            merit = figures_of_merit(picture, grid.x, grid.y, centre, sign=1.0)
            errors.append(merit.position_error_m / phantoms.radius_m)
        except ValueError:  # imaged as nothing
            errors.append(math.inf)
    amplitude = values.astype(np.float64) @ np.abs(mesh.areas) / phantoms.change_integral
    amplitude_error = float(np.max(np.abs(amplitude - 1.0)))
    times = []
    for _ in range(FRAME_REPEATS):
        t = time.perf_counter()
        _reset(imager)
        imager.frame_images(phantoms.frames[0], phantoms.reference)
        times.append(time.perf_counter() - t)
    forward_triangles = build_mesh(concrete).n_triangles
    cost = estimate_cost(forward_triangles, phantoms.frames.shape[1])
    max_pe = float(np.max(errors))
    meets = target is not None and _meets(target, max_pe, amplitude_error)
    return Evaluation(
        candidate=candidate,
        forward_triangles=forward_triangles,
        inverse_elements=mesh.n_triangles,
        pixels=int(grid.shape[0] * grid.shape[1]),
        max_position_error=max_pe,
        mean_position_error=float(np.mean(errors)),
        max_amplitude_error=amplitude_error,
        build_s=build_s,
        frame_ms=float(np.median(times)) * 1e3,
        memory_mib=cost.peak_bytes / 2**20,
        meets=meets,
    )


def choose_model(
    layer: Layer, build: Build, simulate: Simulate, cache_dir: Path | str | None
) -> ModelChoice:
    """The coarsest ladder rung meeting ``layer.solver.accuracy_target`` (cached).

    Args:
        layer: a layer with an accuracy target.
        build: builds a layer's imager as the reconstruction does, without cache.
        simulate: the layer's forward model on a given mesh.
        cache_dir: where the choice is stored (``None``: not stored).

    Raises:
        PatchError: no rung meets the target (names the file and the target's key).
        ValueError: the layer has no target.
    """
    target = layer.solver.accuracy_target
    if target is None:
        raise ValueError(f"layer {layer.name}: no solver.accuracy_target")
    path = None if cache_dir is None else Path(cache_dir) / f"{choice_key(layer)}.json"
    if path is not None and path.is_file():
        cached = _load(path, layer)
        if cached is not None:
            return cached
    phantoms = phantom_set(layer, simulate)
    tried: list[Evaluation] = []
    for candidate in ladder(layer):
        if _cap_cannot_help(candidate, tried, target):
            continue
        tried.append(evaluate(layer, candidate, phantoms, build))
        if tried[-1].meets:
            choice = ModelChoice(
                layer,
                tuple(tried),
                len(tried) - 1,
                phantoms.radius_m,
                phantoms.data_triangles,
                phantoms.centres.shape[0],
            )
            if path is not None:
                _save(path, choice)
            return choice
    raise _nothing_meets(target, tried)


def choice_key(layer: Layer) -> str:
    """File stem of a layer's cached choice: its content hash (target included) and version."""
    text = f"choice:{SELECTOR_VERSION}:{layer.content_hash}"
    return f"{layer.name}-choice-{hashlib.sha256(text.encode()).hexdigest()[:24]}"


def _cap_cannot_help(candidate: Candidate, tried: list[Evaluation], target: AccuracyTarget) -> bool:
    """A higher Gauss-Newton cap on a model where raising the cap last improved nothing.

    Raising the cap is only worth another rung while it lowers a figure the target asks for
    (the largest position error, and the amplitude error when targeted); once it does not,
    the fits stop on their convergence test or the mesh limits them, and the walk moves on
    to the next mesh or pixel count.
    """
    if candidate.max_iterations is None or len(tried) < 2:
        return False
    last, before = tried[-1], tried[-2]
    same_model = all(
        replace(e.candidate, max_iterations=None) == replace(candidate, max_iterations=None)
        for e in (last, before)
    )
    if not same_model:
        return False
    improved = last.max_position_error < before.max_position_error
    if target.amplitude_error_percent is not None:
        improved = improved or last.max_amplitude_error < before.max_amplitude_error
    return not improved


def _meets(target: AccuracyTarget, max_position_error: float, amplitude_error: float) -> bool:
    if not max_position_error <= SELECTION_MARGIN * target.position_error_percent / 100.0:
        return False
    limit = target.amplitude_error_percent
    return limit is None or amplitude_error <= SELECTION_MARGIN * limit / 100.0


def _nothing_meets(target: AccuracyTarget, tried: list[Evaluation]) -> PatchError:
    finest = tried[-1]
    best_pe = min(e.max_position_error for e in tried)
    position_limit = SELECTION_MARGIN * target.position_error_percent / 100.0
    if best_pe <= position_limit and target.amplitude_error_percent is not None:
        best = min(e.max_amplitude_error for e in tried if e.max_position_error <= position_limit)
        return PatchError(
            target.source,
            f"{target.key}.amplitude_error_percent",
            f"no model on the ladder meets {target.amplitude_error_percent:g} %: the best "
            f"reaches {best:.1%} (the finest: {finest.candidate.describe()}); "
            "loosen it or remove it",
        )
    return PatchError(
        target.source,
        f"{target.key}.position_error_percent",
        f"no model on the ladder meets {target.position_error_percent:g} % R: the best reaches "
        f"{best_pe:.2%} R (the finest: {finest.candidate.describe()}, "
        f"{finest.forward_triangles} triangles); loosen the target or give mesh sizes instead",
    )


def _images(imager: Any, frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``[K, N]`` element images of the frames; every Gauss-Newton fit starts cold."""
    if not hasattr(imager.reconstructor, "reset"):
        return np.asarray(imager.relative_change(frames, reference))
    out = []
    for frame in frames:
        _reset(imager)
        out.append(imager.relative_change(frame, reference))
    return np.stack(out)


def _reset(imager: Any) -> None:
    reset = getattr(imager.reconstructor, "reset", None)
    if reset is not None:
        reset()


def _outline_distance(layer: Layer, points: np.ndarray) -> np.ndarray:
    """``[K]`` distance (m) of ``points`` ``[K, 2]`` to the outline of the sheet."""
    outline = layer.outline
    return geometry.distance_to_segments(points, outline, np.roll(outline, -1, axis=0))


def _inner_ring(layer: Layer, clearance_m: float, pitch_m: float) -> np.ndarray:
    """``[K, 2]`` points ``clearance_m`` inside the outline, about ``pitch_m`` apart along it.

    Where targets are hardest to place (the outline cuts their image), and where a lattice
    over the sheet samples least; points that end up nearer the outline elsewhere (corners)
    are dropped by the caller.
    """
    outline = layer.outline
    perimeter = layer.perimeter_m
    s = np.arange(math.ceil(perimeter / pitch_m)) * (perimeter / math.ceil(perimeter / pitch_m))
    step = 1e-6 * perimeter
    tangent = geometry.point_at_arc(outline, s + step) - geometry.point_at_arc(outline, s - step)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    inward = np.column_stack([-tangent[:, 1], tangent[:, 0]])  # left of a CCW outline
    return geometry.point_at_arc(outline, s) + clearance_m * inward


def _save(path: Path, choice: ModelChoice) -> None:
    """Store a choice atomically; a read-only cache only costs the selection next time."""
    data = {
        "version": SELECTOR_VERSION,
        "layer": choice.layer.content_hash,
        "chosen": choice.chosen,
        "radius_m": choice.radius_m,
        "data_triangles": choice.data_triangles,
        "n_phantoms": choice.n_phantoms,
        "ladder": [asdict(e) for e in choice.ladder],
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            json.dump(data, handle)
        os.replace(tmp, path)
    except OSError:
        pass


def _load(path: Path, layer: Layer) -> ModelChoice | None:
    """A stored choice of this layer, or ``None`` (unreadable, stale: choose again)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data["version"] != SELECTOR_VERSION or data["layer"] != layer.content_hash:
            return None
        rungs = []
        for row in data["ladder"]:
            row = dict(row)
            row["candidate"] = Candidate(**row["candidate"])
            rungs.append(Evaluation(**row))
        chosen = int(data["chosen"])
        if not 0 <= chosen < len(rungs):
            return None
        return ModelChoice(
            layer,
            tuple(rungs),
            chosen,
            float(data["radius_m"]),
            int(data["data_triangles"]),
            int(data["n_phantoms"]),
            from_cache=True,
        )
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None
