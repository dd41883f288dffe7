"""GREIT-style trained one-step reconstruction (Adler et al., Physiol. Meas. 30, 2009).

The reconstruction matrix ``R`` minimises, over a training set of ``K`` small circular
targets spread over the sheet,

    ``sum_k || d_k - R y_k ||^2 + lambda^2 || R ||_F^2``,    ``y_k = J x_k``,

where ``x_k`` ``[N]`` is the target (the covered fraction of every element, relative
contrast 1), ``J`` ``[M, N]`` the relative Jacobian (linearised simulation) and ``d_k``
``[N]`` the *desired image*: a smooth, non-negative Gaussian blob centred on the target with
the target's integral. In closed form (``X = [x_k]`` ``[N, K]``, ``D = [d_k]`` ``[N, K]``,
``Y = J X`` ``[M, K]``, white noise on the relative data)

    ``R = (D Y^T) (Y Y^T + lambda^2 I)^-1``,

the dual form of :mod:`eit_skin.inverse.one_step` with ``K = Y Y^T`` ``[M, M]`` and
``D Y^T`` ``[N, M]`` in place of ``J P^-1 J^T`` and ``P^-1 J^T``. Because the desired images
have no negative lobes and are centred on the targets, the trained matrix has far less
ringing and position error than a smoothness prior. Cost: ``O(nnz(X) M + nnz(D) M + M^2 K)``,
linear in ``N``; no ``N x N`` matrix.

Every row of ``R`` is an independent least-squares fit (one element's desired values), so the
element sizes need no weighting. The training set depends only on the mesh (deterministic
lattice of target centres), so a cached relative Jacobian rebuilds the same matrix.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from eit_skin.fem.image_grid import locate_points
from eit_skin.fem.mesh import Mesh
from eit_skin.inverse.one_step import ReconstructionMatrix, checked_jacobian, linear_matrix

#: Target radius as a fraction of the sheet's equivalent radius ``sqrt(area / pi)``.
TARGET_RADIUS = 0.05
#: Standard deviation of the desired Gaussian blob, fraction of the equivalent radius.
BLOB_WIDTH = 0.10
#: Height (relative to the core) and width (multiple of the core's) of the desired blob's tail.
TAIL = 0.07
TAIL_WIDTH = 4.0
#: Fixed-point iterations that move blob centres so the quarter-max centre is on the target.
_CENTRE_ITERATIONS = 4
#: Training targets (approximately; a hexagonal lattice of centres inside the sheet).
N_TARGETS = 600
#: Sample points per element used to compute the covered fraction of each element.
_SAMPLES = 4


@dataclass(frozen=True, eq=False)
class TrainingSet:
    """Training targets and desired images on one mesh.

    Attributes:
        centres: ``[K, 2]`` target centres, metres.
        radius_m: target radius, metres.
        targets: ``[N, K]`` sparse CSC, covered fraction of each element (0..1).
        desired: ``[N, K]`` dense, desired image of each target (relative change).
    """

    centres: np.ndarray
    radius_m: float
    targets: sp.csc_matrix
    desired: np.ndarray

    @property
    def n_targets(self) -> int:
        return int(self.centres.shape[0])


def equivalent_radius(mesh: Mesh) -> float:
    """``sqrt(area / pi)`` of the sheet (holes excluded), metres."""
    return float(np.sqrt(np.abs(mesh.areas).sum() / np.pi))


def target_centres(mesh: Mesh, n_targets: int = N_TARGETS) -> np.ndarray:
    """``[K, 2]`` centres on a hexagonal lattice over the sheet, inside a triangle (metres).

    The lattice pitch is chosen so that about ``n_targets`` points fall inside the sheet.
    """
    if n_targets < 1:
        raise ValueError(f"n_targets must be >= 1, got {n_targets}")
    area = float(np.abs(mesh.areas).sum())
    pitch = float(np.sqrt(2.0 * area / (np.sqrt(3.0) * n_targets)))
    lo = mesh.nodes.min(axis=0)
    hi = mesh.nodes.max(axis=0)
    dy = pitch * np.sqrt(3.0) / 2.0
    ny = int(np.ceil((hi[1] - lo[1]) / dy)) + 1
    nx = int(np.ceil((hi[0] - lo[0]) / pitch)) + 2
    iy, ix = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    centre = 0.5 * (lo + hi)
    x = centre[0] + (ix - nx // 2 + 0.5 * (iy % 2)) * pitch
    y = centre[1] + (iy - ny // 2) * dy
    pts = np.column_stack([x.ravel(), y.ravel()])
    return pts[locate_points(mesh, pts) >= 0]


def _blobs(
    tree: cKDTree, centres: np.ndarray, width: float, tail: float, reach: float
) -> sp.csc_matrix:
    """``[N, K]`` ``exp(-r^2 / 2 w^2) + tail exp(-r^2 / 2 (TAIL_WIDTH w)^2)`` within ``reach``.

    ``N = tree.n``: the points of ``tree`` (element centroids); ``K``: the ``centres``.
    """
    near = cKDTree(centres).sparse_distance_matrix(tree, reach, output_type="coo_matrix")
    return sp.csc_matrix(
        (_blob_profile(near.data, width, tail), (near.col, near.row)),
        shape=(tree.n, centres.shape[0]),
    )


def _blob_profile(r: np.ndarray, width: float, tail: float) -> np.ndarray:
    """Desired image at distance ``r`` (metres) from the blob centre, peak ``1 + tail``."""
    return _blob_profile_sq(np.asarray(r, dtype=np.float64) ** 2, width, tail)


def _blob_profile_sq(r2: np.ndarray, width: float, tail: float) -> np.ndarray:
    """:func:`_blob_profile` of the squared distance ``r2`` (m^2); overwrites ``r2``.

    With ``TAIL_WIDTH = 4`` the core ``exp(-a)`` is the tail ``exp(-a / 16)`` squared four
    times, so only one ``exp`` per entry is evaluated.
    """
    out = np.multiply(r2, -0.5 / (width * TAIL_WIDTH) ** 2, out=r2)
    np.exp(out, out=out)  # tail
    if TAIL_WIDTH == 4.0:
        core = out * out
        for _ in range(3):
            np.multiply(core, core, out=core)
    else:
        core = out ** (TAIL_WIDTH**2)
    out *= tail
    out += core
    return out


def _quarter_max_centres(blob: sp.csc_matrix, areas: np.ndarray, cent: np.ndarray) -> np.ndarray:
    """``[K, 2]`` area-weighted centre of gravity of each column's quarter-maximum set."""
    peak = blob.max(axis=0).toarray().ravel()
    coo = blob.tocoo()
    keep = coo.data >= 0.25 * peak[coo.col]
    w = coo.data[keep] * areas[coo.row[keep]]
    col = coo.col[keep]
    k = blob.shape[1]
    mass = np.maximum(np.bincount(col, weights=w, minlength=k), 1e-300)
    x = np.bincount(col, weights=w * cent[coo.row[keep], 0], minlength=k) / mass
    y = np.bincount(col, weights=w * cent[coo.row[keep], 1], minlength=k) / mass
    return np.column_stack([x, y])


def _sample_points(mesh: Mesh) -> np.ndarray:
    """``[N, S, 2]`` interior sample points of every triangle (barycentric sub-triangle centres)."""
    p = np.asarray(mesh.nodes, dtype=np.float64)[mesh.triangles]  # [N, 3, 2]
    # centroids of the 4 sub-triangles of the midpoint subdivision
    bary = (
        np.array(
            [[4, 1, 1], [1, 4, 1], [1, 1, 4], [2, 2, 2]],
            dtype=np.float64,
        )[:_SAMPLES]
        / 6.0
    )
    return np.einsum("sk,nkd->nsd", bary, p)


def training_set(
    mesh: Mesh,
    n_targets: int = N_TARGETS,
    target_radius: float = TARGET_RADIUS,
    blob_width: float = BLOB_WIDTH,
    tail: float = TAIL,
) -> TrainingSet:
    """Targets and desired images on ``mesh`` (see the module docstring).

    Args:
        mesh: the inverse mesh, metres.
        n_targets: approximate number of training targets.
        target_radius: target radius, fraction of :func:`equivalent_radius`.
        blob_width: standard deviation of the desired Gaussian, fraction of the same.
        tail: height of a wide (``TAIL_WIDTH`` x) low Gaussian added under the blob.
    """
    if not (target_radius > 0 and blob_width > 0):
        raise ValueError("target_radius and blob_width must be > 0")
    size = equivalent_radius(mesh)
    r = target_radius * size
    w = blob_width * size
    centres = target_centres(mesh, n_targets)
    k = centres.shape[0]
    n = mesh.n_triangles
    areas = np.abs(mesh.areas)
    cent = mesh.centroids
    reach = float(np.sqrt(2.0 * areas.max())) * 2.0  # longest edge bound of a quality mesh
    tree_c = cKDTree(cent)
    tree_t = cKDTree(centres)
    # covered fraction: elements whose centroid is within r + reach, sampled
    near = tree_t.sparse_distance_matrix(tree_c, r + reach, output_type="coo_matrix")
    ti, ei = near.row, near.col
    samples = _sample_points(mesh)  # [N, S, 2]
    d2 = ((samples[ei] - centres[ti][:, None, :]) ** 2).sum(axis=2)
    frac = (d2 < r * r).mean(axis=1)
    # the target must cover something: fall back to the element that holds the centre
    hit = np.bincount(ti, weights=frac, minlength=k)
    owner = locate_points(mesh, centres)
    empty = np.flatnonzero(hit == 0)
    ti = np.concatenate([ti, empty])
    ei = np.concatenate([ei, owner[empty]])
    frac = np.concatenate([frac, np.full(empty.size, min(1.0, np.pi * r * r / areas.mean()))])
    keep = frac > 0
    targets = sp.csc_matrix((frac[keep], (ei[keep], ti[keep])), shape=(n, k))
    # desired images: Gaussian blobs (core + low wide tail), same integral as the target;
    # blob centres shifted so that the blob's quarter-maximum centre of gravity (what the
    # position error measures) lies on the target even where the sheet edge truncates it.
    # The quarter-max set lies well within 3 w, so the shift is found on that neighbourhood.
    shifted = centres.copy()
    for _ in range(_CENTRE_ITERATIONS):
        blob = _blobs(tree_c, shifted, w, tail, 3.0 * w)
        step = centres - _quarter_max_centres(blob, areas, cent)
        shifted = centres + _clip_norm(shifted - centres + step, w)
    d2 = (cent**2).sum(axis=1)[:, None] + (shifted**2).sum(axis=1)[None, :] - 2 * cent @ shifted.T
    desired = _blob_profile_sq(np.maximum(d2, 0.0, out=d2), w, tail)  # [N, K]
    mass_target = targets.T @ areas  # [K] m^2
    desired *= mass_target / np.maximum(areas @ desired, 1e-300)
    return TrainingSet(centres=centres, radius_m=r, targets=targets, desired=desired)


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    """Rows of ``v`` ``[K, 2]`` scaled down to at most ``limit`` long."""
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return v * np.minimum(1.0, limit / np.maximum(norm, 1e-300))


@dataclass(frozen=True, eq=False)
class GreitModel:
    """A training set applied to a relative Jacobian: the pieces of the dual form.

    Attributes:
        centres: ``[K, 2]`` training target centres, metres.
        responses: ``[M, K]`` simulated relative voltage changes ``Y = J X`` (all channels).
        gram_all: ``[M, M]`` ``Y Y^T`` on all channels.
        desired_responses: ``[N, M]`` ``D Y^T`` on all channels.
        jacobian: ``[M, N]`` the relative Jacobian it was built from.
        mesh: the imaging mesh (``N`` elements).
    """

    method: ClassVar[str] = "greit"
    centres: np.ndarray
    responses: np.ndarray
    gram_all: np.ndarray
    desired_responses: np.ndarray
    jacobian: np.ndarray
    mesh: Mesh

    @classmethod
    def build(
        cls, jacobian: np.ndarray, mesh: Mesh, training: TrainingSet | None = None
    ) -> GreitModel:
        """Simulate the training targets with the relative Jacobian ``[M, N]`` on ``mesh``.

        ``training``: default :func:`training_set` of ``mesh`` (which depends only on the
        mesh, so the same Jacobian always gives the same matrix).
        """
        j = checked_jacobian(jacobian, mesh)
        training = training_set(mesh) if training is None else training
        if j.shape[1] != training.targets.shape[0]:
            raise ValueError(
                f"Jacobian has {j.shape[1]} columns, training set {training.targets.shape[0]}"
            )
        y = np.ascontiguousarray(np.asarray(training.targets.T @ j.T).T)  # [M, K]
        k = y @ y.T
        return cls(
            centres=training.centres,
            responses=y,
            gram_all=0.5 * (k + k.T),
            desired_responses=training.desired @ y.T,
            jacobian=j,
            mesh=mesh,
        )

    def gram(self, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(Y_c Y_c^T [Mu, Mu], D Y_c^T [N, Mu])`` on the used channels ``[Mu]``.

        Leaving channels out only drops rows of ``Y``, so both are slices of the full ones.
        """
        ch = np.asarray(channels, dtype=np.int64)
        if ch.size == self.gram_all.shape[0] and np.array_equal(ch, np.arange(ch.size)):
            return self.gram_all, self.desired_responses
        return self.gram_all[np.ix_(ch, ch)], self.desired_responses[:, ch]


def greit_matrix(
    jacobian: np.ndarray,
    mesh: Mesh,
    hyperparameter: float | None = None,
    noise_figure: float | None = None,
) -> ReconstructionMatrix:
    """The GREIT-trained matrix from a relative Jacobian ``[M, N]`` on ``mesh`` (no prior).

    Trained on :func:`training_set` of ``mesh``; ``hyperparameter`` None: chosen for
    ``noise_figure`` (:func:`~eit_skin.inverse.one_step.linear_matrix`). Another training
    set: ``linear_matrix(GreitModel.build(jacobian, mesh, training), h)``.
    """
    return linear_matrix(GreitModel.build(jacobian, mesh), hyperparameter, noise_figure)
