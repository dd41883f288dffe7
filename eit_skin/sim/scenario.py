"""Scripted touch sequences for the simulator: built-in scripts, random scripts, YAML files.

A :class:`Scenario` is a time-ordered tuple of :mod:`stimuli <eit_skin.sim.stimuli>` (never two at
once) plus an optional joint :class:`~eit_skin.sim.stimuli.PostureTrack`. Its ground truth
(:meth:`Scenario.truth`) is what the classifier and the tests score against.

Built-in scripts (:data:`BUILTIN_SCENARIOS`) are placed relative to the patch: positions are
fractions of the half-extent of the first layer's outline around its bounding-box centre.
``random`` draws labelled touches at random positions, speeds and magnitudes
(:func:`random_scenario`). The YAML format is documented in ``docs/simulator.md``; a bad file
raises :class:`ScenarioError` ``"<file>: <key.path[2]>: <reason>"``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.model import Patch
from eit_skin.patch.yaml_reader import ConfigError, Reader, describe, read_yaml
from eit_skin.sim.stimuli import Grab, Pinch, PostureTrack, Push, Rub, Stimulus
from eit_skin.touch.events import LABELS

BUILTIN_SCENARIOS = ("demo", "push", "rub", "pinch", "grab", "idle", "elbow_bend", "random")
"""Names accepted by :func:`builtin_scenario` (``random`` uses the seed)."""
EDGE_MARGIN_M = 0.004
"""Minimum distance of every contact disc from the sheet's outline, m."""


class ScenarioError(ConfigError):
    """A scenario file is invalid: ``"<file>: <key path>: <reason>"``."""


@dataclass(frozen=True)
class TouchTruth:
    """Ground truth of one touch.

    Attributes:
        label: ``"push" | "rub" | "pinch" | "grab"``.
        t_start_s, t_end_s: contact begins / ends, s (fields may relax up to ``settle_s`` later).
        track: ``((t_s, x_m, y_m), ...)`` centroid of the contacts while in contact.
        contacts: ``((x_m, y_m), ...)`` contact centres at full press (mid-touch).
        peak_pressure_pa: centre pressure of one contact at full force, Pa.
        force_n: force per contact at full press, N.
        settle_s: time after ``t_end_s`` until the sheet is exactly unloaded again, s.
    """

    label: str
    t_start_s: float
    t_end_s: float
    track: tuple[tuple[float, float, float], ...]
    contacts: tuple[tuple[float, float], ...]
    peak_pressure_pa: float
    force_n: float
    settle_s: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "t_start": self.t_start_s,
            "t_end": self.t_end_s,
            "settle": self.settle_s,
            "track": [list(p) for p in self.track],
            "contacts": [list(c) for c in self.contacts],
            "peak_pressure_pa": self.peak_pressure_pa,
            "force_n": self.force_n,
        }


@dataclass(frozen=True)
class Scenario:
    """A touch script.

    Attributes:
        name: script name (or file name).
        touches: stimuli ordered by start time, never overlapping in time.
        duration_s: length of the script, s.
        posture: joint angle track, or ``None`` (no joint).
    """

    name: str
    touches: tuple[Stimulus, ...]
    duration_s: float
    posture: PostureTrack | None = None

    def __post_init__(self) -> None:
        if not self.duration_s > 0:
            raise ValueError(f"duration: must be > 0 s, got {self.duration_s:g}")
        for a, b in zip(self.touches, self.touches[1:], strict=False):
            if b.t_start_s < a.t_end_s:
                raise ValueError(
                    f"touches overlap in time: {a.label} until {a.t_end_s:g} s, "
                    f"{b.label} from {b.t_start_s:g} s"
                )

    def active(self, t: float) -> list[Stimulus]:
        """Stimuli whose fields are non-zero at ``t`` (including a rub's relaxing trail)."""
        return [s for s in self.touches if s.active(t)]

    def first_touch_s(self) -> float:
        """Start of the first touch (``duration_s`` if there is none), s."""
        return self.touches[0].t_start_s if self.touches else self.duration_s

    def truth(self, rate_hz: float = 50.0) -> tuple[TouchTruth, ...]:
        """Ground truth of every touch; tracks sampled at ``rate_hz``."""
        out = []
        for s in self.touches:
            n = max(2, math.ceil(s.duration_s * rate_hz) + 1)
            times = np.linspace(s.t_start_s, s.t_end_s, n)
            track = tuple((float(t), *(float(v) for v in s.centroid(float(t)))) for t in times)
            mid = s.contacts(0.5 * (s.t_start_s + s.t_end_s))
            out.append(
                TouchTruth(
                    label=s.label,
                    t_start_s=float(s.t_start_s),
                    t_end_s=float(s.t_end_s),
                    track=track,
                    contacts=tuple((float(x), float(y)) for x, y in mid),
                    peak_pressure_pa=float(s.peak_pressure_pa),
                    force_n=float(s.force_n),
                    settle_s=float(s.settle_s),
                )
            )
        return tuple(out)

    def posture_track(self, rate_hz: float = 50.0) -> tuple[tuple[float, float], ...]:
        """``((t_s, angle_rad), ...)`` sampled at ``rate_hz`` over the script (empty: no joint)."""
        if self.posture is None:
            return ()
        n = math.ceil(self.duration_s * rate_hz)
        return tuple((k / rate_hz, self.posture.angle(k / rate_hz)) for k in range(n))


# --------------------------------------------------------------------------- sheet geometry


@dataclass(frozen=True, eq=False)
class SheetFrame:
    """Where touches can go on a patch: the outlines of all its layers.

    Attributes:
        center: ``[2]`` bounding-box centre of the first layer's outline, m.
        half_extent: ``[2]`` half width and half height of that box, m.
        outlines: every layer's outline (a contact must lie inside all of them).
    """

    center: np.ndarray
    half_extent: np.ndarray
    outlines: tuple[np.ndarray, ...]

    @classmethod
    def of(cls, patch: Patch) -> SheetFrame:
        outline = patch.layers[0].outline
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        return cls(0.5 * (lo + hi), 0.5 * (hi - lo), tuple(layer.outline for layer in patch.layers))

    def point(self, u: float, v: float) -> tuple[float, float]:
        """Patch point at fractions ``(u, v)`` of the half extents from the centre, m."""
        p = self.center + np.array([u, v]) * self.half_extent
        return (float(p[0]), float(p[1]))

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """``[n]`` distance to the nearest outline edge, m (negative outside any outline)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        out = np.full(len(pts), np.inf)
        for outline in self.outlines:
            d = geometry.distance_to_segments(pts, outline, np.roll(outline, -1, axis=0))
            inside = geometry.points_in_polygon(pts, outline)
            out = np.minimum(out, np.where(inside, d, -d))
        return out

    def fits(self, stimulus: Stimulus) -> bool:
        """True if every contact disc stays ``EDGE_MARGIN_M`` inside the sheet all the time."""
        t = np.linspace(stimulus.t_start_s, stimulus.t_end_s, 9)
        pts = np.concatenate([stimulus.contacts(float(s)) for s in t])
        return bool(np.all(self.clearance(pts) >= stimulus.radius_m + EDGE_MARGIN_M))


# --------------------------------------------------------------------------- built-in scripts


def _script(name: str, frame: SheetFrame, start_s: float = 1.0) -> tuple[list[Stimulus], float]:
    """The built-in scripts (no posture). Returns (touches, duration_s)."""
    p = frame.point
    ext = float(min(frame.half_extent))
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


def random_scenario(seed: int, duration_s: float, patch: Patch) -> Scenario:
    """Labelled touches of random kind, place, speed and magnitude, one after the other.

    Pauses of 0.6-2.0 s separate touches (after a rub's trail has relaxed); every contact stays
    ``EDGE_MARGIN_M`` inside every layer's outline. Deterministic for a given seed and patch.
    """
    rng = np.random.default_rng([int(seed), 0x5EED])
    frame = SheetFrame.of(patch)
    ext = float(min(frame.half_extent))
    touches: list[Stimulus] = []
    t = float(rng.uniform(0.8, 1.5))
    while True:
        label = LABELS[int(rng.integers(len(LABELS)))]
        stimulus = None
        for _ in range(200):
            candidate = _random_touch(rng, label, t, frame, ext)
            if candidate is not None and frame.fits(candidate):
                stimulus = candidate
                break
        if stimulus is None:
            raise ValueError(f"random scenario: no {label} fits on patch {patch.name}")
        if stimulus.t_end_s + stimulus.settle_s + 0.3 > duration_s:
            break
        touches.append(stimulus)
        t = stimulus.t_end_s + stimulus.settle_s + float(rng.uniform(0.6, 2.0))
    return Scenario(f"random-{seed}", tuple(touches), float(duration_s))


def _random_touch(rng, label: str, t: float, frame: SheetFrame, ext: float) -> Stimulus | None:
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
    if label == "pinch":
        start = float(rng.uniform(0.5, 0.9)) * ext
        end = float(rng.uniform(0.3, 0.5)) * start
        if end < 2.2 * radius:
            return None
        return Pinch(
            t,
            float(rng.uniform(1.0, 2.0)),
            pos,
            force * 0.6,
            radius,
            ramp,
            float(rng.uniform(0, math.pi)),
            start,
            end,
        )
    n = int(rng.integers(3, 6))
    angles = (np.arange(n) + rng.uniform(-0.25, 0.25, n)) * (2 * math.pi / n) + rng.uniform(0, 6.3)
    spread = float(rng.uniform(0.35, 0.6)) * ext
    pos = frame.point(*rng.uniform(-0.3, 0.3, size=2))
    offsets = np.column_stack([np.cos(angles), np.sin(angles)]) * spread
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1) + np.eye(n)
    if gaps.min() < 3.0 * radius:
        return None
    return Grab(
        t,
        float(rng.uniform(0.8, 2.0)),
        pos,
        force * 0.6,
        radius,
        ramp,
        tuple((float(x), float(y)) for x, y in offsets),
    )


# --------------------------------------------------------------------------- YAML files


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


# --------------------------------------------------------------------------- hard scenes

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
    ext = float(min(frame.half_extent))
    electrodes = np.array([e.center for e in patch.layers[0].electrodes])
    touches: list[Stimulus] = []
    t = float(rng.uniform(0.8, 1.2))
    while True:
        stimulus = None
        for _ in range(300):
            candidate = _hard_touch(rng, category, t, frame, ext, electrodes)
            if candidate is not None and frame.fits(candidate):
                stimulus = candidate
                break
        if stimulus is None:
            raise ValueError(f"hard scene: no {category} fits on patch {patch.name}")
        if stimulus.t_end_s + stimulus.settle_s + 0.5 > duration_s:
            break
        touches.append(stimulus)
        pause = rng.uniform(0.1, 0.2) if category == "back_to_back" else rng.uniform(0.6, 1.5)
        t = stimulus.t_end_s + stimulus.settle_s + float(pause)
    return Scenario(f"{category}-{seed}", tuple(touches), float(duration_s))


def _hard_touch(
    rng, category: str, t: float, frame: SheetFrame, ext: float, electrodes: np.ndarray
) -> Stimulus | None:
    radius = float(rng.uniform(0.005, 0.0075))
    force = float(rng.uniform(2.0, 6.0))
    ramp = float(rng.uniform(0.1, 0.25))
    if category == "back_to_back":
        label = LABELS[int(rng.integers(len(LABELS)))]
        return _random_touch(rng, label, t, frame, ext)
    if category == "light_push":
        pos = frame.point(*rng.uniform(-0.33, 0.33, size=2))
        return Push(
            t, float(rng.uniform(0.6, 1.5)), pos, float(rng.uniform(1.0, 2.0)), radius, ramp
        )
    if category == "electrode_push":
        e = electrodes[int(rng.integers(len(electrodes)))]
        inward = frame.center - e
        inward /= max(float(np.linalg.norm(inward)), 1e-9)
        pos = e + inward * (radius + EDGE_MARGIN_M + float(rng.uniform(0.0005, 0.003)))
        return Push(
            t, float(rng.uniform(0.6, 1.5)), (float(pos[0]), float(pos[1])), force, radius, ramp
        )
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
            inward = frame.center - e
            inward /= max(float(np.linalg.norm(inward)), 1e-9)
            pos = e + inward * (radius + EDGE_MARGIN_M + float(rng.uniform(0.001, 0.004)))
            pos = (float(pos[0]), float(pos[1]))
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
