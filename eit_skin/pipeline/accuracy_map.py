"""Predicted accuracy of a design: how well a layer images a small touch, everywhere on it.

:func:`predict_accuracy` builds the layer exactly as the reconstruction does
(:meth:`~eit_skin.pipeline.builder.LayerImager.build`, the layer's method and noise figure),
simulates the package's phantom set (:func:`~eit_skin.fem.phantoms.simulate_discs`: discs
of radius :data:`TARGET_RADIUS_R` R, conductance x :data:`TARGET_CONTRAST`,
:data:`NOISE` of the RMS difference signal, the figures of
``bench/standing/bench_reconstruction.py``) on a *data mesh* finer than and different from the
imaging mesh (no inverse crime), and
measures at every target the GREIT position error, resolution and amplitude response
(:mod:`eit_skin.inverse.figures_of_merit`). Target centres: a hexagonal lattice of about
``lattice`` points over the sheet plus a ring :data:`EDGE_CLEARANCE` target radii inside the
outline (the error is largest near the outline), none in a hole. The per-target figures are
interpolated linearly onto the layer's image pixels (nearest target beyond the outermost
targets), giving maps of the sheet.

Two qualities: ``full`` (``eit-skin patch --predict``: :data:`FULL_LATTICE` targets, data
edge :data:`FULL_DATA_EDGE` of the imaging mesh's) and ``preview`` (the browser designer,
about a second for a 16-electrode patch: :data:`PREVIEW_LATTICE` targets, data edge
:data:`PREVIEW_DATA_EDGE`); both simulate on another, finer mesh than the one they image on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from eit_skin.fem.image_grid import locate_points
from eit_skin.fem.mesh import build_mesh
from eit_skin.fem.phantoms import simulate_discs
from eit_skin.inverse.figures_of_merit import figures_of_merit
from eit_skin.inverse.greit import target_centres
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
from eit_skin.patch import geometry
from eit_skin.patch.model import Layer, MeshSpec
from eit_skin.pipeline.builder import LayerImager, forward_model, resolve_layer
from eit_skin.pipeline.model_choice import equivalent_radius

#: Target radius, fraction of the sheet's equivalent radius R (bench_reconstruction's).
TARGET_RADIUS_R = 0.05
TARGET_CONTRAST = 2.0
NOISE = 0.01
#: Target centres stay this many target radii inside the outline (bench: up to 0.9 R).
EDGE_CLEARANCE = 2.0
FULL_LATTICE = 120
FULL_DATA_EDGE = 0.5
PREVIEW_LATTICE = 36
PREVIEW_DATA_EDGE = 0.7
#: quality -> (lattice targets, data mesh edge as a fraction of the imaging mesh's)
QUALITIES = {
    "full": (FULL_LATTICE, FULL_DATA_EDGE),
    "preview": (PREVIEW_LATTICE, PREVIEW_DATA_EDGE),
}
SEED = 0


@dataclass(frozen=True, eq=False)
class AccuracyMap:
    """Predicted accuracy of one layer.

    Attributes:
        layer: the layer as built (an accuracy target resolved).
        noise_figure: the noise figure the method was built with.
        radius_m: the sheet's equivalent radius R, m.
        centres: ``[K, 2]`` target centres, m.
        position_error_m: ``[K]`` GREIT position error, m (inf: imaged as nothing).
        resolution: ``[K]`` GREIT resolution (sqrt of the quarter-max area over the sheet's).
        amplitude_response: ``[K]`` image integral over the true change's integral.
        x: ``[W]`` pixel-centre x, m.
        y: ``[H]`` pixel-centre y, m.
        maps: name -> ``[H, W]`` float map (NaN outside the sheet), names as the attributes.
        data_triangles: triangles of the data mesh.
        inverse_triangles: elements of the imaging mesh.
        timings_s: ``build`` (the layer's chain), ``simulate`` (phantoms), ``image`` (imaging
            and figures), ``total``, s.
    """

    layer: Layer
    noise_figure: float
    radius_m: float
    centres: np.ndarray
    position_error_m: np.ndarray
    resolution: np.ndarray
    amplitude_response: np.ndarray
    x: np.ndarray
    y: np.ndarray
    maps: dict[str, np.ndarray]
    data_triangles: int
    inverse_triangles: int
    timings_s: dict[str, float]

    def summary(self) -> dict[str, Any]:
        """Worst, median and where, per figure (position error in m and % R)."""
        pe = self.position_error_m
        worst = int(np.argmax(pe))
        res = self.resolution
        amp = self.amplitude_response
        far = int(np.argmax(np.abs(amp - 1.0)))
        return {
            "position_error_worst_m": float(pe[worst]),
            "position_error_worst_percent_r": float(100 * pe[worst] / self.radius_m),
            "position_error_median_m": float(np.median(pe)),
            "position_error_median_percent_r": float(100 * np.median(pe) / self.radius_m),
            "position_error_worst_at_m": [float(v) for v in self.centres[worst]],
            "resolution_worst": float(res.max()),
            "resolution_median": float(np.median(res)),
            "resolution_worst_at_m": [float(v) for v in self.centres[int(np.argmax(res))]],
            "amplitude_response_median": float(np.median(amp)),
            "amplitude_response_worst": float(amp[far]),
            "amplitude_response_worst_at_m": [float(v) for v in self.centres[far]],
        }

    def line(self) -> str:
        """The one-line summary."""
        s = self.summary()
        at = s["position_error_worst_at_m"]
        amp_at = s["amplitude_response_worst_at_m"]
        return (
            f"{self.layer.name}: position error worst {s['position_error_worst_m'] * 1e3:.2f} mm"
            f" ({s['position_error_worst_percent_r']:.2f} % R) at ({at[0] * 1e3:+.1f},"
            f" {at[1] * 1e3:+.1f}) mm, median {s['position_error_median_m'] * 1e3:.2f} mm"
            f" ({s['position_error_median_percent_r']:.2f} % R); resolution median"
            f" {s['resolution_median']:.3f}, worst {s['resolution_worst']:.3f}; amplitude"
            f" response median {s['amplitude_response_median']:.2f}, worst"
            f" {s['amplitude_response_worst']:.2f} at ({amp_at[0] * 1e3:+.1f},"
            f" {amp_at[1] * 1e3:+.1f}) mm"
        )

    def to_json(self) -> dict[str, Any]:
        """Everything as JSON-ready data (lengths in m; maps as rows, null outside)."""

        def rows(a: np.ndarray) -> list[list[float | None]]:
            return [[None if not np.isfinite(v) else round(float(v), 7) for v in r] for r in a]

        return {
            "layer": self.layer.name,
            "method": self.layer.solver.method,
            "noise_figure": self.noise_figure,
            "radius_m": self.radius_m,
            "phantoms": {
                "target_radius_r": TARGET_RADIUS_R,
                "contrast": TARGET_CONTRAST,
                "noise": NOISE,
                "count": int(self.centres.shape[0]),
                "data_triangles": self.data_triangles,
                "inverse_triangles": self.inverse_triangles,
                "centres_m": self.centres.round(7).tolist(),
                "position_error_m": [round(float(v), 7) for v in self.position_error_m],
                "resolution": [round(float(v), 5) for v in self.resolution],
                "amplitude_response": [round(float(v), 5) for v in self.amplitude_response],
            },
            "summary": self.summary(),
            "x_m": self.x.round(7).tolist(),
            "y_m": self.y.round(7).tolist(),
            "maps": {name: rows(m) for name, m in self.maps.items()},
            "timings_s": self.timings_s,
        }


def predict_accuracy(
    layer: Layer,
    noise_figure: float | None = None,
    quality: str = "full",
    cache_dir: Any = "default",
    centres: np.ndarray | None = None,
) -> AccuracyMap:
    """Predicted accuracy maps of ``layer`` (see the module doc).

    Args:
        layer: a validated layer (an accuracy target is resolved first).
        noise_figure: overrides ``solver.noise_figure`` (else the layer's or the method's
            default, :data:`~eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`).
        quality: ``full`` or ``preview`` (:data:`QUALITIES`).
        cache_dir: the reconstruction cache (``None``: build without it).
        centres: ``[K, 2]`` target centres, m, instead of the lattice and ring (e.g. where a
            design must be accurate, or another benchmark's targets).

    Raises:
        ValueError: unknown quality, or no room for a target on the sheet.
    """
    if quality not in QUALITIES:
        raise ValueError(f"quality must be one of {sorted(QUALITIES)}, got {quality!r}")
    lattice, data_fraction = QUALITIES[quality]
    started = time.perf_counter()
    explicit = resolve_layer(layer, cache_dir)
    if noise_figure is not None:
        explicit = replace(explicit, solver=replace(explicit.solver, noise_figure=noise_figure))
    used_nf = explicit.solver.noise_figure or DEFAULT_NOISE_FIGURE[explicit.solver.method]
    imager = LayerImager.build(explicit, cache_dir)
    built = time.perf_counter()
    radius = equivalent_radius(explicit)
    target_r = TARGET_RADIUS_R * radius
    data_mesh = _data_mesh(explicit, data_fraction)
    if centres is None:
        centres = _centres(explicit, data_mesh, lattice, EDGE_CLEARANCE * target_r)
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    phantoms = simulate_discs(
        forward_model(explicit, data_mesh),
        centres,
        target_r,
        TARGET_CONTRAST,
        NOISE,
        np.random.default_rng(SEED),
        explicit.material.sheet_conductance_s,
    )
    simulated = time.perf_counter()
    values = _element_images(imager, phantoms.frames, phantoms.reference)
    grid = imager.grid
    pictures = grid.to_image(values)
    pe, res = _merits(pictures, grid, centres)
    amp = values.astype(np.float64) @ np.abs(imager.mesh.areas) / phantoms.change_integral
    maps = _maps(grid, pictures, centres, (pe, res, amp))
    done = time.perf_counter()
    return AccuracyMap(
        layer=explicit,
        noise_figure=float(used_nf),
        radius_m=radius,
        centres=centres,
        position_error_m=pe,
        resolution=res,
        amplitude_response=amp,
        x=np.asarray(grid.x, dtype=np.float64),
        y=np.asarray(grid.y, dtype=np.float64),
        maps=maps,
        data_triangles=data_mesh.n_triangles,
        inverse_triangles=imager.mesh.n_triangles,
        timings_s={
            "build": built - started,
            "simulate": simulated - built,
            "image": done - simulated,
            "total": done - started,
        },
    )


def _data_mesh(layer: Layer, fraction: float) -> Any:
    """The mesh the phantoms are simulated on: ``fraction`` of the layer's finest edge."""
    inverse_edge = layer.mesh.inverse_max_edge_m or layer.mesh.max_edge_m
    edge = fraction * min(inverse_edge, layer.mesh.max_edge_m)
    spec = MeshSpec(edge, min(edge, layer.mesh.electrode_edge_m), layer.mesh.min_angle_deg, None)
    return build_mesh(replace(layer, mesh=spec))


def _maps(
    grid: Any, pictures: np.ndarray, centres: np.ndarray, figures: tuple[np.ndarray, ...]
) -> dict[str, np.ndarray]:
    """The ``[H, W]`` maps of ``(position error, resolution, amplitude response)`` ``[K]`` each.

    Interpolated between the targets ``[K, 2]`` over the sheet of images ``[K, H, W]``; an
    infinite position error (nothing imaged) counts as the largest finite one.
    """
    pe, res, amp = figures
    inside = np.isfinite(pictures[0]) if len(centres) else np.zeros(grid.shape, bool)
    return {
        name: _interpolated(centres, v, grid.x, grid.y, inside)
        for name, v in (
            ("position_error_m", np.where(np.isfinite(pe), pe, np.nanmax(pe[np.isfinite(pe)]))),
            ("resolution", res),
            ("amplitude_response", amp),
        )
    }


def _merits(pictures: np.ndarray, grid: Any, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(position error [K] m, resolution [K])`` of images ``[K, H, W]`` of targets ``[K, 2]``.

    A target imaged as nothing gets an infinite position error and resolution 1.
    """
    k = centres.shape[0]
    pe, res = np.full(k, np.inf), np.ones(k)
    for i, (picture, centre) in enumerate(zip(pictures, centres, strict=True)):
        try:
            merit = figures_of_merit(picture, grid.x, grid.y, centre, sign=1.0)
        except ValueError:  # imaged as nothing
            continue
        pe[i], res[i] = merit.position_error_m, merit.resolution
    return pe, res


def _centres(layer: Layer, data_mesh: Any, lattice: int, clearance_m: float) -> np.ndarray:
    """``[K, 2]`` lattice centres over the sheet plus a ring ``clearance_m`` inside the outline.

    All at least ``clearance_m`` from the outline and not in a hole.
    """
    pitch = math.sqrt(2.0 * layer.area_m2 / (math.sqrt(3.0) * lattice))
    outline = layer.outline
    n_ring = max(8, math.ceil(layer.perimeter_m / pitch))
    s = np.arange(n_ring) * (layer.perimeter_m / n_ring)
    step = 1e-6 * layer.perimeter_m
    tangent = geometry.point_at_arc(outline, s + step) - geometry.point_at_arc(outline, s - step)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    inward = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    ring = geometry.point_at_arc(outline, s) + clearance_m * inward
    points = np.concatenate([target_centres(data_mesh, lattice), ring])
    near = geometry.distance_to_segments(points, outline, np.roll(outline, -1, axis=0))
    keep = (locate_points(data_mesh, points) >= 0) & (near >= (1 - 1e-9) * clearance_m)
    if not keep.any():
        raise ValueError(f"layer {layer.name}: no room for a simulated target")
    return points[keep]


def _element_images(imager: LayerImager, frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``[K, N]`` element images; every Gauss-Newton fit starts cold."""
    reset = getattr(imager.reconstructor, "reset", None)
    if reset is None:
        return np.asarray(imager.relative_change(frames, reference)).reshape(frames.shape[0], -1)
    out = []
    for frame in frames:
        reset()
        out.append(imager.relative_change(frame, reference))
    return np.stack(out)


def _interpolated(
    centres: np.ndarray, values: np.ndarray, x: np.ndarray, y: np.ndarray, inside: np.ndarray
) -> np.ndarray:
    """``[H, W]`` per-target ``values`` interpolated linearly onto the pixels.

    Nearest target outside their convex hull; NaN outside the sheet.
    """
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    xx, yy = np.meshgrid(x, y)
    pts = np.column_stack([xx[inside], yy[inside]])
    out = np.full(inside.shape, np.nan)
    if centres.shape[0] >= 3:
        linear = LinearNDInterpolator(centres, values)(pts)
    else:
        linear = np.full(pts.shape[0], np.nan)
    gap = ~np.isfinite(linear)
    linear[gap] = NearestNDInterpolator(centres, values)(pts[gap])
    out[inside] = linear
    return out
