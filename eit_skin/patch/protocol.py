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
* ``electrode_order``: an arbitrary board -> config map (clockwise boards, shuffled cables):
  board electrode ``b`` is config electrode ``electrode_order[b]`` (a permutation of
  ``0 .. n-1``); instead of ``first_electrode``. A clockwise board whose electrode 0 is config
  electrode 0 has ``electrode_order = [0, n-1, n-2, ..., 1]``.

Multi-electrode current patterns (``drive = "trigonometric" | "currents"``): every injection
is a current vector over all electrodes (amperes per ``current_a``, summing to zero), stored
in :attr:`Protocol.currents` ``[n_inj, n_el]``. ``"trigonometric"`` is the classic optimal
pattern set of a disc (Isaacson; EIDORS' trigonometric patterns): with board electrode ``b`` at
``theta_b = 2 pi b / n``, injections ``cos(k theta_b)`` for ``k = 1 .. n//2`` then
``sin(k theta_b)`` for ``k = 1 .. (n-1)//2`` (``n - 1`` injections; the peak electrode current
is ``current_a``). ``"currents"`` lists the vectors (board numbering) in ``currents``.

Measurements on current-carrying electrodes (``measure_driven``): left out by default for
pair drives and ``"currents"`` (as pyEIT and EIDORS' ``no_meas_current`` do: their values
are dominated by the contact impedance), kept by default for ``"trigonometric"``, where every
electrode carries current. ``measure_driven = true`` keeps them for any drive.

Frame layout (``layout``): ``"compact"`` (default): the device sends exactly the protocol's
``M`` numbers. ``"full"``: the device sends every pair of the measure pattern for every
injection (``n_inj * n`` numbers, e.g. 16 x 16 = 256, in the pattern's order, including the
pairs on driven electrodes); :attr:`Protocol.frame_index` picks the used entries
(:meth:`Protocol.select`). Explicit measurements have no full layout.

Unequal input gains (``negative_input_gain``, the layer's ``device.negative_input_gain``): the
board reads ``V(plus) - g V(minus)`` against the sink (:mod:`eit_skin.patch.input_gain`).

Values (``values``): ``"signed"`` (default) or ``"magnitude"``: the board reports ``|V|``;
the sign of each channel is taken from the homogeneous model (``pipeline.builder``).
Complex frames (``complex_part``): ``"real"`` (default) or ``"magnitude"`` of a complex
value; ``"magnitude"`` also implies model signs, as a magnitude has none.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import scipy.sparse as sp

from eit_skin.patch.input_gain import input_gain_problem, measurement_terms
from eit_skin.patch.patterns import pattern_offset, trigonometric_currents

PATTERNS = ("adjacent", "opposite", "skip", "explicit")
DRIVE_PATTERNS = (*PATTERNS, "trigonometric", "currents")
ORDERS = ("increasing", "rotated")
LAYOUTS = ("compact", "full")
VALUES = ("signed", "magnitude")
COMPLEX_PARTS = ("real", "magnitude")

#: Largest |sum| of a current vector, relative to its largest entry, accepted as zero.
CURRENT_SUM_TOLERANCE = 1e-6


@dataclass(frozen=True)
class ProtocolSpec:
    """Validated description of a drive/measurement protocol (see the module docstring).

    Attributes:
        drive: ``"adjacent" | "opposite" | "skip" | "explicit" | "trigonometric" | "currents"``.
        drive_skip: electrodes skipped between source and sink for ``drive="skip"``.
        measure: same choices as ``drive``, for the measurement pairs.
        measure_skip: electrodes skipped between plus and minus for ``measure="skip"``.
        first_electrode: config electrode that the board calls electrode 0.
        sign: ``+1``: ``V(plus) - V(minus)``; ``-1``: flipped.
        order: ``"increasing"`` or ``"rotated"`` measurement order within an injection.
        injections: explicit ``(source, sink)`` pairs (board numbering), for ``drive="explicit"``.
        measurements: explicit ``(injection index, plus, minus)`` triples (board numbering),
            for ``measure="explicit"``.
        currents: current vectors ``[n_inj][n]`` (board numbering, multiples of the layer's
            current, each summing to zero), for ``drive="currents"``.
        electrode_order: board -> config electrode map (a permutation), or None.
        measure_driven: keep measurements on current-carrying electrodes; None: only for
            ``drive="trigonometric"``.
        layout: ``"compact"`` or ``"full"`` device frame (see the module docstring).
        values: ``"signed"`` or ``"magnitude"`` (signs from the model).
        complex_part: ``"real"`` or ``"magnitude"`` of complex frames.
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
    currents: tuple[tuple[float, ...], ...] | None = None
    electrode_order: tuple[int, ...] | None = None
    measure_driven: bool | None = None
    layout: str = "compact"
    values: str = "signed"
    complex_part: str = "real"

    #: Keys added after patches were hashed: left out of the content hash at their default,
    #: so caches and press calibrations of existing patches stay valid.
    HASH_ONLY_IF_SET: ClassVar[tuple[str, ...]] = (
        "currents",
        "electrode_order",
        "measure_driven",
        "layout",
        "values",
        "complex_part",
    )

    def __post_init__(self) -> None:
        for name, choices in (("drive", DRIVE_PATTERNS), ("measure", PATTERNS)):
            value = getattr(self, name)
            if value not in choices:
                raise ValueError(f"{name}: unknown pattern {value!r}; expected one of {choices}")
        for name, choices in (
            ("layout", LAYOUTS),
            ("values", VALUES),
            ("complex_part", COMPLEX_PARTS),
        ):
            if getattr(self, name) not in choices:
                raise ValueError(
                    f"{name}: unknown {getattr(self, name)!r}; expected one of {choices}"
                )
        if self.measure_driven is not None and not isinstance(self.measure_driven, bool):
            raise ValueError(f"measure_driven: expected true or false, got {self.measure_driven!r}")
        if self.layout == "full" and self.measure == "explicit":
            raise ValueError("layout: 'full' needs a measure pattern, not measure='explicit'")
        if self.drive == "currents":
            object.__setattr__(self, "currents", _current_vectors(self.currents))
        elif self.currents is not None:
            raise ValueError("currents: only allowed with drive='currents'")
        if self.electrode_order is not None:
            if self.first_electrode != 0:
                raise ValueError(
                    "electrode_order: give electrode_order or first_electrode, not both"
                )
            order = tuple(self.electrode_order)
            if not all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in order):
                raise ValueError(f"electrode_order: expected electrode numbers, got {list(order)}")
            order = tuple(int(x) for x in order)
            object.__setattr__(self, "electrode_order", order)
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
        if self.electrode_order is not None and sorted(self.electrode_order) != list(range(n)):
            raise ValueError(
                f"electrode_order: must list every electrode 0..{n - 1} exactly once, got "
                f"{list(self.electrode_order)}"
            )
        if self.drive == "currents":
            for i, row in enumerate(self.currents):
                if len(row) != n:
                    raise ValueError(
                        f"currents[{i}]: expected {n} values (one per electrode), got {len(row)}"
                    )
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
                offset = pattern_offset(pattern, skip, n)
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
            n_inj = {"explicit": len(self.injections or ()), "currents": len(self.currents or ())}
            n_inj = n_inj.get(self.drive, n - 1 if self.drive == "trigonometric" else n)
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


def _current_vectors(value) -> tuple[tuple[float, ...], ...]:
    """``currents`` rows as float tuples, each finite, not all zero, summing to zero."""
    if not value:
        raise ValueError("currents: drive='currents' needs a non-empty list of current vectors")
    out = []
    for i, row in enumerate(value):
        try:
            items = tuple(float(x) for x in row if not isinstance(x, bool))
        except (TypeError, ValueError):
            raise ValueError(f"currents[{i}]: expected a list of numbers, got {row!r}") from None
        if len(items) != len(row) or not all(np.isfinite(items)):
            raise ValueError(f"currents[{i}]: expected finite numbers, got {row!r}")
        peak = max(abs(x) for x in items) if items else 0.0
        if peak == 0:
            raise ValueError(f"currents[{i}]: all zero")
        if abs(sum(items)) > CURRENT_SUM_TOLERANCE * peak:
            raise ValueError(
                f"currents[{i}]: currents must sum to zero (what enters must leave), "
                f"sum is {sum(items):.3g}"
            )
        out.append(items)
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Protocol:
    """Drive and measurement pairs of one frame, in frame order, config electrode numbering.

    Attributes:
        name: short description, e.g. ``"adjacent/adjacent"``.
        n_electrodes: number of electrodes.
        injections: ``[n_inj, 2]`` int64 ``(source, sink)``: current enters at source. For
            multi-electrode patterns: the electrodes of the largest inflow and outflow
            (labels for messages; the physics is in ``currents``).
        measurements: ``[M, 3]`` int64 ``(injection index, plus, minus)``: value is
            ``V(plus) - V(minus)`` during that injection.
        currents: ``[n_inj, n_el]`` current patterns (multiples of the layer's current,
            each row summing to zero), or None for a pair drive (``+1`` at the source,
            ``-1`` at the sink: :attr:`current_patterns`).
        frame_index: ``[M]`` int64 position of each measurement in the device's frame, or
            None: the device frame is the ``M`` measurements (compact layout).
        frame_size: numbers per device frame (``M`` for the compact layout).
        complex_part: ``"real"`` or ``"magnitude"``: what :meth:`select` takes of complex
            frames.
        magnitude: the device reports magnitudes (``values: magnitude`` or
            ``complex_part: magnitude``): each channel's sign is the homogeneous model's.
        board_to_config: ``[n_el]`` int64: board electrode ``b`` is config electrode
            ``board_to_config[b]`` (``first_electrode`` or ``electrode_order``; identity
            when None is given).
        negative_input_gain: gain of the minus input relative to the plus input (> 0; 1:
            matched inputs; module docstring); pair drives only.
    """

    name: str
    n_electrodes: int
    injections: np.ndarray
    measurements: np.ndarray
    currents: np.ndarray | None = None
    frame_index: np.ndarray | None = None
    frame_size: int = 0
    complex_part: str = "real"
    magnitude: bool = False
    board_to_config: np.ndarray | None = None
    negative_input_gain: float = 1.0
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
        if self.currents is not None:
            cur = np.array(self.currents, dtype=np.float64)
            if cur.shape != (len(inj), n) or not np.all(np.isfinite(cur)):
                raise ValueError(
                    f"protocol {self.name!r}: currents must be finite [{len(inj)}, {n}]"
                )
            cur.setflags(write=False)
            object.__setattr__(self, "currents", cur)
        size = int(self.frame_size) or len(meas)
        if self.frame_index is not None:
            idx = np.array(self.frame_index, dtype=np.int64)
            if idx.shape != (len(meas),) or idx.min() < 0 or idx.max() >= size:
                raise ValueError(f"protocol {self.name!r}: bad frame_index for {size} numbers")
            idx.setflags(write=False)
            object.__setattr__(self, "frame_index", idx)
        elif size != len(meas):
            raise ValueError(f"protocol {self.name!r}: frame_size {size} needs a frame_index")
        object.__setattr__(self, "frame_size", size)
        order = np.arange(n) if self.board_to_config is None else np.array(self.board_to_config)
        if sorted(order.tolist()) != list(range(n)):
            raise ValueError(f"protocol {self.name!r}: board_to_config is not a permutation")
        order = order.astype(np.int64)
        order.setflags(write=False)
        object.__setattr__(self, "board_to_config", order)
        gain = float(self.negative_input_gain)
        problem = input_gain_problem(gain, self.currents is None)
        if problem:
            raise ValueError(f"protocol {self.name!r}: {problem}")
        object.__setattr__(self, "negative_input_gain", gain)
        inj.setflags(write=False)
        meas.setflags(write=False)
        object.__setattr__(self, "n_electrodes", n)
        object.__setattr__(self, "injections", inj)
        object.__setattr__(self, "measurements", meas)
        electrodes, weights = self.measurement_terms
        rows = np.repeat(np.arange(len(meas)), electrodes.shape[1])
        cols = (meas[:, [0]] * n + electrodes).ravel()
        sel = sp.csr_matrix((weights.ravel(), (rows, cols)), shape=(len(meas), len(inj) * n))
        sel.eliminate_zeros()
        object.__setattr__(self, "_selection", sel)

    @property
    def measurement_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """(``[M, T]`` electrodes, ``[M, T]`` weights): :func:`.input_gain.measurement_terms`."""
        return measurement_terms(self.measurements, self.injections[:, 1], self.negative_input_gain)

    @property
    def pair_drive(self) -> bool:
        """True when every injection drives one source and one sink electrode."""
        return self.currents is None

    @property
    def current_patterns(self) -> np.ndarray:
        """``[n_inj, n_el]`` current into each electrode per injection, units of the current."""
        if self.currents is not None:
            return self.currents
        out = np.zeros((self.n_injections, self.n_electrodes))
        rows = np.arange(self.n_injections)
        out[rows, self.injections[:, 0]] = 1.0
        out[rows, self.injections[:, 1]] = -1.0
        return out

    def select(self, frames: np.ndarray, source: str = "frames") -> np.ndarray:
        """Device frames ``[..., frame_size]`` -> the protocol's measurements float ``[..., M]``.

        Complex frames give their real part or magnitude (``complex_part``); the full layout
        keeps the entries of :attr:`frame_index`. Frames already in protocol order (``M``
        numbers, e.g. recorded from the driver's output) pass unchanged.

        Raises ValueError naming ``source`` when the last axis is neither ``frame_size`` nor
        ``M`` long, or the values are not numbers.
        """
        v = np.asarray(frames)
        if v.dtype.kind == "c":
            v = np.abs(v) if self.complex_part == "magnitude" else v.real
        if v.dtype.kind not in "fiu":
            raise ValueError(f"{source}: must be real or complex numbers, got dtype {v.dtype}")
        v = v.astype(np.float64, copy=False)
        if v.ndim > 0 and v.shape[-1] == self.n_measurements:
            return v
        if v.ndim == 0 or v.shape[-1] != self.frame_size:
            layout = "full" if self.frame_index is not None else "compact"
            raise ValueError(
                f"{source}: got shape {v.shape}; the protocol expects {self.frame_size} "
                f"numbers per frame ({layout} layout, {self.name})"
                + (
                    f" or {self.n_measurements} in protocol order"
                    if self.frame_index is not None
                    else ""
                )
            )
        return v if self.frame_index is None else v[..., self.frame_index]

    def device_frame(self, measurements: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`select` for an emulated board: ``[..., M]`` -> ``[..., W]``.

        Entries the protocol does not use (the full layout's pairs on driven electrodes) are
        0, as boards that report them blank do; a magnitude board's values are ``|V|``.
        """
        v = np.asarray(measurements, dtype=np.float64)
        if self.magnitude:
            v = np.abs(v)
        if self.frame_index is None:
            return v
        out = np.zeros((*v.shape[:-1], self.frame_size))
        out[..., self.frame_index] = v
        return out

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
        if self.negative_input_gain == 1.0:
            return u[..., k, p] - u[..., k, m]
        electrodes, weights = self.measurement_terms
        return (u[..., k[:, None], electrodes] * weights).sum(axis=-1)

    def same_numbers(self, measurements: np.ndarray) -> bool:
        """Whether ``(injection, plus, minus)`` rows ``[M, 3]`` give these numbers, in order."""
        other, mine = np.asarray(measurements, dtype=np.int64), self.measurements
        if other.shape != mine.shape:
            return False
        if self.magnitude:  # a pair's orientation is immaterial
            other, mine = (
                np.column_stack([m[:, :1], np.sort(m[:, 1:], axis=1)]) for m in (other, mine)
            )
        return np.array_equal(other, mine)

    def touching_table(self) -> np.ndarray:
        """``[E, M]`` bool: row ``e`` is :meth:`touching` of electrode ``e`` alone (read-only).

        Made once per protocol: every fault check asks for it.
        """
        return self._touching_table

    @functools.cached_property
    def _touching_table(self) -> np.ndarray:
        drives = (self.current_patterns != 0).T  # [E, n_inj]
        on = np.eye(self.n_electrodes, dtype=bool)
        k, p, m = self.measurements.T
        table = drives[:, k] | on[:, p] | on[:, m]
        table.flags.writeable = False
        return table

    def touching(self, electrodes) -> np.ndarray:
        """``[M]`` bool: measurements whose drive or measure electrodes include any given one."""
        el = np.atleast_1d(np.asarray(electrodes, dtype=np.int64))
        if el.size and (el.min() < 0 or el.max() >= self.n_electrodes):
            raise ValueError(f"electrodes: out of range 0..{self.n_electrodes - 1}: {el}")
        bad = np.zeros(self.n_electrodes, dtype=bool)
        bad[el] = True
        k = self.measurements[:, 0]
        driving = (self.current_patterns[:, bad] != 0).any(axis=1)  # [n_inj]
        return driving[k] | bad[self.measurements[:, 1]] | bad[self.measurements[:, 2]]


def build_protocol(spec: ProtocolSpec, n_electrodes: int) -> Protocol:
    """Expand ``spec`` for ``n_electrodes`` electrodes into the frame's pairs (config numbering)."""
    spec.validate(n_electrodes)
    n = int(n_electrodes)
    currents = None
    if spec.drive == "explicit":
        inj = np.array(spec.injections, dtype=np.int64)
    elif spec.drive in ("trigonometric", "currents"):
        currents = (
            trigonometric_currents(n)
            if spec.drive == "trigonometric"
            else np.array(spec.currents, dtype=np.float64)
        )
        inj = np.stack([currents.argmax(axis=1), currents.argmin(axis=1)], axis=1)
    else:
        k = np.arange(n)
        inj = np.stack([k, (k + pattern_offset(spec.drive, spec.drive_skip, n)) % n], axis=1)
    carrying = (
        currents != 0 if currents is not None else np.eye(n, dtype=bool)[inj].any(axis=1)
    )  # [n_inj, n] electrodes carrying current
    keep_driven = (
        spec.drive == "trigonometric" if spec.measure_driven is None else spec.measure_driven
    )
    frame_index = None
    if spec.measure == "explicit":
        meas = np.array(spec.measurements, dtype=np.int64)
        if not keep_driven:
            on_driven = carrying[meas[:, 0], meas[:, 1]] | carrying[meas[:, 0], meas[:, 2]]
            if on_driven.any() and spec.measure_driven is False:
                i = int(np.flatnonzero(on_driven)[0])
                raise ValueError(
                    f"measurements[{i}]: measures on a current-carrying electrode, but "
                    "measure_driven is false"
                )
    else:
        d = pattern_offset(spec.measure, spec.measure_skip, n)
        rows, used = [], []
        for i, (_src, snk) in enumerate(inj):
            start = (snk + 1) % n if spec.order == "rotated" else 0
            m = (start + np.arange(n)) % n
            pairs = np.stack([m, (m + d) % n], axis=1)
            keep = np.ones(n, dtype=bool) if keep_driven else ~carrying[i][pairs].any(axis=1)
            rows.append(np.column_stack([np.full(int(keep.sum()), i), pairs[keep]]))
            used.append(i * n + np.flatnonzero(keep))
        meas = np.concatenate(rows).astype(np.int64)
        if spec.layout == "full":
            frame_index = np.concatenate(used)
        # opposite with an even n visits every pair twice (m, m+n/2) and (m+n/2, m): keep both,
        # as boards do; the values are the negatives of each other.
    if spec.sign == -1:
        meas = meas[:, [0, 2, 1]]
    # board -> config numbering
    board_to_config = (
        np.array(spec.electrode_order, dtype=np.int64)
        if spec.electrode_order is not None
        else (np.arange(n) + spec.first_electrode) % n
    )
    inj = board_to_config[inj]
    meas = meas.copy()
    meas[:, 1:] = board_to_config[meas[:, 1:]]
    if currents is not None:
        config_currents = np.empty_like(currents)
        config_currents[:, board_to_config] = currents
        currents = config_currents
    name = f"{spec.drive}/{spec.measure}"
    if meas.shape[0] == 0:
        raise ValueError(f"protocol {name}: no measurement pair avoids the drive electrodes")
    return Protocol(
        name=name,
        n_electrodes=n,
        injections=inj,
        measurements=meas,
        currents=currents,
        frame_index=frame_index,
        frame_size=len(inj) * n if frame_index is not None else 0,
        complex_part=spec.complex_part,
        magnitude=spec.values == "magnitude" or spec.complex_part == "magnitude",
        board_to_config=board_to_config,
    )
