"""Random and hard touch scenes: labelled touches one after the other, drawn from a seed.

:func:`random_scenario` draws touches of random kind, place, speed and magnitude;
:func:`hard_scenario` the touches of one hard category (the hard-scene benchmark's). Both
place them in turn (:func:`touches_in_turn`): each drawn until it fits on the sheet, then a
pause. Deterministic for a given seed and patch.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from eit_skin.patch.model import Patch
from eit_skin.sim.scenario import EDGE_MARGIN_M, Scenario, SheetFrame
from eit_skin.sim.stimuli import Grab, Pinch, Push, Rub, Stimulus
from eit_skin.touch.events import LABELS


def random_scenario(seed: int, duration_s: float, patch: Patch) -> Scenario:
    """Labelled touches of random kind, place, speed and magnitude, one after the other.

    Pauses of 0.6-2.0 s separate touches (after a rub's trail has relaxed); every contact stays
    ``EDGE_MARGIN_M`` inside every layer's outline. Deterministic for a given seed and patch.
    """
    rng = np.random.default_rng([int(seed), 0x5EED])
    frame = SheetFrame.of(patch)

    def next_touch(t: float) -> Stimulus:
        label = LABELS[int(rng.integers(len(LABELS)))]
        stimulus = _fitting(frame, lambda: _random_touch(rng, label, t, frame), 200)
        if stimulus is None:
            raise ValueError(f"random scenario: no {label} fits on patch {patch.name}")
        return stimulus

    first_s = float(rng.uniform(0.8, 1.5))
    touches = touches_in_turn(
        first_s, duration_s, 0.3, next_touch, lambda: float(rng.uniform(0.6, 2.0))
    )
    return Scenario(f"random-{seed}", touches, float(duration_s))


def _fitting(frame: SheetFrame, draw: Callable[[], Stimulus | None], tries: int) -> Stimulus | None:
    """The first of ``tries`` draws that fits on the sheet (:meth:`SheetFrame.fits`), or None."""
    for _ in range(tries):
        candidate = draw()
        if candidate is not None and frame.fits(candidate):
            return candidate
    return None


def touches_in_turn(
    t_s: float,
    duration_s: float,
    margin_s: float,
    next_touch: Callable[[float], Stimulus],
    pause: Callable[[], float],
) -> tuple[Stimulus, ...]:
    """Touches one after the other from ``t_s``, s, while each settles in time.

    A touch must settle ``margin_s`` before ``duration_s`` (both s), or it ends the script.
    ``next_touch(t)`` draws the touch starting at ``t``; ``pause()`` the time from one
    touch's settling to the next touch, s.
    """
    touches: list[Stimulus] = []
    while True:
        stimulus = next_touch(t_s)
        if stimulus.t_end_s + stimulus.settle_s + margin_s > duration_s:
            return tuple(touches)
        touches.append(stimulus)
        t_s = stimulus.t_end_s + stimulus.settle_s + pause()


def _random_touch(rng, label: str, t: float, frame: SheetFrame) -> Stimulus | None:
    ext = frame.min_half_extent_m
    radius = float(rng.uniform(0.005, 0.0075))
    force = float(rng.uniform(2.0, 8.0))
    ramp = float(rng.uniform(0.15, 0.3))
    pos = frame.point(*rng.uniform(-0.8, 0.8, size=2))
    if label == "push":
        return Push(t, float(rng.uniform(0.6, 2.0)), pos, force, radius, ramp)
    if label == "rub":
        speed = float(rng.uniform(0.02, 0.1))
        length = float(rng.uniform(0.3, 0.8)) * ext
        duration = length / speed + 2 * ramp
        return Rub(t, duration, pos, force, radius, ramp, float(rng.uniform(0, 2 * math.pi)), speed)
    # a pinch or a grab: several fingertips, each pressing with 0.6 of one finger's force
    fingertip = {"force_n": force * 0.6, "radius_m": radius, "ramp_s": ramp}
    if label == "pinch":
        start = float(rng.uniform(0.5, 0.9)) * ext
        end = float(rng.uniform(0.3, 0.5)) * start
        if end < 2.2 * radius:
            return None
        duration = float(rng.uniform(1.0, 2.0))
        axis = float(rng.uniform(0, math.pi))
        return Pinch(t, duration, pos, **fingertip, axis_rad=axis, start_gap_m=start, end_gap_m=end)
    n = int(rng.integers(3, 6))
    angles = (np.arange(n) + rng.uniform(-0.25, 0.25, n)) * (2 * math.pi / n) + rng.uniform(0, 6.3)
    spread = float(rng.uniform(0.35, 0.6)) * ext
    pos = frame.point(*rng.uniform(-0.3, 0.3, size=2))
    offsets = np.column_stack([np.cos(angles), np.sin(angles)]) * spread
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1) + np.eye(n)
    if gaps.min() < 3.0 * radius:
        return None
    duration = float(rng.uniform(0.8, 2.0))
    offsets_m = tuple((float(x), float(y)) for x, y in offsets)
    return Grab(t, duration, pos, **fingertip, offsets=offsets_m)


HARD_SCENES = (
    "light_push",
    "electrode_push",
    "slow_rub",
    "fast_rub",
    "short_rub",
    "close_pinch",
    "edge_pinch",
    "uneven_grab",
    "palm_grab",
    "back_to_back",
)
"""Touch categories of :func:`hard_scenario` (the hard-scene benchmark's touch scenes)."""


def hard_scenario(category: str, seed: int, duration_s: float, patch: Patch) -> Scenario:
    """Touches of one hard ``category`` (see :data:`HARD_SCENES`) one after the other.

    * ``light_push``: 1-2 N in the middle third of the sheet;
    * ``electrode_push``: 2-6 N with the disc next to an electrode (edge margin only);
    * ``slow_rub`` (10-20 mm/s), ``fast_rub`` (150-250 mm/s), ``short_rub`` (12-15 mm);
    * ``close_pinch`` / ``edge_pinch``: two fingers 15 mm apart closing to 5 mm, in the middle
      / with the pair next to the outline;
    * ``uneven_grab``: 3-5 fingers bunched on one side (30-60 mm across, uneven angles);
    * ``palm_grab``: a palm plus 3-4 fingers (every contact 8-11 mm radius, at most a fifth
      of the sheet's half extent);
    * ``back_to_back``: random kinds (as :func:`random_scenario`) separated by 0.1-0.2 s of
      release.

    Pauses are 0.6-1.5 s (``back_to_back``: 0.1-0.2 s after a rub's trail). Deterministic for a
    given category, seed and patch.
    """
    if category not in HARD_SCENES:
        raise KeyError(f"unknown hard scene {category!r}; one of {', '.join(HARD_SCENES)}")
    rng = np.random.default_rng([int(seed), HARD_SCENES.index(category), 0x4A2D])
    frame = SheetFrame.of(patch)
    electrodes = np.array([e.center for e in patch.layers[0].electrodes])

    def next_touch(t: float) -> Stimulus:
        draw = lambda: _hard_touch(rng, category, t, frame, electrodes)  # noqa: E731
        stimulus = _fitting(frame, draw, 300)
        if stimulus is None:
            raise ValueError(f"hard scene: no {category} fits on patch {patch.name}")
        return stimulus

    def pause() -> float:
        return float(rng.uniform(0.1, 0.2) if category == "back_to_back" else rng.uniform(0.6, 1.5))

    first_s = float(rng.uniform(0.8, 1.2))
    touches = touches_in_turn(first_s, duration_s, 0.5, next_touch, pause)
    return Scenario(f"{category}-{seed}", touches, float(duration_s))


def _hard_touch(
    rng, category: str, t: float, frame: SheetFrame, electrodes: np.ndarray
) -> Stimulus | None:
    ext = frame.min_half_extent_m
    radius = float(rng.uniform(0.005, 0.0075))
    force = float(rng.uniform(2.0, 6.0))
    ramp = float(rng.uniform(0.1, 0.25))
    if category == "back_to_back":
        label = LABELS[int(rng.integers(len(LABELS)))]
        return _random_touch(rng, label, t, frame)
    if category == "light_push":
        pos = frame.point(*rng.uniform(-0.33, 0.33, size=2))
        return Push(
            t, float(rng.uniform(0.6, 1.5)), pos, float(rng.uniform(1.0, 2.0)), radius, ramp
        )
    if category == "electrode_push":
        e = electrodes[int(rng.integers(len(electrodes)))]
        pos, _ = frame.beside(e, radius + EDGE_MARGIN_M + float(rng.uniform(0.0005, 0.003)))
        return Push(t, float(rng.uniform(0.6, 1.5)), pos, force, radius, ramp)
    if category.endswith("_rub"):
        pos = frame.point(*rng.uniform(-0.6, 0.6, size=2))
        if category == "slow_rub":
            speed, length = float(rng.uniform(0.01, 0.02)), float(rng.uniform(0.3, 0.6)) * ext
        elif category == "fast_rub":
            speed, length = float(rng.uniform(0.15, 0.25)), float(rng.uniform(0.5, 0.9)) * ext
        else:
            speed, length = float(rng.uniform(0.02, 0.06)), float(rng.uniform(0.012, 0.015))
        direction = float(rng.uniform(0, 2 * math.pi))
        return Rub(t, length / speed + 2 * ramp, pos, force, radius, ramp, direction, speed)
    if category.endswith("_pinch"):
        radius = float(rng.uniform(0.005, 0.006))
        if category == "close_pinch":
            pos = frame.point(*rng.uniform(-0.3, 0.3, size=2))
            axis = float(rng.uniform(0, math.pi))
        else:  # the pair next to the outline, along it
            e = electrodes[int(rng.integers(len(electrodes)))]
            clearance = radius + EDGE_MARGIN_M + float(rng.uniform(0.001, 0.004))
            pos, inward = frame.beside(e, clearance)
            axis = math.atan2(inward[0], -inward[1])
        start, end = float(rng.uniform(0.014, 0.016)), float(rng.uniform(0.004, 0.006))
        return Pinch(
            t, float(rng.uniform(1.0, 1.8)), pos, force * 0.6, radius, ramp, axis, start, end
        )
    # grabs
    if category == "palm_grab":
        n = int(rng.integers(3, 5))
        radius = min(float(rng.uniform(0.008, 0.011)), 0.2 * ext)
        spread = max(float(rng.uniform(0.5, 0.65)) * ext, 2.5 * radius)
        angles = np.linspace(-1.3, 1.3, n) + rng.uniform(-0.1, 0.1, n) + rng.uniform(0, 6.3)
        offsets = [(0.0, 0.0), *(np.column_stack([np.cos(angles), np.sin(angles)]) * spread)]
    else:
        n = int(rng.integers(3, 6))
        spread = float(rng.uniform(0.3, 0.5)) * ext
        angles = np.sort(rng.uniform(-1.2, 1.2, n)) + rng.uniform(0, 2 * math.pi)
        offsets = list(np.column_stack([np.cos(angles), np.sin(angles)]) * spread)
    offsets_a = np.asarray(offsets, dtype=float)
    offsets_a -= offsets_a.mean(axis=0)
    gaps = np.linalg.norm(offsets_a[:, None] - offsets_a[None], axis=-1) + np.eye(len(offsets_a))
    if gaps.min() < 2.0 * radius:
        return None
    pos = frame.point(*rng.uniform(-0.2, 0.2, size=2))
    return Grab(
        t,
        float(rng.uniform(0.8, 1.8)),
        pos,
        force * 0.6,
        radius,
        ramp,
        tuple((float(x), float(y)) for x, y in offsets_a),
    )
