"""Fast exact forward solves for conductivity changes confined to a few elements (Woodbury).

A touch changes the sheet conductance only under and around the finger. With the grounded CEM
system ``K0`` of a base conductance factorised once, a changed conductance gives
``K = K0 + dK`` where ``dK`` (stiffness only) is non-zero on the nodes ``a`` of the changed
triangles. The push-through identity

``E^T K^-1 E = E^T K0^-1 E - W_a^T (I + dK_aa G_aa)^-1 dK_aa W_a``

with ``W = K0^-1 E`` (fields of unit currents into each electrode, the ground electrode
excluded) and ``G_aa = (K0^-1)_aa`` (node Green's function on the changed nodes) gives the
electrode transfer matrix of the changed sheet exactly (to round-off) from one dense
``|a| x |a|`` solve. Green's-function columns are computed with the base factorisation the
first time a node becomes active and kept (``|a|`` is a few hundred nodes for a fingertip).
When the change covers too much of the sheet the update falls back to a direct solve of
:class:`~eit_skin.fem.forward.ForwardModel`, which gives the same voltages.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from eit_skin.fem.forward import ForwardModel

_RHS_CHUNK = 4  # SuperLU's multi-RHS solve slows down superlinearly with many columns


class LocalForwardUpdate:
    """Voltages of ``sigma`` that differs from ``sigma_base`` on few triangles.

    Args:
        model: the forward model (mesh, protocol, contact impedance, current).
        sigma_base: ``[n_triangles]`` base sheet conductance, S.
        max_active_fraction: above this fraction of changed nodes, solve directly.
    """

    def __init__(
        self, model: ForwardModel, sigma_base: np.ndarray, max_active_fraction: float = 0.2
    ) -> None:
        self.model = model
        self.sigma_base = np.array(sigma_base, dtype=np.float64)
        self._n_nodes = model.n_nodes
        self._n_el = model.n_electrodes
        self._max_active = int(max_active_fraction * self._n_nodes)
        k0 = model.system_matrix(self.sigma_base).tocsr()
        k0.sort_indices()
        self._k0 = k0
        scale = 1.0 / np.sqrt(k0.diagonal())
        ks = sp.csc_matrix(sp.diags(scale) @ k0 @ sp.diags(scale))
        self._lu = spla.splu(
            ks, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
        self._scale = scale
        n, n_el = self._n_nodes, self._n_el
        rhs = np.zeros((k0.shape[0], n_el - 1))
        rhs[n + np.arange(n_el - 1), np.arange(n_el - 1)] = 1.0
        w = self._solve(rhs)
        self._w_nodes = np.ascontiguousarray(w[:n])  # [n_nodes, n_el - 1]
        self._r0 = w[n:]  # [n_el - 1, n_el - 1] electrode transfer matrix, ohm
        self._green = np.zeros((n, 64), order="F")  # columns of K0^-1 (node rows), cached
        self._n_green = 0
        self._green_slot = np.full(n, -1, dtype=np.int64)
        self.direct_solves = 0
        self.update_solves = 0

    def _solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._scale[:, None] * self._lu.solve(np.asfortranarray(self._scale[:, None] * rhs))

    def _green_block(self, nodes: np.ndarray) -> np.ndarray:
        """``[k, k]`` block ``(K0^-1)[nodes, nodes]``; columns are computed on first use."""
        missing = nodes[self._green_slot[nodes] < 0]
        if missing.size:
            need = self._n_green + missing.size
            if need > self._green.shape[1]:
                grown = np.zeros((self._n_nodes, max(need, 2 * self._green.shape[1])), order="F")
                grown[:, : self._n_green] = self._green[:, : self._n_green]
                self._green = grown
            rhs = np.zeros((self._k0.shape[0], _RHS_CHUNK), order="F")
            for a in range(0, missing.size, _RHS_CHUNK):
                chunk = missing[a : a + _RHS_CHUNK]
                cols = np.arange(chunk.size)
                rhs[:] = 0.0
                rhs[chunk, cols] = 1.0
                sol = self._solve(rhs[:, : chunk.size])
                self._green[:, self._n_green + a + cols] = sol[: self._n_nodes]
            self._green_slot[missing] = self._n_green + np.arange(missing.size)
            self._n_green = need
        return self._green[np.ix_(nodes, self._green_slot[nodes])]

    def transfer_matrix(self, sigma: np.ndarray) -> np.ndarray | None:
        """``[n_el, n_el]`` electrode potentials (V) per unit current (A) into each electrode.

        Grounded at the last electrode (its row and column are zero). ``None`` when the change
        is too large for the update (the caller then solves directly).
        """
        s = np.asarray(sigma, dtype=np.float64)
        changed = s != self.sigma_base
        r = np.zeros((self._n_el, self._n_el))
        if not changed.any():
            r[:-1, :-1] = self._r0
            return r
        active = self.model.nodes_of(changed)
        if active.size > self._max_active:
            return None
        dk = self.model.system_matrix(s) - self._k0
        dk_aa = dk[active][:, active]
        g_aa = self._green_block(active)
        w_a = self._w_nodes[active]
        m = np.eye(active.size) + dk_aa @ g_aa
        x = sla.solve(m, dk_aa @ w_a, check_finite=False)
        r[:-1, :-1] = self._r0 - w_a.T @ x
        return r

    def voltages(self, sigma: np.ndarray) -> np.ndarray:
        """``[M]`` measured voltages (V), protocol order; same as ``model.voltages(sigma)``."""
        r = self.transfer_matrix(sigma)
        if r is None:
            self.direct_solves += 1
            return self.model.voltages(sigma)
        self.update_solves += 1
        potentials = self.model.current_a * (self.model.protocol.current_patterns @ r.T)
        return self.model.protocol.measure(potentials)
