"""Drive and measurement protocol: the one place that knows the measurement order.

Canonical default (``ProtocolSpec()``, "adjacent/adjacent"):

* electrodes are numbered counter-clockwise ``0 .. n-1`` (the patch config numbering);
* injection ``k = 0 .. n-1``: the current enters the sheet at electrode ``k`` (source) and
  leaves it at electrode ``k+1 mod n`` (sink);
* for each injection, measure ``V(m) - V(m+1 mod n)`` for ``m = 0 .. n-1`` in increasing ``m``,
  skipping every pair that touches the source or the sink electrode
  (16 electrodes -> 16 x 13 = 208 values per frame).

Generalisations (all in :class:`ProtocolSpec`):

* pattern pairs: a pattern with *offset* ``d`` uses the pairs ``(k, k+d mod n)``;
  ``"adjacent"`` has ``d = 1``, ``"opposite"`` ``d = n // 2``, ``"skip"`` ``d = skip + 1``
  (``skip`` electrodes lie between the two electrodes of the pair).
  The same rule is used for drive (source, sink) and measurement (plus, minus) pairs.
  Measurement pairs that touch a current-carrying electrode are always left out.
* ``"explicit"``: ``injections`` lists ``(source, sink)`` pairs, ``measurements`` lists
  ``(injection index, plus, minus)`` triples, in frame order.
* ``first_electrode``: the board numbers its electrodes from a different start: board
  electrode ``b`` is config electrode ``(b + first_electrode) mod n``. Patterns and explicit
  lists are written in board numbering; :class:`Protocol` stores config numbering.
* ``sign = -1``: every measurement is ``V(minus) - V(plus)`` of the canonical pair
  (stored by swapping plus and minus).
* ``order = "rotated"``: for each injection, measurement pairs start at the pair whose first
  electrode follows the sink (``m = sink+1, sink+2, ...`` wrapping), as many boards do.
  Ignored for explicit measurements, whose order is the listed one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

PATTERNS = ("adjacent", "opposite", "skip", "explicit")
ORDERS = ("increasing", "rotated")


@dataclass(frozen=True)
class ProtocolSpec:
    """Validated description of a drive/measurement protocol (see the module docstring).

    Attributes:
        drive: ``"adjacent" | "opposite" | "skip" | "explicit"``.
        drive_skip: electrodes skipped between source and sink for ``drive="skip"``.
        measure: same choices as ``drive``, for the measurement pairs.
        measure_skip: electrodes skipped between plus and minus for ``measure="skip"``.
        first_electrode: config electrode that the board calls electrode 0.
        sign: ``+1``: ``V(plus) - V(minus)``; ``-1``: flipped.
        order: ``"increasing"`` or ``"rotated"`` measurement order within an injection.
        injections: explicit ``(source, sink)`` pairs (board numbering), for ``drive="explicit"``.
        measurements: explicit ``(injection index, plus, minus)`` triples (board numbering),
            for ``measure="explicit"``.
    """

    drive: str = "adjacent"
    drive_skip: int = 0
    measure: str = "adjacent"
    measure_skip: int = 0
    first_electrode: int = 0
    sign: int = 1
    order: str = "increasing"
    injections: tuple[tuple[int, int], ...] | None = None
    measurements: tuple[tuple[int, int, int], ...] | None = None

    def __post_init__(self) -> None:
        for name in ("drive", "measure"):
            value = getattr(self, name)
            if value not in PATTERNS:
                raise ValueError(f"{name}: unknown pattern {value!r}; expected one of {PATTERNS}")
        for name in ("drive_skip", "measure_skip", "first_electrode"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name}: expected a non-negative integer, got {value!r}")
        if self.sign not in (1, -1) or isinstance(self.sign, bool):
            raise ValueError(f"sign: expected +1 or -1, got {self.sign!r}")
        if self.order not in ORDERS:
            raise ValueError(f"order: unknown order {self.order!r}; expected one of {ORDERS}")
        if self.drive == "explicit":
            if not self.injections:
                raise ValueError("injections: drive='explicit' needs a non-empty list")
            object.__setattr__(
                self, "injections", _int_tuples(self.injections, 2, "injections", "(source, sink)")
            )
        elif self.injections is not None:
            raise ValueError("injections: only allowed with drive='explicit'")
        if self.measure == "explicit":
            if not self.measurements:
                raise ValueError("measurements: measure='explicit' needs a non-empty list")
            object.__setattr__(
                self,
                "measurements",
                _int_tuples(self.measurements, 3, "measurements", "(injection, plus, minus)"),
            )
        elif self.measurements is not None:
            raise ValueError("measurements: only allowed with measure='explicit'")

    def validate(self, n_electrodes: int) -> None:
        """Raise ``ValueError`` if the spec cannot be used with ``n_electrodes`` electrodes."""
        n = int(n_electrodes)
        if n < 3:
            raise ValueError(f"n_electrodes: need at least 3 electrodes, got {n}")
        if self.first_electrode >= n:
            raise ValueError(f"first_electrode: {self.first_electrode} is not in 0..{n - 1}")
        for name, pattern, skip in (
            ("drive", self.drive, self.drive_skip),
            ("measure", self.measure, self.measure_skip),
        ):
            if pattern == "skip" and skip >= n:
                raise ValueError(
                    f"{name}_skip: {skip} is not below the electrode count {n} (it would wrap "
                    f"around to skip {skip % n}); use 0..{n - 2}"
                )
            if pattern != "explicit":
                offset = _offset(pattern, skip, n)
                if offset % n == 0:
                    raise ValueError(
                        f"{name}_skip: skipping {skip} of {n} electrodes joins an electrode "
                        "to itself"
                    )
        if self.drive == "explicit":
            for i, (a, b) in enumerate(self.injections):
                if not (0 <= a < n and 0 <= b < n):
                    raise ValueError(f"injections[{i}]: electrode out of range 0..{n - 1}")
                if a == b:
                    raise ValueError(f"injections[{i}]: source and sink are the same electrode")
        if self.measure == "explicit":
            n_inj = len(self.injections) if self.drive == "explicit" else n
            for i, (k, p, m) in enumerate(self.measurements):
                if not 0 <= k < n_inj:
                    raise ValueError(f"measurements[{i}]: injection {k} is not in 0..{n_inj - 1}")
                if not (0 <= p < n and 0 <= m < n):
                    raise ValueError(f"measurements[{i}]: electrode out of range 0..{n - 1}")
                if p == m:
                    raise ValueError(f"measurements[{i}]: plus and minus are the same electrode")


def _int_tuples(value, width: int, name: str, what: str) -> tuple[tuple[int, ...], ...]:
    out = []
    for i, row in enumerate(value):
        try:
            items = tuple(row)
        except TypeError:
            raise ValueError(f"{name}[{i}]: expected {what}, got {row!r}") from None
        if len(items) != width or not all(
            isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in items
        ):
            raise ValueError(f"{name}[{i}]: expected {what} integers, got {row!r}")
        out.append(tuple(int(x) for x in items))
    return tuple(out)


def _offset(pattern: str, skip: int, n: int) -> int:
    if pattern == "adjacent":
        return 1
    if pattern == "opposite":
        return n // 2
    return skip + 1


@dataclass(frozen=True, eq=False)
class Protocol:
    """Drive and measurement pairs of one frame, in frame order, config electrode numbering.

    Attributes:
        name: short description, e.g. ``"adjacent/adjacent"``.
        n_electrodes: number of electrodes.
        injections: ``[n_inj, 2]`` int64 ``(source, sink)``: current enters at source.
        measurements: ``[M, 3]`` int64 ``(injection index, plus, minus)``: value is
            ``V(plus) - V(minus)`` during that injection.
    """

    name: str
    n_electrodes: int
    injections: np.ndarray
    measurements: np.ndarray
    _selection: sp.csr_matrix | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        inj = np.asarray(self.injections, dtype=np.int64).reshape(-1, 2)
        meas = np.asarray(self.measurements, dtype=np.int64).reshape(-1, 3)
        n = int(self.n_electrodes)
        if inj.size == 0 or meas.size == 0:
            raise ValueError(f"protocol {self.name!r}: no injections or no measurements")
        if inj.min() < 0 or inj.max() >= n or np.any(inj[:, 0] == inj[:, 1]):
            raise ValueError(f"protocol {self.name!r}: bad injection pair")
        if (
            meas[:, 0].min() < 0
            or meas[:, 0].max() >= len(inj)
            or meas[:, 1:].min() < 0
            or meas[:, 1:].max() >= n
            or np.any(meas[:, 1] == meas[:, 2])
        ):
            raise ValueError(f"protocol {self.name!r}: bad measurement triple")
        inj.setflags(write=False)
        meas.setflags(write=False)
        object.__setattr__(self, "n_electrodes", n)
        object.__setattr__(self, "injections", inj)
        object.__setattr__(self, "measurements", meas)
        rows = np.repeat(np.arange(len(meas)), 2)
        cols = (meas[:, [0]] * n + meas[:, 1:]).ravel()
        vals = np.tile([1.0, -1.0], len(meas))
        sel = sp.csr_matrix((vals, (rows, cols)), shape=(len(meas), len(inj) * n))
        object.__setattr__(self, "_selection", sel)

    @property
    def n_injections(self) -> int:
        return int(self.injections.shape[0])

    @property
    def n_measurements(self) -> int:
        return int(self.measurements.shape[0])

    @property
    def selection_matrix(self) -> sp.csr_matrix:
        """``[M, n_inj * n_el]`` sparse +1/-1 matrix: ``voltages = S @ U.ravel()``."""
        return self._selection

    def measure(self, electrode_potentials: np.ndarray) -> np.ndarray:
        """Measured voltages ``[..., M]`` (V) from electrode potentials ``[..., n_inj, n_el]``."""
        u = np.asarray(electrode_potentials)
        if u.shape[-2:] != (self.n_injections, self.n_electrodes):
            raise ValueError(
                f"electrode_potentials: expected shape [..., {self.n_injections}, "
                f"{self.n_electrodes}], got {u.shape}"
            )
        k, p, m = self.measurements.T
        return u[..., k, p] - u[..., k, m]

    def touching(self, electrodes) -> np.ndarray:
        """``[M]`` bool: measurements whose drive or measure electrodes include any given one."""
        el = np.atleast_1d(np.asarray(electrodes, dtype=np.int64))
        if el.size and (el.min() < 0 or el.max() >= self.n_electrodes):
            raise ValueError(f"electrodes: out of range 0..{self.n_electrodes - 1}: {el}")
        bad = np.zeros(self.n_electrodes, dtype=bool)
        bad[el] = True
        k = self.measurements[:, 0]
        return (
            bad[self.injections[k, 0]]
            | bad[self.injections[k, 1]]
            | bad[self.measurements[:, 1]]
            | bad[self.measurements[:, 2]]
        )


def build_protocol(spec: ProtocolSpec, n_electrodes: int) -> Protocol:
    """Expand ``spec`` for ``n_electrodes`` electrodes into the frame's pairs (config numbering)."""
    spec.validate(n_electrodes)
    n = int(n_electrodes)
    if spec.drive == "explicit":
        inj = np.array(spec.injections, dtype=np.int64)
    else:
        k = np.arange(n)
        inj = np.stack([k, (k + _offset(spec.drive, spec.drive_skip, n)) % n], axis=1)
    if spec.measure == "explicit":
        meas = np.array(spec.measurements, dtype=np.int64)
    else:
        d = _offset(spec.measure, spec.measure_skip, n)
        rows = []
        for i, (src, snk) in enumerate(inj):
            start = (snk + 1) % n if spec.order == "rotated" else 0
            m = (start + np.arange(n)) % n
            pairs = np.stack([m, (m + d) % n], axis=1)
            keep = ~np.isin(pairs, (src, snk)).any(axis=1)
            pairs = pairs[keep]
            rows.append(np.column_stack([np.full(len(pairs), i), pairs]))
        meas = np.concatenate(rows).astype(np.int64)
        # opposite with an even n visits every pair twice (m, m+n/2) and (m+n/2, m): keep both,
        # as boards do; the values are the negatives of each other.
    if spec.sign == -1:
        meas = meas[:, [0, 2, 1]]
    # board -> config numbering
    inj = (inj + spec.first_electrode) % n
    meas = meas.copy()
    meas[:, 1:] = (meas[:, 1:] + spec.first_electrode) % n
    name = f"{spec.drive}/{spec.measure}"
    if meas.shape[0] == 0:
        raise ValueError(f"protocol {name}: no measurement pair avoids the drive electrodes")
    return Protocol(name=name, n_electrodes=n, injections=inj, measurements=meas)
