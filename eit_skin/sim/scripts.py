"""Built-in touch scripts, and a scenario from a name, a YAML path or a :class:`Scenario`.

Built-in scripts (:data:`BUILTIN_SCENARIOS`) are placed relative to the patch: positions are
fractions of the half-extent of the first layer's outline around its bounding-box centre
(:meth:`~eit_skin.sim.scenario.SheetFrame.point`); ``random`` draws labelled touches
(:func:`~eit_skin.sim.random_scenes.random_scenario`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from eit_skin.patch.model import Patch
from eit_skin.sim.random_scenes import random_scenario
from eit_skin.sim.scenario import Scenario, SheetFrame
from eit_skin.sim.scenario_yaml import load_scenario
from eit_skin.sim.stimuli import Grab, Pinch, PostureTrack, Push, Rub, Stimulus

BUILTIN_SCENARIOS = ("demo", "push", "rub", "pinch", "grab", "idle", "elbow_bend", "random")
"""Names accepted by :func:`builtin_scenario` (``random`` uses the seed)."""


def _script(name: str, frame: SheetFrame, start_s: float = 1.0) -> tuple[list[Stimulus], float]:
    """The built-in scripts (no posture). Returns (touches, duration_s)."""
    p = frame.point
    ext = frame.min_half_extent_m
    push = Push(start_s, 1.2, p(0.25, 0.2), force_n=5.0)
    rub = Rub(
        start_s, 1.6, p(-0.35, -0.25), force_n=3.0, direction_rad=0.0, speed_mps=0.55 * ext / 1.1
    )
    pinch = Pinch(
        start_s,
        1.6,
        p(0.0, 0.1),
        force_n=3.0,
        axis_rad=math.pi / 2,
        start_gap_m=0.9 * ext,
        end_gap_m=0.35 * ext,
    )
    grab = Grab(
        start_s,
        1.5,
        p(0.0, 0.0),
        force_n=3.0,
        offsets=(
            (-0.5 * ext, -0.25 * ext),
            (0.0, 0.5 * ext),
            (0.5 * ext, -0.25 * ext),
            (0.0, -0.55 * ext),
        ),
    )
    single = {"push": push, "rub": rub, "pinch": pinch, "grab": grab}
    if name in single:
        s = single[name]
        return [s], s.t_end_s + 1.5
    if name == "idle":
        return [], 10.0
    if name == "demo":
        touches, t = [], start_s
        for s in (push, rub, pinch, grab):
            shifted = type(s)(**{**_fields(s), "t_start_s": t})
            touches.append(shifted)
            t = shifted.t_end_s + 2.5
        return touches, touches[-1].t_end_s + 2.0
    raise KeyError(name)


def _fields(s: Stimulus) -> dict[str, Any]:
    from dataclasses import fields

    return {f.name: getattr(s, f.name) for f in fields(s)}


def builtin_scenario(name: str, patch: Patch, seed: int = 0, duration_s: float = 30.0):
    """A built-in script by name (see :data:`BUILTIN_SCENARIOS`), placed on ``patch``.

    ``random`` uses ``seed`` and ``duration_s``; the others ignore them.
    """
    frame = SheetFrame.of(patch)
    if name == "random":
        return random_scenario(seed, duration_s, patch)
    if name == "elbow_bend":
        # bend 0 -> 2 rad over 3 s, hold, push while bent, straighten
        posture = PostureTrack(
            ((0.0, 0.0), (1.0, 0.0), (4.0, 2.0), (9.0, 2.0), (11.0, 0.0)),
            crease_y_m=float(frame.center[1]),
            width_m=0.25 * float(2 * frame.half_extent[1]),
        )
        push = Push(5.5, 1.5, frame.point(0.3, 0.35), force_n=5.0)
        return Scenario("elbow_bend", (push,), 12.0, posture)
    if name not in BUILTIN_SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; built-in: {', '.join(BUILTIN_SCENARIOS)}")
    touches, duration = _script(name, frame)
    for s in touches:
        if not frame.fits(s):
            raise ValueError(f"scenario {name!r}: the {s.label} does not fit on patch {patch.name}")
    return Scenario(name, tuple(touches), duration)


def resolve_scenario(
    name_or_path: str | Scenario, patch: Patch, seed: int = 0, duration_s: float | None = None
) -> Scenario:
    """A scenario from a built-in name, a YAML path, or a :class:`Scenario` (returned as is).

    ``duration_s`` (if given) is the length of ``random`` scripts; other scripts are not
    changed by it (the simulator cuts or extends the run instead).
    """
    if isinstance(name_or_path, Scenario):
        return name_or_path
    text = str(name_or_path)
    if text in BUILTIN_SCENARIOS:
        return builtin_scenario(text, patch, seed, 30.0 if duration_s is None else duration_s)
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.exists():
        return load_scenario(path, patch)
    raise KeyError(
        f"unknown scenario {text!r}: not a built-in ({', '.join(BUILTIN_SCENARIOS)}) "
        "and not a .yaml file"
    )
