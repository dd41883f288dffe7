"""Scenario files: a YAML list of touches (and a posture track) read against a patch.

The format is documented in ``docs/simulator.md``; a bad file raises
:class:`~eit_skin.sim.scenario.ScenarioError` ``"<file>: <key.path[2]>: <reason>"``. Read
like patch files (:func:`eit_skin.patch.yaml_reader.read_yaml`: YAML 1.2 numbers, empty files
and duplicate keys refused).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from eit_skin.patch.model import Patch
from eit_skin.patch.yaml_reader import Reader, describe, read_yaml
from eit_skin.sim.scenario import EDGE_MARGIN_M, Scenario, ScenarioError, SheetFrame
from eit_skin.sim.stimuli import Grab, Pinch, PostureTrack, Push, Rub, Stimulus

_COMMON_KEYS = ("at", "duration", "force_n", "radius", "ramp")
TOUCH_KEYS = {
    "push": (*_COMMON_KEYS, "position"),
    "rub": (*_COMMON_KEYS, "position", "direction_deg", "speed"),
    "pinch": (*_COMMON_KEYS, "position", "axis_deg", "start_gap", "end_gap"),
    "grab": (*_COMMON_KEYS, "positions"),
}
"""Keys of each ``touch`` kind of a scenario file (besides ``touch``)."""


def load_scenario(path: str | Path, patch: Patch) -> Scenario:
    """Read and validate a YAML scenario file against ``patch`` (positions must fit).

    Read like patch files (:func:`eit_skin.patch.yaml_reader.read_yaml`: YAML 1.2 numbers,
    empty files and duplicate keys refused).
    """
    data = read_yaml(path, ScenarioError, list_key="touches")
    return scenario_from_dict(data, patch, source=str(path), name=Path(path).stem)


def scenario_from_dict(
    data: Any, patch: Patch, source: str = "<dict>", name: str = "scenario"
) -> Scenario:
    """Validate parsed YAML (a list of touches or a mapping; see docs/simulator.md)."""
    r = Reader(source, ScenarioError)
    if isinstance(data, list):
        data = {"touches": data}
    if not isinstance(data, Mapping):
        raise r.error("", f"expected a list of touches or a mapping, got {describe(data)}")
    data = r.mapping(data, "", optional=("name", "duration", "touches", "posture"))
    name = r.string(data, "name", "", default=name)
    items = r.sequence(data.get("touches") or [], "touches")
    frame = SheetFrame.of(patch)
    touches = [_touch(r, item, f"touches[{i}]", frame) for i, item in enumerate(items)]
    order = sorted(range(len(touches)), key=lambda i: touches[i].t_start_s)
    for a, b in itertools.pairwise(order):
        if touches[b].t_start_s < touches[a].t_end_s:
            raise r.error(
                f"touches[{b}].at",
                f"starts at {touches[b].t_start_s:g} s while touches[{a}] lasts until "
                f"{touches[a].t_end_s:g} s (touches must not overlap)",
            )
    touches = [touches[i] for i in order]
    posture = None
    if data.get("posture") is not None:
        posture = _posture(r, data["posture"], frame)
    end = max([s.t_end_s + s.settle_s for s in touches] + [0.0])
    if posture is not None:
        end = max(end, posture.changing_until_s)
    if "duration" in data:
        duration = r.number(data, "duration", "", positive=True)
        if duration < end:
            raise r.error("duration", f"{duration:g} s ends before the last touch ({end:g} s)")
    else:
        duration = end + 1.5
    return Scenario(name, tuple(touches), duration, posture)


def _touch(r: Reader, item: Any, path: str, frame: SheetFrame) -> Stimulus:
    kind, item = r.variant(item, path, TOUCH_KEYS, "touch", key="touch")
    common = {
        "t_start_s": r.number(item, "at", path, minimum=0.0),
        "duration_s": r.number(item, "duration", path, positive=True, default=1.5),
        "force_n": r.number(item, "force_n", path, positive=True, default=4.0),
        "radius_m": r.number(item, "radius", path, positive=True, default=0.006),
        "ramp_s": r.number(item, "ramp", path, positive=True, default=0.25),
    }
    try:
        if kind == "grab":
            where = r.join(path, "positions")
            if "positions" not in item:
                raise r.error(where, "missing required key")
            pts = r.points(item["positions"], where, min_len=2)
            c = pts.mean(axis=0)
            offsets = tuple((float(x), float(y)) for x, y in pts - c)
            stimulus: Stimulus = Grab(
                position=(float(c[0]), float(c[1])), offsets=offsets, **common
            )
        else:
            where = r.join(path, "position")
            if "position" not in item:
                raise r.error(where, "missing required key")
            x, y = r.vector(item["position"], where, 2)
            pos = (float(x), float(y))
            if kind == "push":
                stimulus = Push(position=pos, **common)
            elif kind == "rub":
                stimulus = Rub(
                    position=pos,
                    direction_rad=math.radians(r.number(item, "direction_deg", path, default=0.0)),
                    speed_mps=r.number(item, "speed", path, positive=True, default=0.05),
                    **common,
                )
            else:
                stimulus = Pinch(
                    position=pos,
                    axis_rad=math.radians(r.number(item, "axis_deg", path, default=0.0)),
                    start_gap_m=r.number(item, "start_gap", path, positive=True, default=0.04),
                    end_gap_m=r.number(item, "end_gap", path, positive=True, default=0.015),
                    **common,
                )
    except ScenarioError:
        raise
    except ValueError as exc:
        key, _, reason = str(exc).partition(": ")
        raise r.error(r.join(path, key), reason) from None
    if not frame.fits(stimulus):
        key = "positions" if kind == "grab" else "position"
        raise r.error(
            r.join(path, key),
            f"the {kind} leaves the sheet (every contact of radius {stimulus.radius_m:g} m must "
            f"stay {EDGE_MARGIN_M:g} m inside the outline)",
        )
    return stimulus


def _posture(r: Reader, raw: Any, frame: SheetFrame) -> PostureTrack:
    if not isinstance(raw, list) or not raw:
        raise r.error("posture", "expected a non-empty list of {at: s, angle: rad} keyframes")
    keys = []
    for i, item in enumerate(raw):
        where = f"posture[{i}]"
        d = r.mapping(item, where, required=("at", "angle"), what="posture keyframe")
        keys.append(
            (r.number(d, "at", where, minimum=0.0), r.number(d, "angle", where, minimum=0.0))
        )
    for i in range(1, len(keys)):
        if keys[i][0] <= keys[i - 1][0]:
            raise r.error(f"posture[{i}].at", "keyframe times must increase")
    try:
        return PostureTrack(
            tuple(keys),
            crease_y_m=float(frame.center[1]),
            width_m=0.25 * float(2 * frame.half_extent[1]),
        )
    except ValueError as exc:
        raise r.error("posture", str(exc).removeprefix("posture: ")) from None
