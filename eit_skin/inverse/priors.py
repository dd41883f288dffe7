"""Regularisation priors for EIT reconstruction on a triangle mesh.

A prior is a sparse symmetric positive-definite matrix ``P = R^T R`` of shape
``[n_triangles, n_triangles]`` acting on per-element conductivity changes
(dimensionless, delta sigma / sigma0). The reconstruction only ever needs
``P^-1 B`` for a few hundred right-hand sides ``B``, so a :class:`Prior` holds
a sparse factorisation (or a diagonal) and applies its inverse without forming
a dense ``N x N`` matrix.

Solving: ``P`` is factorised once by SuperLU (symmetric mode, minimum-degree order,
no pivoting), and ``P^-1 B`` for many columns is done by :class:`SparseFactor`, which
runs the two triangular solves *level by level* over the elimination tree: all rows at
the same tree depth are independent, so each level is one sparse-times-dense product
over all ``k`` columns. Cost ``O(nnz(L) k)`` plus one small step per tree level (a few
hundred for a 10k-element mesh), instead of SuperLU's own multi-column solve, which is
much slower for a few hundred columns.

Kinds:
    ``tikhonov``: ``P = I``.
    ``laplace``: graph Laplacian of the element adjacency (elements sharing an
        edge) plus ``diagonal_weight * I`` so that ``P`` is positive definite.
    ``noser``: ``P = diag(J^T J)^exponent`` (Cheney et al. 1990), needs the
        Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from eit_skin.fem.mesh import Mesh
from eit_skin.patch.model import PRIOR_KINDS  # the schema's names; make_prior builds each


def element_adjacency(mesh: Mesh) -> sp.csr_matrix:
    """``[n_triangles, n_triangles]`` 0/1 CSR: 1 where two triangles share an edge."""
    t = np.asarray(mesh.triangles, dtype=np.int64)
    n = t.shape[0]
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    edges.sort(axis=1)
    owner = np.tile(np.arange(n, dtype=np.int64), 3)
    key = edges[:, 0] * (int(mesh.n_nodes) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    shared = np.flatnonzero(key_sorted[1:] == key_sorted[:-1])
    a = owner[order[shared]]
    b = owner[order[shared + 1]]
    data = np.ones(2 * a.size)
    adj = sp.coo_matrix((data, (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))
    adj = adj.tocsr()
    adj.data[:] = 1.0
    return adj


def laplace_matrix(mesh: Mesh, diagonal_weight: float = 1e-2) -> sp.csc_matrix:
    """Graph Laplacian of the element adjacency plus ``diagonal_weight * I``, CSC ``[N, N]``."""
    adj = element_adjacency(mesh)
    degree = np.asarray(adj.sum(axis=1)).ravel()
    return sp.csc_matrix(sp.diags(degree + diagonal_weight) - adj)


class SparseFactor:
    """``A^-1 B`` for a sparse symmetric positive-definite ``A`` ``[n, n]`` and dense ``B``.

    ``A`` is factorised once (SuperLU, ``Pr A Pc = L U``, symmetric mode); the triangular
    solves are scheduled by elimination-tree depth (see the module docstring). If the factor's
    structure does not allow that schedule (it always does for a symmetric structure without
    pivoting; checked), SuperLU's own solve is used in chunks of a few columns.
    """

    _CHUNK = 4  # SuperLU's multi-column solve slows down superlinearly with more columns

    def __init__(self, a: sp.spmatrix) -> None:
        a = sp.csc_matrix(a)
        self.n = int(a.shape[0])
        self._lu = spla.splu(
            a,
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        self._perm_r = self._lu.perm_r
        self._perm_c = self._lu.perm_c
        lower = sp.tril(self._lu.L.tocsr(), -1).tocsr()
        upper = self._lu.U.tocsr()
        self._diag = upper.diagonal()
        upper = (sp.diags(1.0 / self._diag) @ sp.triu(upper, 1)).tocsr()  # unit upper
        depth = _tree_depth(lower)
        self._levels: tuple[list, list] | None = None
        if depth is not None and _schedule_ok(lower, upper, depth):
            self._levels = (
                _level_blocks(lower, -depth),  # forward: deepest rows first
                _level_blocks(upper, depth),  # backward: the root first
            )

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``A^-1 b`` for ``b`` ``[n]`` or ``[n, k]`` (float64)."""
        b = np.asarray(b, dtype=np.float64)
        single = b.ndim == 1
        b2 = b[:, None] if single else b
        if self._levels is None:
            out = np.empty_like(b2)
            for a in range(0, b2.shape[1], self._CHUNK):
                out[:, a : a + self._CHUNK] = self._lu.solve(
                    np.asfortranarray(b2[:, a : a + self._CHUNK])
                )
            return out[:, 0] if single else out
        x = np.empty(b2.shape)  # C order: every level multiplies the whole block
        x[self._perm_r] = b2
        forward, backward = self._levels
        for rows, block in forward:  # L y = Pr b, unit diagonal
            if block is not None:
                x[rows] -= block @ x
        x /= self._diag[:, None]
        for rows, block in backward:  # U z = y with U = diag (unit upper)
            if block is not None:
                x[rows] -= block @ x
        out = x[self._perm_c]
        return out[:, 0] if single else out


def _tree_depth(lower: sp.csr_matrix) -> np.ndarray | None:
    """Depth of every row in the elimination tree of the strictly lower factor ``[n, n]``.

    ``parent(j)`` = first row below ``j`` with a non-zero in column ``j``; depth by pointer
    jumping (``log2`` of the tree height vectorised rounds).
    """
    n = lower.shape[0]
    csc = lower.tocsc()
    csc.sort_indices()
    has = np.diff(csc.indptr) > 0
    parent = np.arange(n)
    parent[has] = csc.indices[csc.indptr[:-1][has]]
    depth = (parent != np.arange(n)).astype(np.int64)
    anc = parent.copy()
    for _ in range(64):
        nxt = anc[anc]
        if np.array_equal(nxt, anc):
            return depth
        depth = depth + np.where(anc != nxt, depth[anc], 0)
        anc = nxt
    return None


def _schedule_ok(lower: sp.csr_matrix, upper: sp.csr_matrix, depth: np.ndarray) -> bool:
    """True if every dependency is on a strictly shallower (lower: deeper) row."""
    lo = lower.tocoo()
    up = upper.tocoo()
    return bool(np.all(depth[lo.col] > depth[lo.row]) and np.all(depth[up.col] < depth[up.row]))


def _level_blocks(m: sp.csr_matrix, key: np.ndarray) -> list:
    """Rows grouped by increasing ``key`` with their rows of ``m`` (``None`` if empty)."""
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [key.size]])
    permuted = m[order].tocsr()
    blocks = []
    for a, b in zip(starts, ends, strict=True):
        block = permuted[a:b]
        blocks.append((order[a:b], block if block.nnz else None))
    return blocks


@dataclass(frozen=True, eq=False)
class Prior:
    """A factorised prior ``P`` on ``N`` elements.

    Attributes:
        kind: ``"tikhonov"``, ``"laplace"`` or ``"noser"``.
        matrix: sparse ``[N, N]`` SPD matrix ``P``.
        diagonal: ``[N]`` diagonal of ``P`` when ``P`` is diagonal, else ``None``.
    """

    kind: str
    matrix: sp.csc_matrix
    diagonal: np.ndarray | None
    _lu: object | None = None

    @property
    def n(self) -> int:
        return int(self.matrix.shape[0])

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Return ``P^-1 b`` for ``b`` of shape ``[N]`` or ``[N, k]`` (float64)."""
        b = np.asarray(b, dtype=np.float64)
        if self.diagonal is not None:
            return b / (self.diagonal if b.ndim == 1 else self.diagonal[:, None])
        return self._lu.solve(b)  # type: ignore[union-attr]  # a SparseFactor

    def quadratic(self, x: np.ndarray) -> float:
        """``x^T P x`` for ``x`` ``[N]``."""
        return float(x @ (self.matrix @ x))


def make_prior(
    kind: str,
    mesh: Mesh,
    jacobian: np.ndarray | None = None,
    *,
    laplace_diagonal: float = 1e-2,
    noser_exponent: float = 0.5,
) -> Prior:
    """Build and factorise a prior.

    Args:
        kind: one of :data:`PRIOR_KINDS`.
        mesh: the inverse mesh (``N`` triangles).
        jacobian: ``[M, N]`` Jacobian in the data space used for imaging; needed for ``noser``.
        laplace_diagonal: weight of the identity added to the Laplacian (> 0).
        noser_exponent: exponent ``p`` of ``diag(J^T J)^p``.

    Raises:
        ValueError: unknown kind, or ``noser`` without a Jacobian.
    """
    n = mesh.n_triangles
    if kind == "tikhonov":
        d = np.ones(n)
        return Prior(kind, sp.csc_matrix(sp.identity(n)), d)
    if kind == "noser":
        if jacobian is None:
            raise ValueError("prior 'noser' needs the Jacobian")
        j = np.asarray(jacobian, dtype=np.float64)
        if j.shape[1] != n:
            raise ValueError(f"prior 'noser': Jacobian has {j.shape[1]} columns, mesh has {n}")
        d = np.einsum("mn,mn->n", j, j)
        scale = float(d.max()) if d.size and d.max() > 0 else 1.0
        # floor insensitive elements so P stays positive definite
        d = np.maximum(d / scale, 1e-6) ** noser_exponent
        return Prior(kind, sp.csc_matrix(sp.diags(d)), d)
    if kind == "laplace":
        if laplace_diagonal <= 0:
            raise ValueError("prior 'laplace': laplace_diagonal must be > 0")
        p = laplace_matrix(mesh, laplace_diagonal)
        return Prior(kind, p, None, SparseFactor(p))
    if kind == "greit":
        raise ValueError(
            "'greit' is a method, not a prior: eit_skin.inverse.greit.greit_matrix or "
            "eit_skin.inverse.dispatch.make_reconstructor('greit', ...)"
        )
    raise ValueError(f"unknown prior {kind!r}; expected one of {', '.join(PRIOR_KINDS)}")
