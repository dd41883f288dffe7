"""Complete-electrode-model forward solver: sheet conductance -> electrode voltages, Jacobian.

Physics (2-D sheet, SI units): ``div(sigma grad u) = 0`` in the sheet, ``sigma`` the sheet
conductance per triangle (siemens, i.e. 1 / (ohm per square)); on electrode ``l`` (boundary
edges ``e_l``) ``sigma du/dn = (U_l - u) / z_l`` with contact impedance ``z_l`` (ohm*metre:
current per unit boundary length = voltage drop / z), ``int_{e_l} (U_l - u) / z_l ds = I_l``
(current entering the sheet through electrode ``l``, amperes), and ``sigma du/dn = 0`` on the
free boundary (including holes).

Discretisation: linear triangles; unknowns are the node potentials ``u`` and the electrode
potentials ``U``. The system matrix ``K = [[A + B, -C], [-C^T, D]]`` (stiffness ``A`` scales
with sigma, ``B``, ``C``, ``D`` are the constant contact terms) is symmetric and positive
semi-definite with the constants as null space.

Ground: the last electrode's potential is fixed to 0 V while solving (its row and column are
dropped, which leaves a symmetric positive-definite matrix); the reported potentials are then
shifted so that **the electrode potentials of every injection sum to zero**. Voltage
differences (the measurements) do not depend on this choice.

Solving: the grounded matrix is scaled symmetrically by its diagonal
(``S K S`` with ``S = diag(K)^(-1/2)``), which removes the scale of sigma and of ``1/z`` and
keeps the factorisation accurate at large conductivity contrasts, then factorised
once per conductivity with SuperLU (``scipy.sparse.linalg.splu``) using the minimum-degree
ordering of ``K^T + K`` (``MMD_AT_PLUS_A``, right for a symmetric matrix) with diagonal pivoting
(no row interchanges are needed for an SPD matrix, so the fill-reducing order is kept).
One solve with ``n_el - 1`` right-hand sides (unit current into each non-ground electrode)
gives a field basis ``W``; every injection and every measurement "lead field" is a
difference of two basis columns, so ``solve`` and ``jacobian`` share a single factorisation.

Jacobian (adjoint / reciprocity): for measurement ``V = U_p - U_q`` during injection ``i``,
``dV/dsigma_t = -int_t grad u_i . grad v_pq dA`` where ``v_pq`` is the field for a unit current
entering at ``p`` and leaving at ``q``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from eit_skin.fem.elements import Elements, TankDepth, sheet_elements, tank_elements
from eit_skin.fem.mesh import Mesh
from eit_skin.patch.protocol import Protocol


@dataclass(frozen=True, eq=False)
class ForwardSolution:
    """Result of one forward solve.

    Attributes:
        node_potentials: ``[n_inj, n_nodes]`` V (NaN on nodes no triangle uses).
        electrode_potentials: ``[n_inj, n_el]`` V, summing to zero per injection.
        electrode_currents: ``[n_inj, n_el]`` A entering the sheet through each electrode,
            computed back from the potentials (Kirchhoff check: ``+current_a`` at the
            source, ``-current_a`` at the sink, 0 elsewhere).
        voltages: ``[M]`` V in protocol order.
    """

    node_potentials: np.ndarray
    electrode_potentials: np.ndarray
    electrode_currents: np.ndarray
    voltages: np.ndarray


@dataclass(frozen=True, eq=False)
class JacobianBasis:
    """The Jacobian in factored form: ``jacobian = combination @ products`` ``[M, n_triangles]``.

    Every measurement's sensitivity is a signed sum of four element-wise products of the
    gradients of two unit-current fields (``n_el - 1`` non-zero fields, ground excluded), so
    only the ``(n_el - 1) n_el / 2`` distinct products are stored.

    Attributes:
        products: ``[P, n_triangles]`` ``int_t grad w_a . grad w_b dA`` (ohm^2) for the pairs
            ``a <= b`` of unit-current fields ``w`` (row-major upper triangle).
        combination: ``[M, P]`` sparse CSR, amperes: ``-current_a`` times the signed pair sums.
    """

    products: np.ndarray
    combination: sp.csr_matrix


@dataclass(eq=False)
class _Factorised:
    sigma: np.ndarray  # [n_triangles] the conductance this belongs to
    basis: np.ndarray  # [n_nodes + n_el, n_el] fields for 1 A into electrode l (ground: last)
    lu: spla.SuperLU  # of the symmetrically permuted, scaled matrix
    scale: np.ndarray  # [n_unknowns] diagonal scaling S
    order: np.ndarray  # [n_unknowns] fill-reducing order: the factor is of Ks[order][:, order]

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``Ks^-1 b`` for the scaled matrix (``b`` ``[n]`` or ``[n, k]``)."""
        x = np.empty_like(b, dtype=np.float64)
        x[self.order] = self.lu.solve(np.ascontiguousarray(b[self.order]))
        return x


class ForwardModel:
    """Sparse CEM finite-element forward model of one sheet, or of a tank of some depth.

    Args:
        mesh: the sheet's triangle mesh with its electrodes.
        protocol: drive and measurement pairs (``protocol.n_electrodes == mesh.n_electrodes``).
        contact_impedance_ohm_m: contact impedance ``z`` per electrode, ohm*metre, scalar or
            ``[n_el]``, each > 0 (a tank: per unit electrode width, :mod:`~eit_skin.fem.elements`).
        current_a: injected current amplitude, amperes (> 0).
        depth: None for a sheet (2-D); a tank's depth and electrode height: the mesh extruded
            into prism columns (:func:`~eit_skin.fem.elements.tank_elements`), the unknowns
            still one sheet conductance per triangle, node potentials those of the ring's plane.
    """

    def __init__(
        self,
        mesh: Mesh,
        protocol: Protocol,
        contact_impedance_ohm_m: float | np.ndarray,
        current_a: float = 1e-3,
        depth: TankDepth | None = None,
    ) -> None:
        nodes = np.asarray(mesh.nodes, dtype=np.float64)
        tri = np.asarray(mesh.triangles, dtype=np.int64)
        n_nodes, n_el = nodes.shape[0], mesh.n_electrodes
        if nodes.ndim != 2 or nodes.shape[1] != 2 or not np.all(np.isfinite(nodes)):
            raise ValueError(f"mesh.nodes: expected finite [n, 2], got shape {nodes.shape}")
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] == 0:
            raise ValueError(f"mesh.triangles: expected [t, 3], got shape {tri.shape}")
        if tri.min() < 0 or tri.max() >= n_nodes:
            raise ValueError("mesh.triangles: node index out of range")
        if protocol.n_electrodes != n_el:
            raise ValueError(
                f"protocol: made for {protocol.n_electrodes} electrodes, mesh has {n_el}"
            )
        z = np.broadcast_to(np.asarray(contact_impedance_ohm_m, dtype=np.float64), (n_el,))
        if not np.all(np.isfinite(z)) or np.any(z <= 0):
            raise ValueError(f"contact_impedance_ohm_m: must be finite and > 0, got {z}")
        if not (np.isfinite(current_a) and current_a > 0):
            raise ValueError(f"current_a: must be finite and > 0, got {current_a}")

        self._mesh = mesh
        self._protocol = protocol
        self._current_a = float(current_a)
        self._z = z.copy()
        self._depth = depth
        self._outside_s = 1.0 if depth is None else depth.outside_s
        self._n_plane = n_nodes  # the nodes of the mesh (of the ring's plane in a tank)
        self._n_el = n_el

        el = (
            sheet_elements(mesh, nodes, tri)
            if depth is None
            else tank_elements(mesh, nodes, tri, depth)
        )
        self._tri = tri
        self._elements = el
        self._n_nodes = n_nodes = el.n_nodes
        self._grad_op = el.operator()
        erows, ecols, evals, self._el_len = _contact_terms(el, n_el, z)
        # C^T rows [n_el, n_nodes]: electrode current I_l = D_l U_l - (C^T u)_l
        coupling = (erows >= n_nodes) & (ecols < n_nodes)
        self._ct = sp.csr_matrix(
            (-evals[coupling], (erows[coupling] - n_nodes, ecols[coupling])),
            shape=(n_el, n_nodes),
        )

        # nodes no triangle uses: an identity row keeps the matrix regular
        used = np.zeros(self._n_plane, dtype=bool)
        used[tri.ravel()] = True
        _check_every_part_touches_an_electrode(mesh, tri, used)
        self._unused = np.flatnonzero(~used)  # of the plane's nodes
        levels = n_nodes // self._n_plane
        unused = (self._unused[None, :] + self._n_plane * np.arange(levels)[:, None]).ravel()
        self._assemble_pattern(el, (erows, ecols, evals), unused)
        self._cache: _Factorised | None = None
        self._order: np.ndarray | None = None  # fill-reducing order, found once
        self._permuted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _assemble_pattern(
        self,
        elements: Elements,
        contact: tuple[np.ndarray, np.ndarray, np.ndarray],
        unused: np.ndarray,
    ) -> None:
        """Assemble the grounded system's CSR pattern once.

        Data slots of the stiffness entries (``elements``' stiffness per unit sigma), the
        constant contact data (``contact``: rows, columns, values) and the identity rows of
        the ``unused`` nodes.
        """
        conn, n_nodes, n_el = elements.nodes, self._n_nodes, self._n_el
        local = elements.stiffness()
        k = conn.shape[1]
        erows, ecols, evals = contact
        ground = n_nodes + n_el - 1
        srows = np.repeat(conn, k, axis=1).ravel()
        scols = np.tile(conn, (1, k)).ravel()
        rows = np.concatenate([srows, erows, unused])
        cols = np.concatenate([scols, ecols, unused])
        keep = (rows != ground) & (cols != ground)
        n_stiff = srows.size
        keep_stiff = keep[:n_stiff]
        n_sys = n_nodes + n_el - 1
        key = rows[keep] * n_sys + cols[keep]
        uniq, inverse = np.unique(key, return_inverse=True)
        self._n_sys = n_sys
        self._slot_stiff = inverse[: int(keep_stiff.sum())]  # data slot of each kept stiff entry
        self._stiff_elem = np.repeat(elements.owner(), k * k)[keep_stiff]
        self._stiff_vals = local.reshape(-1)[keep_stiff]
        const = np.bincount(
            inverse[int(keep_stiff.sum()) :],
            weights=np.concatenate([evals, np.ones(len(unused))])[keep[n_stiff:]],
            minlength=len(uniq),
        )
        self._const_data = const
        self._indices = (uniq % n_sys).astype(np.int32)
        row_of = uniq // n_sys
        self._indptr = np.searchsorted(row_of, np.arange(n_sys + 1)).astype(np.int32)
        self._row_of = row_of
        self._diag_slot = np.flatnonzero(row_of == self._indices)
        if self._diag_slot.size != n_sys:
            raise ValueError("mesh: some unknown has no diagonal entry (isolated node?)")

    # ------------------------------------------------------------------ properties
    @property
    def mesh(self) -> Mesh:
        return self._mesh

    @property
    def protocol(self) -> Protocol:
        return self._protocol

    @property
    def n_measurements(self) -> int:
        return self._protocol.n_measurements

    @property
    def n_elements(self) -> int:
        """Number of triangles (conductivity unknowns)."""
        return int(self._tri.shape[0])

    @property
    def n_electrodes(self) -> int:
        return self._n_el

    @property
    def n_nodes(self) -> int:
        """Node potentials solved for (a tank: the mesh's nodes at every level)."""
        return self._n_nodes

    @property
    def depth(self) -> TankDepth | None:
        """The tank's depth, or None for a sheet."""
        return self._depth

    def nodes_of(self, changed: np.ndarray) -> np.ndarray:
        """Sorted node indices whose stiffness a change of the ``changed`` triangles touches.

        ``changed``: bool ``[n_triangles]``; a tank: the nodes of those columns' slab elements.
        """
        el = self._elements
        sensed = np.flatnonzero(np.tile(np.asarray(changed, dtype=bool), el.sensed // el.columns))
        return np.unique(el.nodes[sensed])

    @property
    def current_a(self) -> float:
        return self._current_a

    @property
    def contact_impedance_ohm_m(self) -> np.ndarray:
        """``[n_el]`` contact impedance, ohm*metre."""
        return self._z.copy()

    # ------------------------------------------------------------------ assembly
    def _sigma_array(self, sigma) -> np.ndarray:
        s = np.asarray(sigma, dtype=np.float64)
        if s.ndim == 0:
            s = np.full(self.n_elements, float(s))
        if s.shape != (self.n_elements,):
            raise ValueError(
                f"sigma: expected a scalar or shape [{self.n_elements}] (one per triangle), "
                f"got shape {s.shape}"
            )
        if not np.all(np.isfinite(s)):
            raise ValueError("sigma: contains NaN or inf")
        if np.any(s <= 0):
            raise ValueError(f"sigma: sheet conductance must be > 0 S, min is {s.min():g}")
        return s

    def system_matrix(self, sigma) -> sp.csr_matrix:
        """Grounded CEM matrix ``[n_nodes + n_el - 1]^2`` (last electrode at 0 V), unscaled."""
        s = self._sigma_array(sigma)
        return self._matrix(s)

    def _matrix(self, s: np.ndarray) -> sp.csr_matrix:
        data = self._const_data + np.bincount(
            self._slot_stiff,
            weights=self._stiff_vals * np.append(s, self._outside_s)[self._stiff_elem],
            minlength=self._const_data.size,
        )
        return sp.csr_matrix(
            (data, self._indices, self._indptr), shape=(self._n_sys, self._n_sys), copy=False
        )

    def _factorise(self, s: np.ndarray) -> _Factorised:
        cache = self._cache
        if cache is not None and np.array_equal(cache.sigma, s):
            return cache
        K = self._matrix(s)
        scale = 1.0 / np.sqrt(K.data[self._diag_slot])
        Ks = sp.csc_matrix(
            (K.data * scale[self._row_of] * scale[self._indices], K.indices, K.indptr),
            shape=K.shape,
        )  # symmetric, so the CSR arrays read as CSC are the same matrix
        if self._order is None:
            # The sparsity pattern never changes: find the minimum-degree order once (from a
            # first factorisation) and factorise the pre-permuted matrix in natural order
            # afterwards, which halves the factorisation time (no ordering per call).
            first = spla.splu(
                Ks,
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
            self._order = np.argsort(first.perm_c)
            template = sp.csc_matrix(
                (np.arange(Ks.nnz, dtype=np.float64) + 1.0, Ks.indices, Ks.indptr),
                shape=Ks.shape,
            )[self._order][:, self._order].tocsc()
            template.sort_indices()
            self._permuted = (template.indices, template.indptr, template.data.astype(np.int64) - 1)
        indices, indptr, source = self._permuted
        lu = spla.splu(
            sp.csc_matrix((Ks.data[source], indices, indptr), shape=Ks.shape),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        n, n_el = self._n_nodes, self._n_el
        rhs = np.zeros((self._n_sys, n_el - 1))
        rhs[n + np.arange(n_el - 1), np.arange(n_el - 1)] = 1.0
        factor = _Factorised(sigma=s.copy(), basis=None, lu=lu, scale=scale, order=self._order)
        sol = scale[:, None] * factor.solve(scale[:, None] * rhs)
        basis = np.zeros((n + n_el, n_el))
        basis[: self._n_sys, : n_el - 1] = sol  # ground electrode: zero column and row
        if not np.all(np.isfinite(basis)):
            raise FloatingPointError("forward: factorisation produced non-finite potentials")
        factor.basis = basis
        self._cache = factor
        return factor

    # ------------------------------------------------------------------ public solves
    def solve(self, sigma) -> ForwardSolution:
        """Potentials and voltages for sheet conductance ``sigma`` (S, scalar or [n_triangles])."""
        s = self._sigma_array(sigma)
        basis = self._factorise(s).basis
        fields = self._current_a * (self._protocol.current_patterns @ basis.T)  # [n_inj, N]
        u = fields[:, : self._n_nodes]
        U = fields[:, self._n_nodes :]
        shift = U.mean(axis=1, keepdims=True)
        u = u - shift
        U = U - shift
        currents = U * (self._el_len / self._z) - (self._ct @ u.T).T
        u = u[:, : self._n_plane]  # a tank: the ring's plane
        if self._unused.size:
            u[:, self._unused] = np.nan
        return ForwardSolution(
            node_potentials=u,
            electrode_potentials=U,
            electrode_currents=currents,
            voltages=self._protocol.measure(U),
        )

    def voltages(self, sigma) -> np.ndarray:
        """``[M]`` measured voltages (V) in protocol order."""
        return self.solve(sigma).voltages

    def jacobian(self, sigma) -> np.ndarray:
        """``[M, n_triangles]`` sensitivity ``dV/dsigma`` (V/S), adjoint method."""
        s = self._sigma_array(sigma)
        basis = self._factorise(s).basis[: self._n_nodes]  # [n_nodes, n_el]
        # element rows of each basis field, [n_el, q, t] (rows contiguous per field), so
        # sum_q gu*gv is the column's int grad u . grad v per unit sheet conductance
        gw = self._field_gradients(basis)
        n_el, n_t = self._n_el, self.n_elements
        lead = self._lead_coefficients()  # [M, n_el * n_el] sparse
        if n_el**2 * n_t <= 20_000_000:
            # all pairwise field products once ([n_el * n_el, t]), then a sparse combination
            P = np.einsum("aqt,bqt->abt", gw, gw).reshape(n_el * n_el, n_t)
            out = np.asarray(lead @ P)
        else:  # many electrodes on a big mesh: bounded memory
            k = self._protocol.measurements[:, 0]
            electrodes, weights = self._protocol.measurement_terms
            patterns = self._protocol.current_patterns
            out = np.empty((k.size, n_t))
            chunk = max(1, 4_000_000 // n_t)
            for a in range(0, k.size, chunk):
                sl = slice(a, a + chunk)
                gu = np.einsum("cl,ldt->cdt", patterns[k[sl]], gw)  # [c, 2, t]
                gv = np.einsum("ce,cedt->cdt", weights[sl], gw[electrodes[sl]])
                out[sl] = np.einsum("cdt,cdt->ct", gu, gv)
        out *= -self._current_a
        return out

    def _field_gradients(self, fields: np.ndarray) -> np.ndarray:
        """``[k, q, t]`` element rows ``B u`` per column of node fields ``[n_nodes, k]``.

        A sheet: ``q = 2``, ``sqrt(area) grad u``; a tank: 7 rows per prism of the column.
        """
        g = self._grad_op @ fields  # [q t, k], one sparse product
        q = self._elements.rows_per_column
        return np.ascontiguousarray(g.T).reshape(fields.shape[1], q, self.n_elements)

    def jacobian_basis(self, sigma) -> JacobianBasis:
        """:meth:`jacobian` factored as ``combination @ products`` (see :class:`JacobianBasis`).

        Uses the same factorisation as :meth:`solve` (cached per conductivity); cheaper than
        :meth:`jacobian` and lets a Gauss-Newton step work with ``P < M`` rows.
        """
        s = self._sigma_array(sigma)
        n_el, n_t = self._n_el, self.n_elements
        f = n_el - 1  # the ground electrode's field is identically zero
        basis = self._factorise(s).basis[: self._n_nodes, :f]  # [n_nodes, f]
        gw = self._field_gradients(basis)  # [f, 2, t]
        a_idx, b_idx = np.triu_indices(f)
        products = np.empty((a_idx.size, n_t))  # rows (a, a..f-1) for a = 0..f-1
        row = 0
        for a in range(f):  # one block of rows per field (f ~ 15), vectorised over elements
            products[row : row + f - a] = np.einsum("qt,bqt->bt", gw[a], gw[a:])
            row += f - a
        pair = np.full((n_el, n_el), -1, dtype=np.int64)
        pair[a_idx, b_idx] = np.arange(a_idx.size)
        pair[b_idx, a_idx] = np.arange(a_idx.size)
        lead = self._lead_coefficients().tocoo()  # entries (m, a * n_el + b)
        a, b = np.divmod(lead.col, n_el)
        used = (a < f) & (b < f)  # the ground field is zero
        combination = sp.csr_matrix(
            (-self._current_a * lead.data[used], (lead.row[used], pair[a[used], b[used]])),
            shape=(lead.shape[0], a_idx.size),
        )
        combination.sum_duplicates()
        return JacobianBasis(products=products, combination=combination)

    def contact_jacobian(self, sigma) -> np.ndarray:
        """``[M, n_el]`` sensitivity ``dV/dz_l`` (V per ohm*m) to each contact impedance.

        Adjoint form: the contact term of electrode ``l`` is ``(1/z_l) int_{e_l} (U_l - u)
        (W_l - w) ds``, so ``dV/dz_l = (current_a / z_l^2) int_{e_l} (U_l - u_k)(P_l - v_pq) ds``
        for injection field ``u_k`` and the unit-current field ``v_pq`` of the measuring
        pair; both are combinations of the unit-current basis of :meth:`solve`'s factorisation.
        """
        s = self._sigma_array(sigma)
        basis = self._factorise(s).basis  # [n_nodes + n_el, n_el]
        n_el = self._n_el
        gram = np.empty((n_el, n_el, n_el))  # [l, a, b] int_{e_l} (W_a,l - w_a)(W_b,l - w_b) ds
        for el, (surface, mass) in enumerate(self._elements.contact):
            drop = basis[self._n_nodes + el][None, :] - basis[surface]  # [e, c, n_el]
            gram[el] = np.einsum("eia,eij,ejb->ab", drop, mass, drop)
        k = self._protocol.measurements[:, 0]
        electrodes, weights = self._protocol.measurement_terms
        # [l, n_inj, n_el]: current pattern of each injection through each electrode's form
        through = np.einsum("ia,lab->lib", self._protocol.current_patterns, gram)
        out = (through[:, k[:, None], electrodes] * weights).sum(axis=-1).T  # [M, n_el]
        return out * (self._current_a / self._z**2)[None, :]

    def _lead_coefficients(self) -> sp.csr_matrix:
        """``[M, n_el * n_el]``: measurement ``m`` is ``sum I_k[a] c_m[b] w_a . w_b``.

        ``I_k`` is the current pattern of the measurement's injection, ``c_m`` its measurement
        weights (``e_p - e_q`` for matched inputs: :attr:`Protocol.measurement_terms`); a
        pair drive gives four entries per row, an ``n_el``-electrode pattern ``2 n_el``.
        """
        n_el = self._n_el
        k = self._protocol.measurements[:, 0]
        measured, weights = self._protocol.measurement_terms  # [M, T]
        patterns = self._protocol.current_patterns  # [n_inj, n_el]
        inj_rows, electrodes = np.nonzero(patterns)
        counts = np.bincount(inj_rows, minlength=patterns.shape[0])
        starts = np.concatenate([[0], np.cumsum(counts)])
        per = counts[k]  # nonzero currents of each measurement's injection
        rows = np.repeat(np.arange(k.size), per)
        offset = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
        src = starts[k][rows] + offset  # index into the nonzero list
        el = electrodes[src]
        amp = patterns[inj_rows[src], el]
        terms = measured.shape[1]
        all_rows = np.tile(rows, terms)
        cols = (el[None, :] * n_el + measured[rows].T).ravel()  # term-major, [T * nnz]
        vals = (amp[None, :] * weights[rows].T).ravel()
        lead = sp.csr_matrix((vals, (all_rows, cols)), shape=(k.size, n_el * n_el))
        lead.sum_duplicates()
        return lead

    def condition_estimate(self, sigma) -> float:
        """1-norm condition number estimate of the scaled, grounded system that is factorised."""
        s = self._sigma_array(sigma)
        fac = self._factorise(s)
        K = self._matrix(s)
        Ks = sp.diags(fac.scale) @ K @ sp.diags(fac.scale)
        n = self._n_sys
        inv = spla.LinearOperator((n, n), matvec=fac.solve, rmatvec=fac.solve)  # symmetric
        return float(spla.norm(Ks, 1) * spla.onenormest(inv))


def _contact_terms(
    elements: Elements, n_el: int, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The constant contact terms ``B``, ``C``, ``D`` and the electrode sizes ``[n_el]`` m.

    The terms are COO rows, columns and values over the unknowns ``[u (n_nodes), U (n_el)]``;
    an electrode's size is its surface's mass total (a sheet: its length).
    """
    n_nodes = elements.n_nodes
    erows, ecols, evals = [], [], []
    size = np.zeros(n_el)
    for el_i, (surface, mass) in enumerate(elements.contact):
        w = 1.0 / z[el_i]
        c = surface.shape[1]
        size[el_i] = mass.sum()
        erows.append(np.repeat(surface, c, axis=1).ravel())  # B: surface mass / z
        ecols.append(np.tile(surface, (1, c)).ravel())
        evals.append(w * mass.ravel())
        integral = w * mass.sum(axis=2)  # int phi_i ds / z, [e, c]: the coupling C, symmetric
        el = np.full(surface.size, n_nodes + el_i)
        erows += [surface.ravel(), el]
        ecols += [el, surface.ravel()]
        evals += [-integral.ravel(), -integral.ravel()]
        erows.append(np.array([n_nodes + el_i]))
        ecols.append(np.array([n_nodes + el_i]))
        evals.append(np.array([size[el_i] * w]))
    return np.concatenate(erows), np.concatenate(ecols), np.concatenate(evals), size


def _check_every_part_touches_an_electrode(mesh: Mesh, tri: np.ndarray, used: np.ndarray) -> None:
    """Refuse a mesh with a connected piece no electrode touches (its potential is undefined)."""
    n_nodes = used.size
    adj = sp.coo_matrix(
        (np.ones(3 * len(tri)), (tri.ravel(), np.roll(tri, 1, axis=1).ravel())),
        shape=(n_nodes, n_nodes),
    )
    n_comp, label = csgraph.connected_components(adj, directed=False)
    el_nodes = np.unique(np.concatenate([np.ravel(e) for e in mesh.electrode_edges]))
    touched = np.zeros(n_comp, dtype=bool)
    touched[label[el_nodes]] = True
    if not np.all(touched[np.unique(label[used])]):
        raise ValueError(
            "mesh: a connected part of the sheet has no electrode; its potential is undefined"
        )
