"""Simulated hardware faults: the kinds, their text form, and what they do to a frame.

``FAULT_KINDS`` is the one table of fault kinds: :class:`Fault` parses and validates against
it, and the help texts of ``eit-skin simulate --fault`` and of the driver's ``faults``
parameter are built from it (:func:`fault_help`), so a documented name always parses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eit_skin.patch.protocol import Protocol


@dataclass(frozen=True)
class FaultKind:
    """One kind of fault.

    Attributes:
        index: what ``INDEX`` counts: ``"electrode"`` or ``"measurement"`` (protocol order).
        effect: what the fault does, for help texts.
        example: an example ``INDEX`` for help texts.
    """

    index: str
    effect: str
    example: int


FAULT_KINDS: dict[str, FaultKind] = {
    "dead-electrode": FaultKind("electrode", "disconnected", 5),
    "saturated-channel": FaultKind("measurement", "stuck at the rail", 17),
}
"""Fault kind name -> what it is (the names of ``KIND:INDEX[@LAYER]``)."""

FLOATING_NOISE_FRACTION = 0.3
"""A floating (disconnected) measurement input reads noise of this fraction of full scale."""


def fault_help(separator: str = ",") -> str:
    """One line for help texts: the syntax, every kind, and an example list joined by ``separator``.

    Every ``KIND:INDEX`` in the returned text parses with :meth:`Fault.parse`.
    """
    kinds = ", ".join(f"{k} ({v.index} INDEX {v.effect})" for k, v in FAULT_KINDS.items())
    example = separator.join(f"{k}:{v.example}" for k, v in FAULT_KINDS.items())
    return f"KIND:INDEX[@LAYER], KIND one of {kinds}; e.g. {example}"


@dataclass(frozen=True)
class Fault:
    """A hardware fault.

    Attributes:
        kind: a key of :data:`FAULT_KINDS`: ``"dead-electrode"`` (disconnected: drive pairs with
            it hit the rail, measurements with it read noise) or ``"saturated-channel"``
            (measurement stuck at the positive rail).
        index: electrode (dead-electrode) or measurement index (saturated-channel).
        layer: layer name, or ``None`` for every layer.
    """

    kind: str
    index: int
    layer: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(
                f"fault: unknown kind {self.kind!r}; expected one of {', '.join(FAULT_KINDS)}"
            )
        if self.index < 0:
            raise ValueError(f"fault: index must be >= 0, got {self.index}")

    @classmethod
    def parse(cls, text: str) -> Fault:
        """``"dead-electrode:5"``, ``"saturated-channel:17@stretch"``."""
        spec, _, layer = text.partition("@")
        kind, sep, index = spec.partition(":")
        if not sep or not index.strip().isdigit():
            raise ValueError(
                f"fault {text!r}: expected KIND:INDEX[@LAYER] with KIND one of "
                f"{', '.join(FAULT_KINDS)}"
            )
        return cls(kind.strip(), int(index), layer.strip() or None)

    def __str__(self) -> str:
        """The text form that :meth:`parse` reads."""
        return f"{self.kind}:{self.index}" + (f"@{self.layer}" if self.layer else "")

    def check(self, protocol: Protocol, layer: str) -> None:
        """Raise ValueError if the index does not exist on ``layer`` (with ``protocol``)."""
        counts = {"electrode": protocol.n_electrodes, "measurement": protocol.n_measurements}
        limit = counts[FAULT_KINDS[self.kind].index]
        if self.index >= limit:
            raise ValueError(f"fault {self}: layer {layer!r} has only {limit}")


def parse_faults(text: str) -> tuple[Fault, ...]:
    """Comma-separated ``KIND:INDEX[@LAYER]`` items (empty items ignored)."""
    return tuple(Fault.parse(item.strip()) for item in text.split(",") if item.strip())


def apply_faults(
    volts: np.ndarray,
    protocol: Protocol,
    faults: tuple[Fault, ...] | list[Fault],
    full_scale_v: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The analogue effect of ``faults`` on one frame, before the ADC.

    Args:
        volts: ``[M]`` noise-free voltages, V, protocol order.
        protocol: the layer's protocol.
        faults: the faults of this layer.
        full_scale_v: the ADC's full scale, V (floating inputs read noise of a fraction of it).
        rng: noise of the floating inputs.

    Returns:
        (voltages ``[M]`` V with floating inputs replaced by noise, ``rails`` bool ``[M]``:
        values the caller pins to the positive rail and flags saturated after the ADC).
    """
    volts = np.array(volts, dtype=np.float64)
    rails = np.zeros(volts.shape, dtype=bool)
    if not faults:
        return volts, rails
    floating = np.zeros(volts.shape, dtype=bool)
    currents = protocol.current_patterns[protocol.measurements[:, 0]]  # [M, n_el]
    for f in faults:
        if f.kind == "dead-electrode":
            driven = currents[:, f.index] != 0
            rails |= driven
            floating |= protocol.touching([f.index]) & ~driven
        else:
            rails[f.index] = True
    noise = rng.standard_normal(volts.shape)
    volts[floating] = FLOATING_NOISE_FRACTION * full_scale_v * noise[floating]
    return volts, rails
