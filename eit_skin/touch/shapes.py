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
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

if TYPE_CHECKING:
    from eit_skin.pipeline.builder import LayerImager

BLOB_FRACTION = 0.3
"""Pixels count towards the moments by how far they exceed this fraction of the maximum."""
FINGER_RADIUS_M = 0.006
"""Radius of the fingertip-sized disc of :func:`single_contact_spread`, m."""


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
    centroids = mesh.centroids
    d2 = ((centroids[None, :, :] - points[:, None, :]) ** 2).sum(axis=-1)  # [P, N]
    disc = (d2 <= radius_m**2).astype(np.float64)
    disc[np.arange(len(points)), d2.argmin(axis=1)] = 1.0  # at least the nearest element
    dv = disc @ matrix.jacobian.T  # [P, M]
    images = grid.to_image(matrix.solve(dv))  # [P, H, W]
    moments = blob_moments(images, xx, yy, fraction)
    spread = np.sqrt(moments[:, 3] * moments[:, 4])
    values = np.full(inside.shape, np.nan)
    values[sample] = spread
    known = np.isfinite(values)
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return values[iy, ix]
