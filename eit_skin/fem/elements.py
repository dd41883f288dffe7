"""The finite elements of a forward model: a sheet's triangles, or a tank's prism columns.

A sheet (2-D) is discretised by its mesh's linear triangles. A tank of depth ``D`` (3-D) is the
same mesh extruded into layers of 6-node prisms (linear triangle x linear interval), the
electrode ring in the middle plane, each electrode a wall patch of the electrode's width x
``electrode_height_m``, top and bottom insulating. The problem is symmetric about the middle
plane, so only the upper half ``0 <= z <= D / 2`` is meshed; the middle plane's natural
boundary condition is the symmetry. The conductivity unknown stays one per triangle: the
conductance of the **electrode plane's slab** ``|z| <= electrode_height_m / 2`` above it
(what a ring of electrodes images: EIDORS's coarse-to-fine mapping of a 2-D model into a
3-D one with ``z_depth``), the rest of the tank at a fixed conductance ``outside_s``. A
conductance ``s`` (S) is the bulk conductivity ``s / (D / 2)`` in the half model (``s / D``
in the whole tank with twice the current: the same potentials), so a tank with full-height
electrodes is all slab, has exactly the sheet's field (z-invariant) and the sheet's voltages.
The contact impedance keeps the sheet's unit (ohm*m per unit electrode width): an electrode of
height ``h`` has surface impedance ``z h`` (ohm*m^2), the same total contact conductance.

Both discretisations are given as element blocks ``B`` ``[P, q, k]`` with ``B^T B`` the
element stiffness per unit sheet conductance: ``u^T K v = sum (B u)(B v)``; the Jacobian's
element products ``int grad u . grad v`` are sums over the ``q`` rows (and, in a tank, over
the column's layers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from eit_skin.fem.mesh import Mesh
from eit_skin.patch.model import Layer

#: Layers of the half electrode height (uniform), then each layer this factor thicker.
ELECTRODE_LAYERS = 2
LAYER_GROWTH = 2.0

_M_EDGE = np.array([[2.0, 1.0], [1.0, 2.0]]) / 6.0  # 1-D mass of a unit interval
_M_TRI = (np.ones((3, 3)) + np.eye(3)) / 12.0  # mass of a unit-area triangle


@dataclass(frozen=True)
class TankDepth:
    """The third dimension of a tank (a 2-D sheet has none).

    Attributes:
        depth_m: the conducting medium's depth, m (the electrode ring at mid-depth).
        electrode_height_m: each electrode's height on the wall, m (<= ``depth_m``): the
            imaged slab's thickness too.
        outside_s: the conductance of the tank outside the slab, S (the homogeneous value).
    """

    depth_m: float
    electrode_height_m: float
    outside_s: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.depth_m) and self.depth_m > 0):
            raise ValueError(f"depth: must be finite and > 0 m, got {self.depth_m}")
        h = self.electrode_height_m
        if not (np.isfinite(h) and 0 < h <= self.depth_m * (1 + 1e-12)):
            raise ValueError(f"electrode height: must be in (0, depth {self.depth_m}] m, got {h}")
        if not (np.isfinite(self.outside_s) and self.outside_s > 0):
            raise ValueError(f"outside conductance: must be finite and > 0 S, got {self.outside_s}")

    def levels(self) -> np.ndarray:
        """``[L + 1]`` node heights of the half model, m: from 0 (the ring's plane) to ``D / 2``.

        :data:`ELECTRODE_LAYERS` uniform layers up to the electrode's top edge, then layers
        growing by :data:`LAYER_GROWTH` (the last one shortened to end at ``D / 2``, merged
        with the one before when it would be thinner than a tenth of it).
        """
        top, half = 0.5 * self.electrode_height_m, 0.5 * self.depth_m
        z = list(np.linspace(0.0, top, ELECTRODE_LAYERS + 1))
        step = top / ELECTRODE_LAYERS
        while z[-1] < half * (1 - 1e-9):
            step *= LAYER_GROWTH
            z.append(min(z[-1] + step, half))
        if len(z) > ELECTRODE_LAYERS + 2 and z[-1] - z[-2] < 0.1 * (z[-2] - z[-3]):
            del z[-2]
        return np.array(z)


def layer_depth(layer: Layer) -> TankDepth | None:
    """The layer's tank depth (``layers[].depth``; electrodes as high as wide), or None."""
    if layer.depth_m is None:
        return None
    return TankDepth(layer.depth_m, layer.electrodes[0].width_m, layer.material.sheet_conductance_s)


@dataclass(frozen=True, eq=False)
class Elements:
    """The element matrices of one discretisation.

    Attributes:
        n_nodes: node count (a tank: the mesh's nodes at each level, the ring's plane first).
        nodes: ``[P, k]`` node indices of each element.
        blocks: ``[P, q, k]`` ``B`` with ``B^T B`` the element stiffness per unit sheet
            conductance (dimensionless: 1 S of sheet conductance gives ``B^T B`` siemens).
        columns: number of conductivity unknowns (the mesh's triangles); element ``p``
            belongs to triangle ``p % columns`` (elements ordered level by level).
        sensed: the first ``sensed`` elements carry the unknowns (a sheet: all; a tank: the
            slab's), the others the fixed ``outside_s``.
        contact: per electrode ``(nodes [e, c], mass [e, c, c])``: the electrode surface's
            elements and their mass matrices per unit contact impedance, m (a sheet: edge
            length; a tank: area over the electrode's height).
    """

    n_nodes: int
    nodes: np.ndarray
    blocks: np.ndarray
    columns: int
    contact: tuple[tuple[np.ndarray, np.ndarray], ...]
    sensed: int

    def stiffness(self) -> np.ndarray:
        """``[P, k, k]`` element stiffness per unit sheet conductance, ``B^T B``."""
        return np.einsum("pqi,pqj->pij", self.blocks, self.blocks)

    def operator(self) -> sp.csr_matrix:
        """``[q P, n_nodes]``: ``(B u)`` of every sensed element, rows ``(row of B, element)``."""
        p, q, k = self.blocks[: self.sensed].shape
        rows = np.broadcast_to(
            (np.arange(q)[None, :, None] * p) + np.arange(p)[:, None, None], (p, q, k)
        )
        cols = np.broadcast_to(self.nodes[:p, None, :], (p, q, k))
        return sp.csr_matrix(
            (self.blocks[:p].ravel(), (rows.ravel(), cols.ravel())), shape=(q * p, self.n_nodes)
        )

    @property
    def rows_per_column(self) -> int:
        """``q`` times the sensed elements per column: the product rows of one unknown."""
        return self.blocks.shape[1] * (self.sensed // self.columns)

    def owner(self) -> np.ndarray:
        """``[P]`` the unknown of each element; ``columns`` (one past the last) outside."""
        p = np.arange(len(self.nodes))
        return np.where(p < self.sensed, p % self.columns, self.columns)


def hat_gradients(nodes: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle areas ``[t]`` m^2 and hat-function gradients ``[t, 2, 3]`` 1/m.

    ``grads[:, d, j]`` is component ``d`` of node ``j``'s gradient; a degenerate or clockwise
    triangle is refused.
    """
    p = nodes[tri]  # [t, 3, 2]
    e1 = p[:, 2] - p[:, 1]  # edge opposite node 0
    e2 = p[:, 0] - p[:, 2]
    e3 = p[:, 1] - p[:, 0]
    area = 0.5 * (e3[:, 0] * (-e2[:, 1]) - e3[:, 1] * (-e2[:, 0]))
    if np.any(area <= 0):
        bad = int(np.flatnonzero(area <= 0)[0])
        raise ValueError(
            f"mesh.triangles: triangle {bad} is degenerate or clockwise (area {area[bad]:g})"
        )
    edges = np.stack([e1, e2, e3], axis=1)  # [t, 3, 2]
    # grad phi_j = perp(edge opposite j) / (2 area), perp(x, y) = (-y, x)
    grads = np.stack([-edges[..., 1], edges[..., 0]], axis=1) / (2 * area)[:, None, None]
    return area, grads


def electrode_edge_lengths(mesh: Mesh, nodes: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per electrode ``(edges [e, 2], lengths [e])`` m, checked (non-empty, in range, > 0)."""
    out = []
    for el_i, edge_arr in enumerate(mesh.electrode_edges):
        ed = np.asarray(edge_arr, dtype=np.int64).reshape(-1, 2)
        if ed.shape[0] == 0:
            raise ValueError(f"mesh.electrode_edges[{el_i}]: electrode has no boundary edge")
        if ed.min() < 0 or ed.max() >= len(nodes):
            raise ValueError(f"mesh.electrode_edges[{el_i}]: node index out of range")
        length = np.linalg.norm(nodes[ed[:, 1]] - nodes[ed[:, 0]], axis=1)
        if np.any(length <= 0):
            raise ValueError(f"mesh.electrode_edges[{el_i}]: zero-length edge")
        out.append((ed, length))
    return out


def sheet_elements(mesh: Mesh, nodes: np.ndarray, tri: np.ndarray) -> Elements:
    """The sheet's linear triangles: ``B = sqrt(area) grad`` ``[t, 2, 3]``, edge contacts."""
    area, grads = hat_gradients(nodes, tri)
    contact = tuple(
        (ed, length[:, None, None] * _M_EDGE) for ed, length in electrode_edge_lengths(mesh, nodes)
    )
    return Elements(
        n_nodes=len(nodes),
        nodes=tri,
        blocks=np.sqrt(area)[:, None, None] * grads,
        columns=len(tri),
        contact=contact,
        sensed=len(tri),
    )


def tank_elements(mesh: Mesh, nodes: np.ndarray, tri: np.ndarray, depth: TankDepth) -> Elements:
    """The half tank's prisms (see the module docstring), ``B`` ``[L t, 7, 6]``.

    Prism node ``2 i + j``: triangle node ``i`` at the layer's bottom (``j = 0``) or top.
    Its stiffness ``A_tri (x) M_z + M_tri (x) A_z`` factors as ``[G (x) C_z; F (x) d_z]``
    with ``G = sqrt(area) grad``, ``C_z^T C_z = M_z``, ``F^T F = M_tri``, ``d_z^T d_z = A_z``.
    """
    area, grads = hat_gradients(nodes, tri)
    z = depth.levels()
    half = 0.5 * depth.depth_m
    dz = np.diff(z)  # [L]
    n2, n_t, n_l = len(nodes), len(tri), len(dz)
    g = np.sqrt(area)[:, None, None] * grads  # [t, 2, 3]
    f = np.sqrt(area)[:, None, None] * np.linalg.cholesky(_M_TRI).T[None]  # [t, 3, 3]
    cz = np.sqrt(dz)[:, None, None] * np.linalg.cholesky(_M_EDGE).T[None]  # [L, 2, 2]
    dd = (np.array([[1.0, -1.0]]) / np.sqrt(dz)[:, None])[:, None, :]  # [L, 1, 2]
    upper = np.einsum("tai,lbj->ltabij", g, cz).reshape(n_l, n_t, 4, 6)
    lower = np.einsum("tai,lbj->ltabij", f, dd).reshape(n_l, n_t, 3, 6)
    blocks = np.concatenate([upper, lower], axis=2).reshape(n_l * n_t, 7, 6) / np.sqrt(half)
    level = np.arange(n_l)[:, None, None, None] + np.arange(2)[None, None, None, :]
    prism = (tri[None, :, :, None] + level * n2).reshape(n_l * n_t, 6)
    top = 0.5 * depth.electrode_height_m
    wall = np.flatnonzero(z[1:] <= top * (1 + 1e-9))  # the layers the electrodes cover
    contact = []
    for ed, length in electrode_edge_lengths(mesh, nodes):
        quad = (ed[None, :, :, None] + (wall[:, None, None, None] + np.arange(2)) * n2).reshape(
            -1, 4
        )
        mass = np.einsum("e,l,ij,ab->leiajb", length, dz[wall], _M_EDGE, _M_EDGE).reshape(-1, 4, 4)
        contact.append((quad, mass / top))
    return Elements(
        n_nodes=n2 * (n_l + 1),
        nodes=prism,
        blocks=blocks,
        columns=n_t,
        contact=tuple(contact),
        sensed=len(wall) * n_t,
    )
