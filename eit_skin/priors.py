"""Regularisation priors for EIT reconstruction on a triangle mesh.

A prior is a sparse symmetric positive-definite matrix ``P = R^T R`` of shape
``[n_triangles, n_triangles]`` acting on per-element conductivity changes
(dimensionless, delta sigma / sigma0). The reconstruction only ever needs
``P^-1 B`` for a few hundred right-hand sides ``B``, so a :class:`Prior` holds
a sparse factorisation (or a diagonal) and applies its inverse without forming
a dense ``N x N`` matrix.

Kinds:
    ``tikhonov``: ``P = I``.
    ``laplace``: graph Laplacian of the element adjacency (elements sharing an
        edge) plus ``diagonal_weight * I`` so that ``P`` is positive definite.
    ``noser``: ``P = diag(J^T J)^exponent`` (Cheney et al. 1990), needs the
        Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from eit_skin.mesh import Mesh

PriorKind = Literal["tikhonov", "laplace", "noser"]
PRIOR_KINDS: tuple[str, ...] = ("tikhonov", "laplace", "noser")


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
        return self._lu.solve(b)  # type: ignore[union-attr]

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
        lu = spla.splu(p, permc_spec="MMD_AT_PLUS_A")
        return Prior(kind, p, None, lu)
    raise ValueError(f"unknown prior {kind!r}; expected one of {', '.join(PRIOR_KINDS)}")
