"""The scenario model: a touch script, its ground truth and where touches fit on a patch.

A :class:`Scenario` is a time-ordered tuple of :mod:`stimuli <eit_skin.sim.stimuli>` (never two at
once) plus an optional joint :class:`~eit_skin.sim.stimuli.PostureTrack`. Its ground truth
(:meth:`Scenario.truth`) is what the classifier and the tests score against.
:class:`SheetFrame` places touches on a patch. Scenarios come from
:mod:`~eit_skin.sim.scripts` (built-in names, :func:`~eit_skin.sim.scripts.resolve_scenario`),
:mod:`~eit_skin.sim.random_scenes` (random and hard scenes) and
:mod:`~eit_skin.sim.scenario_yaml` (files).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.model import Patch
from eit_skin.patch.yaml_reader import ConfigError
from eit_skin.sim.stimuli import PostureTrack, Stimulus

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

    @property
    def min_half_extent_m(self) -> float:
        """The smaller of the half width and half height, m (the scale of random touches)."""
        return float(min(self.half_extent))

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

    def beside(
        self, point: np.ndarray, clearance_m: float
    ) -> tuple[tuple[float, float], np.ndarray]:
        """``clearance_m`` in from ``point`` ``[2]`` (on the outline), towards the centre.

        Returns ``(position, inward)``: that position, m, and the ``[2]`` inward unit vector.
        """
        inward = self.center - point
        inward /= max(float(np.linalg.norm(inward)), 1e-9)
        pos = point + inward * clearance_m
        return (float(pos[0]), float(pos[1])), inward

    def fits(self, stimulus: Stimulus) -> bool:
        """True if every contact disc stays ``EDGE_MARGIN_M`` inside the sheet all the time."""
        t = np.linspace(stimulus.t_start_s, stimulus.t_end_s, 9)
        pts = np.concatenate([stimulus.contacts(float(s)) for s in t])
        return bool(np.all(self.clearance(pts) >= stimulus.radius_m + EDGE_MARGIN_M))
