"""The regularised dual-form algebra shared by every reconstruction method.

All methods solve ``(K + lambda^2 I) u = r`` for an ``M x M`` symmetric positive
semi-definite ``K`` (one-step: ``J P^-1 J^T``; GREIT: ``Y Y^T``; Gauss-Newton: ``J P^-1 J^T``
at the current linearisation) and scale the regularisation with the data:
``lambda^2 = h^2 * trace(K) / M``, so the hyperparameter ``h`` is dimensionless and
comparable between meshes, channel subsets and methods. The hyperparameter choice
(:mod:`eit_skin.inverse.hyperparameter`) uses the same two functions, so a chosen ``h``
means the same ``lambda^2`` wherever it is applied.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla


def lambda_squared(h: float, trace: float, m: int) -> float:
    """``lambda^2 = h^2 * trace(K) / M`` (dimensionless ``h``; ``trace(K) <= 0`` counts as ``M``).

    Args:
        h: the hyperparameter.
        trace: ``trace(K)`` of the ``[M, M]`` matrix being regularised.
        m: ``M``, channels used.
    """
    scale = float(trace) / max(int(m), 1)
    return float(h) ** 2 * (scale if scale > 0 else 1.0)


def regularised_inverse(k: np.ndarray, lam2: float) -> np.ndarray:
    """``(K + lambda^2 I)^-1`` ``[M, M]`` by Cholesky (``K`` symmetric positive semi-definite).

    Only a Cholesky factorisation is used: LAPACK's symmetric eigensolver is level-2 BLAS
    bound and, with a multi-threaded OpenBLAS on a busy machine, took ~1 s for ``M = 208``
    (a Cholesky factorisation takes ~0.3 ms).
    """
    c = k + lam2 * np.eye(k.shape[0])
    low = np.linalg.cholesky(c)
    w = sla.solve_triangular(low, np.eye(k.shape[0]), lower=True, check_finite=False)
    return w.T @ w
