"""Simulated presses at several places at once: the truth a several-touches model is checked on.

Press ``k`` is a :class:`~eit_skin.sim.stimuli.Grab` with one fingertip at each of its points
(all pressing at once, each with the same force), with the timing of
:mod:`eit_skin.sim.press_session` (frame ``2k``: the unloaded sheet just before, frame
``2k + 1``: all probes at full press), through the simulator's physics, sigma0 drift and ADC
noise.
"""

from __future__ import annotations

import numpy as np

from eit_skin.patch.model import Patch
from eit_skin.sim.press_session import PRESS_PERIOD_S, simulate_press_frames
from eit_skin.sim.scenario import Scenario
from eit_skin.sim.stimuli import Grab

PROBE_FORCE_N = 5.0
"""Force of every probe, N."""
PROBE_RADIUS_M = 0.006
"""Contact radius of every probe, m."""


def simulate_simultaneous_presses(
    patch: Patch,
    points_xy: np.ndarray,
    layer: str | None = None,
    seed: int = 0,
    drift: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Frames of presses with several probes each (:data:`PROBE_FORCE_N`, :data:`PROBE_RADIUS_M`).

    Args:
        patch: the skin patch.
        points_xy: ``[P, K, 2]`` the K probe centres of each of P presses, m.
        layer: layer whose frames are recorded (default: the first).
        seed: seed of noise and drift.
        drift: slow random sigma0 drift.

    Returns:
        (``[P, M]`` frames at full press, ``[P, M]`` the unloaded frame just before each), V.
    """
    name = layer or patch.layers[0].name
    points = np.asarray(points_xy, dtype=np.float64)
    if points.ndim != 3 or points.shape[2] != 2:
        raise ValueError(f"points_xy: shape {points.shape}, want [P, K, 2]")
    centres = points.mean(axis=1)  # [P, 2]
    touches = tuple(
        Grab(
            k * PRESS_PERIOD_S + 0.2,
            0.6,
            (float(centres[k, 0]), float(centres[k, 1])),
            PROBE_FORCE_N,
            PROBE_RADIUS_M,
            0.1,
            tuple((float(dx), float(dy)) for dx, dy in points[k] - centres[k]),
        )
        for k in range(len(points))
    )
    scenario = Scenario(f"simultaneous-{seed}", touches, len(points) * PRESS_PERIOD_S)
    return simulate_press_frames(patch, scenario, name, seed, drift)
