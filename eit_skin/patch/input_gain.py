"""Unequal input gains of a board's difference amplifier (``device.negative_input_gain``).

A differential input whose minus side has gain ``g`` relative to its plus side reads
``(V(plus) - V(sink)) - g (V(minus) - V(sink))`` = ``V(plus) - g V(minus) - (1 - g) V(sink)``:
the two inputs see potentials against the board's ground, the injection's sink (the current
returns through a virtual-ground amplifier), so ``g != 1`` leaks ``(1 - g)`` of the minus
input's common-mode voltage into the reading, largest next to the source, and makes the frame
chiral (a pair reads differently from its mirror pair about the drive axis). Pair drives only
(a current pattern has no single sink); ``g = 1`` is exactly ``V(plus) - V(minus)``.
:attr:`~eit_skin.patch.protocol.Protocol.measurement_terms` (from :func:`measurement_terms`)
is the one place every measurement operator reads it from: the forward model's voltages,
Jacobian and contact sensitivity, so the simulator and the reconstruction.
"""

from __future__ import annotations

import numpy as np


def input_gain_problem(gain: float, pair_drive: bool) -> str | None:
    """Why ``gain`` cannot be a negative input gain of a protocol, or None."""
    if not (np.isfinite(gain) and gain > 0):
        return f"negative_input_gain must be > 0, got {gain}"
    if gain != 1.0 and not pair_drive:
        return (
            f"negative_input_gain {gain:g} needs a pair drive (the inputs' ground is the "
            "injection's sink, which a current pattern does not have)"
        )
    return None


def measurement_terms(
    measurements: np.ndarray, sinks: np.ndarray, gain: float
) -> tuple[np.ndarray, np.ndarray]:
    """(``[M, T]`` electrodes, ``[M, T]`` weights) of ``(injection, plus, minus)`` rows.

    Measurement ``m`` of injection ``k`` is ``sum_t weights[m, t] V_k(electrodes[m, t])``:
    ``T = 2`` (plus, minus; weights 1, -1) at ``gain`` 1, else ``T = 3`` (plus, minus and the
    injection's sink from ``sinks`` ``[n_inj]``; weights 1, -g, g - 1).
    """
    pairs = measurements[:, 1:]
    if gain == 1.0:
        return pairs, np.broadcast_to(np.array([1.0, -1.0]), pairs.shape)
    sink = sinks[measurements[:, 0]]
    weights = np.broadcast_to(np.array([1.0, -gain, gain - 1.0]), (len(pairs), 3))
    return np.column_stack([pairs, sink]), weights
