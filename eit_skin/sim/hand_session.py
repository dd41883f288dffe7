"""A simulated hand-guided calibration: a person pressing a finger on each printed target.

What is simulated (one :class:`~eit_skin.sim.stimuli.Push` per press, in target order):

* **placement**: the finger lands off the printed mark by an isotropic Gaussian error of
  ``placement_rms_m`` root-mean-square distance (default 2 mm: a careful press on a printed
  cross; each axis has ``placement_rms_m / sqrt(2)``), kept on the sheet;
* **timing**: a quiet lead-in (``lead_in_s``), presses held 0.7-1.3 s with 0.12-0.25 s
  press and release ramps, 1.0-1.8 s pauses between presses (reading the next number);
* **strength**: 2-6 N per press over a 5-7 mm contact radius;
* **mistakes**: one press too weak (``weak_target``: a brush of ``WEAK_FORCE_N``, followed by
  a proper press on the same target) and one press the person redoes (``redo_target``: a
  second press after answering ``redo``).

:func:`simulate_hand_session` returns the layer's frames (the ``eit-skin presses guide
--frames`` input), the answers the person gave (one per accepted press) and the true press
positions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from eit_skin.patch.model import Patch
from eit_skin.sim.scenario import EDGE_MARGIN_M, Scenario, SheetFrame
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Push

WEAK_FORCE_N = 0.3
"""Force of the simulated too-weak press, N (a brush of the finger)."""


@dataclass(frozen=True, eq=False)
class HandSession:
    """A simulated hand-guided session of one layer.

    Attributes:
        t: ``[F]`` frame times, s.
        frames: ``[F, M]`` frames, V.
        reference: ``[M]`` mean of the quiet lead-in's frames, V.
        answers: the person's answer after each accepted press, ``"ok"`` or ``"redo"``.
        press_xy: ``[P, 2]`` true centre of every press made, in order, m.
        press_target: ``[P]`` index of the target each press was aimed at.
        press_force_n: ``[P]`` force of each press, N.
    """

    t: np.ndarray
    frames: np.ndarray
    reference: np.ndarray
    answers: tuple[str, ...]
    press_xy: np.ndarray
    press_target: np.ndarray
    press_force_n: np.ndarray


@dataclass(frozen=True)
class HandHabits:
    """How the simulated person presses, and the board's frame rate.

    Attributes:
        placement_rms_m: root-mean-square distance of the finger from the mark, m.
        rate_hz: frame rate, Hz.
        lead_in_s: quiet time before the first press, s.
        weak_target: target (0-based) whose first press is too weak, or None.
        redo_target: target (0-based) pressed twice (the first answered ``redo``), or None.
    """

    placement_rms_m: float = 0.002
    rate_hz: float = 20.0
    lead_in_s: float = 2.0
    weak_target: int | None = 3
    redo_target: int | None = 7


def simulate_hand_session(
    patch: Patch,
    targets: np.ndarray,
    layer: str | None = None,
    seed: int = 0,
    person: HandHabits = HandHabits(),
) -> HandSession:
    """Simulate a person pressing every target of ``targets`` [N, 2] m once, in order.

    Args:
        patch: the skin patch (only ``layer`` is simulated).
        targets: the printed targets, m.
        layer: layer recorded (default: the first).
        seed: seed of placement, timing, force, noise and drift.
        person: how the person presses and how fast the board records.
    """
    name = layer or patch.layers[0].name
    one_layer = dataclasses.replace(patch, layers=(patch.layer(name),))
    rng = np.random.default_rng([int(seed), 0x4A4D])
    frame = SheetFrame.of(one_layer)
    plan: list[tuple[int, float]] = []  # (target, force)
    for k in range(len(targets)):
        if k == person.weak_target:
            plan.append((k, WEAK_FORCE_N))
        plan.append((k, float(rng.uniform(2.0, 6.0))))
        if k == person.redo_target:
            plan.append((k, float(rng.uniform(2.0, 6.0))))
    touches, xy = [], []
    t = person.lead_in_s
    for k, force in plan:
        radius = float(rng.uniform(0.005, 0.007))
        for _ in range(100):
            offset = rng.normal(0.0, person.placement_rms_m / np.sqrt(2.0), size=2)
            at = np.asarray(targets[k], float) + offset
            if frame.clearance(at[None])[0] >= radius + EDGE_MARGIN_M:
                break
        else:
            raise ValueError(f"target {k + 1}: no room for a fingertip on the sheet")
        duration = float(rng.uniform(0.7, 1.3))
        ramp = float(rng.uniform(0.12, 0.25))
        touches.append(Push(t, duration, (float(at[0]), float(at[1])), force, radius, ramp))
        xy.append(at)
        t += duration + float(rng.uniform(1.0, 1.8))
    scenario = Scenario(f"hand-guided-{seed}", tuple(touches), t)
    recording = SkinSimulator(one_layer, scenario, rate_hz=person.rate_hz, seed=seed).run()
    layer_recording = recording.layers[name]
    answers = []
    for i, (k, force) in enumerate(plan):
        if force == WEAK_FORCE_N:
            continue  # rejected by the guide: no question asked
        redo_first = k == person.redo_target and (i + 1 < len(plan) and plan[i + 1][0] == k)
        answers.append("redo" if redo_first else "ok")
    return HandSession(
        recording.t,
        layer_recording.frames,
        layer_recording.reference,
        tuple(answers),
        np.array(xy),
        np.array([k for k, _ in plan]),
        np.array([f for _, f in plan]),
    )
