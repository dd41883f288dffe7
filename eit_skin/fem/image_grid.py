"""Regular pixel grids over a sheet: element values -> ``[H, W]`` images.

:class:`ImageGrid` precomputes, once per mesh, a sparse ``[H*W, N]`` matrix that
maps every pixel centre to the triangle containing it (element values are
piecewise constant, so this is exact sampling). Pixels outside the sheet or
inside a hole (no triangle there) are NaN in every image.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from eit_skin.fem.mesh import Mesh


def locate_points(mesh: Mesh, points: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """Index of the triangle containing each point, ``-1`` if none (outside, in a hole).

    A uniform bucket grid (cell ~ 1.5 x the mean triangle size) lists the triangles whose
    bounding box touches each cell; a point is tested (barycentric) against its cell's list
    only. Vectorised, ``O(N + P)`` for a quality mesh. A point on a shared edge gets the
    lowest-numbered triangle.

    Args:
        mesh: triangle mesh, metres.
        points: ``[P, 2]`` query points, metres.
        tolerance: barycentric slack (dimensionless) so points on edges are found.

    Returns:
        ``[P]`` int64 triangle indices.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n_tri = mesh.n_triangles
    out = np.full(points.shape[0], -1, dtype=np.int64)
    if n_tri == 0 or points.shape[0] == 0:
        return out
    p = np.asarray(mesh.nodes, dtype=np.float64)[mesh.triangles]  # [N, 3, 2]
    lo = p.min(axis=1)
    hi = p.max(axis=1)
    origin = lo.min(axis=0)
    extent = np.maximum(hi.max(axis=0) - origin, 1e-300)
    a = p[:, 0]
    e1 = p[:, 1] - a
    e2 = p[:, 2] - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    cell = 1.5 * float(np.sqrt(np.abs(det).mean() / 2))
    cell = max(cell, float(extent.max()) / 4096)  # at most 4096^2 cells
    shape = np.maximum(np.ceil(extent / cell).astype(np.int64), 1)
    slack = tolerance * extent
    i0 = np.clip(((lo - slack - origin) / cell).astype(np.int64), 0, shape - 1)
    i1 = np.clip(((hi + slack - origin) / cell).astype(np.int64), 0, shape - 1)
    nx = i1[:, 0] - i0[:, 0] + 1
    ny = i1[:, 1] - i0[:, 1] + 1
    count = nx * ny
    tri = np.repeat(np.arange(n_tri), count)
    k = np.arange(tri.size) - np.repeat(np.cumsum(count) - count, count)  # index in the box
    cx = i0[tri, 0] + k % nx[tri]
    cy = i0[tri, 1] + k // nx[tri]
    cell_id = cy * shape[0] + cx
    order = np.argsort(cell_id, kind="stable")
    bucket_tri = tri[order]
    starts = np.searchsorted(cell_id[order], np.arange(shape[0] * shape[1] + 1))
    q = np.floor((points - origin) / cell).astype(np.int64)
    valid = np.all((q >= 0) & (q < shape), axis=1) & np.all(np.isfinite(points), axis=1)
    pt = np.flatnonzero(valid)
    cid = q[pt, 1] * shape[0] + q[pt, 0]
    n_cand = starts[cid + 1] - starts[cid]
    pt_rep = np.repeat(pt, n_cand)
    j = np.arange(pt_rep.size) - np.repeat(np.cumsum(n_cand) - n_cand, n_cand)
    cand = bucket_tri[np.repeat(starts[cid], n_cand) + j]
    d = points[pt_rep] - a[cand]
    u = (d[:, 0] * e2[cand, 1] - d[:, 1] * e2[cand, 0]) / det[cand]
    v = (e1[cand, 0] * d[:, 1] - e1[cand, 1] * d[:, 0]) / det[cand]
    inside = (u >= -tolerance) & (v >= -tolerance) & (u + v <= 1 + tolerance)
    best = np.full(points.shape[0], n_tri, dtype=np.int64)
    np.minimum.at(best, pt_rep[inside], cand[inside])
    found = best < n_tri
    out[found] = best[found]
    return out


@dataclass(frozen=True, eq=False)
class ImageGrid:
    """Pixel grid over a mesh and the sparse map from element values to pixels.

    Attributes:
        x: ``[W]`` pixel-centre x coordinates, metres (increasing).
        y: ``[H]`` pixel-centre y coordinates, metres (increasing; row 0 is lowest y).
        matrix: ``[H*W, N]`` CSR float32; row ``i`` picks the element under pixel ``i``.
        inside: ``[H, W]`` bool, True where a pixel centre lies on the sheet.
    """

    x: np.ndarray
    y: np.ndarray
    matrix: sp.csr_matrix
    inside: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.y.size), int(self.x.size))

    @classmethod
    def build(
        cls,
        mesh: Mesh,
        pixels: int,
        bounding_box: tuple[float, float, float, float] | None = None,
    ) -> ImageGrid:
        """Build the grid for ``mesh``.

        Args:
            mesh: the mesh whose element values will be imaged (holes are absent triangles).
            pixels: number of pixels along the longer side of the bounding box (>= 2);
                pixels are square, the other side gets ``ceil(extent / pixel size)``.
            bounding_box: ``(x_min, y_min, x_max, y_max)`` metres; default: the mesh's.

        Raises:
            ValueError: ``pixels < 2`` or an empty/degenerate bounding box.
        """
        if int(pixels) < 2:
            raise ValueError(f"image pixels must be >= 2, got {pixels}")
        if bounding_box is None:
            lo = mesh.nodes.min(axis=0)
            hi = mesh.nodes.max(axis=0)
            bounding_box = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
        x0, y0, x1, y1 = (float(v) for v in bounding_box)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"degenerate image bounding box {bounding_box}")
        size = max(x1 - x0, y1 - y0) / int(pixels)
        w = max(1, int(np.ceil((x1 - x0) / size - 1e-9)))
        h = max(1, int(np.ceil((y1 - y0) / size - 1e-9)))
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        x = cx + (np.arange(w) - 0.5 * (w - 1)) * size
        y = cy + (np.arange(h) - 0.5 * (h - 1)) * size
        xx, yy = np.meshgrid(x, y)
        element = locate_points(mesh, np.column_stack([xx.ravel(), yy.ravel()]))
        rows = np.flatnonzero(element >= 0)
        matrix = sp.csr_matrix(
            (np.ones(rows.size, dtype=np.float32), (rows, element[rows])),
            shape=(h * w, mesh.n_triangles),
        )
        return cls(x=x, y=y, matrix=matrix, inside=(element >= 0).reshape(h, w))

    def to_image(self, values: np.ndarray) -> np.ndarray:
        """Map element values to images.

        Args:
            values: ``[N]`` or ``[T, N]`` per-element values.

        Returns:
            float32 ``[H, W]`` or ``[T, H, W]``, NaN outside the sheet and in holes.
        """
        n = self.matrix.shape[1]
        if np.shape(values) == (n,):  # one frame: one (casting) copy and one gather
            padded = np.empty(n + 1, dtype=np.float32)
            padded[:n] = values
            padded[n] = np.nan
            return self.image_of_row(padded)
        v = np.asarray(values, dtype=np.float32)
        single = v.ndim == 1
        v2 = v[None, :] if single else v
        if v2.ndim != 2 or v2.shape[1] != self.matrix.shape[1]:
            raise ValueError(
                f"values must be [N] or [T, N] with N={self.matrix.shape[1]}, got {v.shape}"
            )
        h, w = self.shape
        padded = np.concatenate([v2, np.full((v2.shape[0], 1), np.nan, np.float32)], axis=1)
        return np.take(padded, self.pixel_owner, axis=1, mode="wrap").reshape(-1, h, w)[
            0 if single else slice(None)
        ]

    def image_of_row(self, row: np.ndarray) -> np.ndarray:
        """``[N + 1]`` float32 element values with NaN last -> ``[H, W]`` image (one gather).

        The gathers use ``mode="wrap"``: every index is in range, and numpy's default mode
        checks and buffers (a 4096-pixel gather takes ~6 us instead of ~4).
        """
        return row.take(self.pixel_owner, mode="wrap").reshape(self.shape)

    @cached_property
    def pixel_owner(self) -> np.ndarray:
        """``[H*W]`` element under each pixel; ``N`` (a NaN column) where there is none.

        Every row of :attr:`matrix` holds at most one 1, so imaging is one gather, several
        times cheaper per frame than the sparse product and the NaN mask.
        """
        m = self.matrix.tocsr()
        counts = np.diff(m.indptr)
        if counts.max(initial=0) > 1 or not np.all(m.data == 1):
            raise ValueError("ImageGrid.matrix must pick one element per pixel")
        owner = np.full(m.shape[0], m.shape[1], dtype=np.intp)
        owner[counts == 1] = m.indices
        return owner


#: Two input columns of a folded matrix whose columns are proportional to within this fraction
#: of the column's norm share one column (:func:`proportional_columns`). Far below float32
#: rounding (6e-8), so merging changes an image by less than storing the matrix in float32
#: does; the reciprocal columns of a least-squares matrix agree to ~1e-10
#: (bench/standing/reconstruction.md).
MERGE_TOLERANCE = 1e-8


def proportional_columns(
    a: np.ndarray, tolerance: float = MERGE_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of proportional columns of ``a`` ``[K, M]``: ``(inputs, weights)``, both ``[2, P]``.

    ``a @ x == a[:, inputs[0]] @ (weights * x[inputs]).sum(0)`` (to ``tolerance``): merged
    column ``p`` is ``a[:, inputs[0, p]]`` and multiplies ``x[inputs[0, p]] + c x[inputs[1, p]]``
    with ``a[:, inputs[1, p]] = c a[:, inputs[0, p]]``. A column without a partner has
    ``inputs[1, p] = M`` (a zero input appended by the caller) and weight 0; ``P <= M``.

    A pair is two non-zero columns that are each other's most parallel column with residual
    ``|a_j - c a_i| <= tolerance |a_j|``. Scale-free and exact in exact arithmetic for the
    reciprocal measurements of a protocol (drive ``ab`` measure ``cd`` and drive ``cd`` measure
    ``ab`` have the same sensitivity, so every least-squares matrix, weighted or not, combines
    them only through ``x_i / s_i^2 + x_j / s_j^2``): half the columns for an adjacent protocol.
    """
    a = np.asarray(a, dtype=np.float64)
    m = a.shape[1]
    g = a.T @ a
    norm = np.sqrt(np.diag(g))
    nonzero = norm > 0
    safe = np.where(nonzero, norm, 1.0)
    cosine = np.abs(g) / safe[:, None] / safe[None, :]
    cosine[~nonzero, :] = -1.0
    cosine[:, ~nonzero] = -1.0
    np.fill_diagonal(cosine, -1.0)
    best = np.argmax(cosine, axis=1) if m > 1 else np.zeros(m, dtype=np.intp)
    i = np.arange(m)
    candidate = np.flatnonzero(nonzero & (best[best] == i) & (i < best))
    j = best[candidate]
    c = g[candidate, j] / g[candidate, candidate]
    residual = np.linalg.norm(a[:, j] - a[:, candidate] * c, axis=0)
    ok = residual <= tolerance * norm[j]
    first, second, c = candidate[ok], j[ok], c[ok]
    partner = np.full(m, m, dtype=np.intp)
    weight = np.zeros(m)
    partner[first] = second
    weight[first] = c
    keep = np.ones(m, dtype=bool)
    keep[second] = False
    base = np.flatnonzero(keep)
    inputs = np.stack([base, partner[base]])
    weights = np.stack([np.ones(base.size), weight[base]])
    return inputs, weights
