"""Shape of a touch in a reconstructed image: second moments, and what one fingertip would give.

EIT blur merges fingertips 15-30 mm apart into one blob, so counting peaks does not tell a grab
or a pinch from a push. The blob's *spread* still does: :func:`blob_moments` weights every pixel
by how far it rises above ``fraction`` of the image's maximum (so the estimate is independent
of the touch's strength) and returns the centroid and the principal standard deviations
(``major >= minor``, m) of that weight. A grab (3-5 fingers over 30-90 mm) is much wider than
one finger's blur; a pinch is elongated along its axis and narrows as the fingers close.

The blur of one finger depends on where it is (sensitivity is highest near the electrodes,
lowest in the middle of the sheet), so spreads are compared with :func:`single_contact_spread`:
the spread of the reconstructed image of one fingertip-sized conductivity change at every
pixel, computed from the layer's own Jacobian and reconstruction matrix (noise-free; the
moments do not depend on the amplitude, the reconstruction being linear).
:func:`contact_geometry` keeps that map in the reconstruction's cache, so the classifier gets
it and its pixel grid (:func:`layer_image_grid`) without building the reconstruction.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.mesh import Mesh, build_mesh
from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.model import Layer
from eit_skin.pipeline.builder import (
    LayerImager,
    cache_key,
    contact_patterns,
    default_cache_dir,
    resolve_layer,
)

BLOB_FRACTION = 0.3
"""Pixels count towards the moments by how far they exceed this fraction of the maximum
(default of ``ClassifierConfig.blob_fraction``)."""
FINGER_RADIUS_M = 0.006
"""Radius of the fingertip-sized disc of :func:`single_contact_spread`, m (default of
``ClassifierConfig.finger_radius_m``)."""


def blob_moments(
    images: np.ndarray,
    xx: np.ndarray,
    yy: np.ndarray,
    fraction: float = BLOB_FRACTION,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Peak, centroid and principal spreads of ``images`` ``[..., H, W]`` (NaN ignored).

    Args:
        images: one image ``[H, W]`` or a stack ``[P, H, W]`` (any unit, positive = touch).
        xx: ``[H, W]`` pixel-centre x, m.
        yy: ``[H, W]`` pixel-centre y, m.
        fraction: weight of a pixel = ``max(value - fraction * peak, 0)``.
        mask: optional bool ``[H, W]`` (or like ``images``): only these pixels count (e.g. the
            segmented contact regions, so that far-away noise pixels, which weigh heavily in a
            second moment, are left out).

    Returns:
        ``[..., 6]``: peak (image unit), centroid x, y (m), major and minor standard deviation
        (m, ``major >= minor``), major axis angle (rad, in ``(-pi/2, pi/2]``). An image with no
        positive value gives NaN moments.
    """
    a = np.asarray(images, dtype=np.float64)
    single = a.ndim == 2
    a = a[None] if single else a.reshape(-1, *a.shape[-2:])
    a = np.where(np.isfinite(a), a, 0.0)
    if mask is not None:
        a = np.where(
            np.broadcast_to(np.asarray(mask, dtype=bool), np.shape(images)).reshape(a.shape), a, 0.0
        )
    peak = a.max(axis=(1, 2))
    w = np.clip(a - fraction * peak[:, None, None], 0.0, None)
    total = w.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = np.einsum("pij,ij->p", w, xx) / total
        cy = np.einsum("pij,ij->p", w, yy) / total
        dx = xx[None] - cx[:, None, None]
        dy = yy[None] - cy[:, None, None]
        sxx = np.einsum("pij,pij->p", w, dx * dx) / total
        syy = np.einsum("pij,pij->p", w, dy * dy) / total
        sxy = np.einsum("pij,pij->p", w, dx * dy) / total
    half_sum = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum((0.5 * (sxx - syy)) ** 2 + sxy**2, 0.0))
    major = np.sqrt(np.maximum(half_sum + root, 0.0))
    minor = np.sqrt(np.maximum(half_sum - root, 0.0))
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    out = np.stack([peak, cx, cy, major, minor, angle], axis=-1)
    out[~(peak > 0)] = np.nan
    out[~(peak > 0), 0] = peak[~(peak > 0)]
    return out[0] if single else out.reshape(*np.shape(images)[:-2], 6)


def fingertip_discs(points_m: np.ndarray, mesh: Mesh, radius_m: float) -> np.ndarray:
    """``[P, N]`` 0/1 indicator of the elements of a disc of ``radius_m`` at each point.

    An element belongs to the disc at ``points_m`` ``[P, 2]`` (m) when its centroid lies
    within ``radius_m``; the element nearest the point always does.
    """
    points_m = np.asarray(points_m, dtype=np.float64)
    d2 = ((mesh.centroids[None, :, :] - points_m[:, None, :]) ** 2).sum(axis=-1)  # [P, N]
    disc = (d2 <= radius_m**2).astype(np.float64)
    disc[np.arange(len(points_m)), d2.argmin(axis=1)] = 1.0
    return disc


def single_contact_spread(
    imager: LayerImager,
    radius_m: float = FINGER_RADIUS_M,
    stride: int = 2,
    fraction: float = BLOB_FRACTION,
) -> np.ndarray:
    """``[H, W]`` geometric-mean spread ``sqrt(major * minor)`` (m) of one fingertip's image.

    A disc of ``radius_m`` of uniform relative conductivity change is placed on every
    ``stride``-th pixel inside the sheet; its image (Jacobian, then the reconstruction matrix,
    then the pixel grid) gives the moments of :func:`blob_moments`. Pixels between the samples
    (and outside the sheet) take the nearest sample's value.

    Args:
        imager: the layer's imager: its pixel grid ``[H, W]``, inverse mesh (N elements) and
            reconstruction matrix (Jacobian ``[M, N]`` and its solve).
        radius_m: disc radius, m.
        stride: pixel step between discs.
        fraction: moment weighting, see :func:`blob_moments`.
    """
    grid, mesh, matrix = imager.grid, imager.mesh, imager.matrix
    xx, yy = np.meshgrid(grid.x, grid.y)
    inside = np.asarray(grid.inside, dtype=bool)
    sample = np.zeros_like(inside)
    sample[::stride, ::stride] = True
    sample &= inside
    if not sample.any():
        raise ValueError("single_contact_spread: no pixel inside the sheet")
    points = np.column_stack([xx[sample], yy[sample]])
    dv = fingertip_discs(points, mesh, radius_m) @ matrix.jacobian.T  # [P, M]
    images = grid.to_image(matrix.solve(dv))  # [P, H, W]
    moments = blob_moments(images, xx, yy, fraction)
    spread = np.sqrt(moments[:, 3] * moments[:, 4])
    values = np.full(inside.shape, np.nan)
    values[sample] = spread
    known = np.isfinite(values)
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return values[iy, ix]


def disc_patterns(
    grid: ImageGrid, mesh: Mesh, jacobian: np.ndarray, radius_m: float = FINGER_RADIUS_M
) -> np.ndarray:
    """``[H, W, M]`` float32 relative change of every channel for a fingertip on each pixel.

    The fingertip is :func:`fingertip_discs` (``radius_m``) of unit relative conductivity
    change; its pattern is ``J disc`` (``jacobian`` ``[M, N]``, relative, over ``mesh``'s
    ``N`` elements): times ``|v_ref|`` it is volts. NaN on pixels outside the sheet. The raw
    frames' START filter (:class:`~eit_skin.touch.frame_evidence.TouchFilter`).
    """
    jacobian = np.asarray(jacobian, dtype=np.float64)
    inside = np.asarray(grid.inside, dtype=bool)
    xx, yy = np.meshgrid(grid.x, grid.y)
    points = np.column_stack([xx[inside], yy[inside]])
    rows = np.concatenate(
        [
            fingertip_discs(points[i : i + 512], mesh, radius_m) @ jacobian.T  # 512 at a time
            for i in range(0, len(points), 512)
        ]
    )
    out = np.full((*inside.shape, jacobian.shape[0]), np.nan, dtype=np.float32)
    out[inside] = rows
    return out


def layer_image_grid(layer: Layer) -> ImageGrid:
    """The pixel grid ``layer`` is imaged on, without any reconstruction matrix.

    The grid of :class:`~eit_skin.pipeline.builder.LayerImager`: the layer's inverse mesh
    (``mesh.inverse_max_edge``, else its forward mesh) at ``solver.image_pixels``.
    """
    return ImageGrid.build(
        build_mesh(layer, layer.mesh.inverse_max_edge_m), layer.solver.image_pixels
    )


def raw_patterns(
    layer: Layer, imager: LayerImager, radius_m: float = FINGER_RADIUS_M
) -> tuple[np.ndarray, np.ndarray]:
    """``(disc_rel [H, W, M], contact_rel [M, E])`` of ``layer`` imaged by ``imager``.

    A fingertip on each pixel (:func:`disc_patterns`) and each electrode's contact impedance
    (:func:`~eit_skin.pipeline.builder.contact_patterns`), as relative channel changes; with
    a magnitude-only device's signs (its frames are ``|v|``, they change by ``sign(v) dv``).
    """
    disc = disc_patterns(imager.grid, imager.mesh, imager.matrix.jacobian, radius_m)
    contact = contact_patterns(layer)
    if imager.signs is not None:
        disc = disc * imager.signs.astype(np.float32)
        contact = contact * imager.signs[:, None]
    return disc, contact


@dataclass(frozen=True)
class ContactGeometry:
    """What touch classification needs of a pressure layer, and where it came from.

    Attributes:
        grid: the layer's pixel grid (``[H, W]`` images).
        spread_m: ``[H, W]`` one fingertip's spread at every pixel, m
            (:func:`single_contact_spread`).
        disc_rel: ``[H, W, M]`` float32 relative change of every raw channel for a
            fingertip on each pixel (:func:`disc_patterns`; NaN off the sheet).
        contact_rel: ``[M, E]`` relative change of every raw channel per change of each
            electrode's contact impedance (:func:`~eit_skin.pipeline.builder.contact_patterns`).
        source: ``"spread cache"`` (no matrix touched), ``"matrix cache"`` (matrix rebuilt
            from the Jacobian the reconstruction cached) or ``"built"`` (forward model
            solved; its Jacobian is cached for the reconstruction too).

    Both patterns carry a magnitude-only device's signs (its frames are ``|v|``).
    """

    grid: ImageGrid
    spread_m: np.ndarray
    disc_rel: np.ndarray
    contact_rel: np.ndarray
    source: str


def contact_geometry(
    layer: Layer,
    cache_dir: Path | str | None = "default",
    radius_m: float = FINGER_RADIUS_M,
    stride: int = 2,
    fraction: float = BLOB_FRACTION,
) -> ContactGeometry:
    """The pixel grid, single-finger spread map and raw-channel patterns of ``layer``, cached.

    The spread needs the layer's Jacobian and reconstruction matrix (the image of a disc is
    ``R J disc``), the fingertip patterns the Jacobian (``J disc``), the contact patterns
    the forward model. All are computed once and stored in ``cache_dir`` next to the
    matrices the reconstruction caches, as ``<cache_key(layer)>-spread.npz`` (keyed by the
    layer's content hash, so an edited layer never reads a stale map; the disc parameters
    are checked on load). A hit builds only the grid (the inverse mesh, no forward model, no
    matrix). A miss takes the matrix from the reconstruction's cache
    (:meth:`LayerImager.build`), or builds and caches it there, then stores the rest.
    ``cache_dir=None``: no cache at all.
    """
    directory = default_cache_dir() if cache_dir == "default" else cache_dir
    layer = resolve_layer(layer, directory)  # an accuracy target: its chosen model's grid
    path = None if directory is None else Path(directory) / f"{cache_key(layer)}-spread.npz"
    params = np.array([radius_m, stride, fraction], dtype=np.float64)
    if path is not None and path.is_file():
        grid = layer_image_grid(layer)
        try:
            with np.load(path) as cached:
                spread, stored = cached["spread_m"], cached["parameters"]
                disc, contact = cached["disc_rel"], cached["contact_rel"]
            if (
                spread.shape == grid.shape
                and disc.shape[:2] == grid.shape
                and contact.shape == (disc.shape[2], layer.n_electrodes)
                and np.array_equal(stored, params)
                and np.all(np.isfinite(spread) & (spread > 0))
            ):
                return ContactGeometry(grid, spread, disc, contact, "spread cache")
        except (OSError, KeyError, ValueError):
            pass  # unreadable or stale (or from before the patterns): recompute below
    imager = LayerImager.build(layer, cache_dir=directory)
    spread = single_contact_spread(imager, radius_m, stride, fraction)
    disc, contact = raw_patterns(layer, imager, radius_m)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_npz_atomic(
                path, spread_m=spread, disc_rel=disc, contact_rel=contact, parameters=params
            )
        except OSError:
            pass  # a read-only cache only costs the computation next time
    source = "matrix cache" if imager.from_cache else "built"
    return ContactGeometry(imager.grid, spread, disc, contact, source)
