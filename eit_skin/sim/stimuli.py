"""Touch primitives: contact pressure (Pa) and in-plane strain fields on a sheet over time.

Every stimulus is a frozen dataclass with a time window ``[t_start_s, t_end_s]`` and three
vectorised fields, evaluated at a scalar time ``t`` (s) and points ``[n, 2]`` (m, patch frame):

* ``pressure(t, points) -> [n]`` contact pressure, Pa (>= 0);
* ``strain(t, points) -> [n]`` in-plane (areal) tensile strain, dimensionless (0.05 = 5 %);
* ``contacts(t) -> [k, 2]`` contact centres, m, and ``force(t)`` total normal force, N.

Models (see docs/simulator.md): a fingertip is a Hertz-like contact of radius ``a``
(``p = p0 sqrt(1 - (d/a)^2)``, ``p0 = 3 F / (2 pi a^2)``, so the pressure integrates to the
force ``F``); strain fields use the compactly supported bump ``b(u) = (1 - u^2)^2`` (``|u| < 1``)
so a touch changes a bounded set of elements (the simulator exploits this). Force envelopes
rise and fall with a smoothstep over ``ramp_s``.

* :class:`Push`: one contact pressing in; a small ring of radial stretch around the
  indentation (``PUSH_STRAIN_PER_N`` per newton).
* :class:`Rub`: a pressed contact sliding at ``speed_mps``; an elongated stretch region ahead of
  and behind the finger, and a trail along the path that relaxes with time constant
  ``RUB_TRAIL_TAU_S`` after the finger has passed (it outlives the touch by ~4 tau).
* :class:`Pinch`: two contacts closing from ``start_gap_m`` to ``end_gap_m``; strong stretch
  concentrated between them, growing as they close.
* :class:`Grab`: several (3-5) separate contacts at once over a wide area.
* :class:`PostureTrack`: a joint angle (rad) over time and the smooth strain it puts on a sheet
  over the joint (strongest along the crease).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

PUSH_STRAIN_PER_N = 0.004
"""Peak radial strain of the ring around a push, per newton of force (4 N -> 1.6 %)."""
RUB_STRAIN_PER_N = 0.02
"""Peak lateral strain around a sliding finger, per newton (4 N -> 8 %)."""
RUB_TRAIL_FRACTION = 0.5
"""Strain of the trail, relative to the strain around the finger."""
RUB_TRAIL_TAU_S = 0.15
"""Relaxation time constant of the rub trail, s."""
PINCH_STRAIN_PER_N = 0.06
"""Peak strain between closed pinching fingers, per newton of each finger (3 N -> 18 %)."""
TRAIL_SAMPLES = 16
"""Past finger positions summed into the rub trail (over 4 tau)."""


def smoothstep(u: np.ndarray | float) -> np.ndarray:
    """``3u^2 - 2u^3`` on ``u`` clipped to [0, 1] (C1 ramp from 0 to 1)."""
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def bump(u: np.ndarray) -> np.ndarray:
    """Compact C1 bump ``(1 - u^2)^2`` for ``|u| < 1``, else 0."""
    w = np.clip(1.0 - np.asarray(u, dtype=float) ** 2, 0.0, None)
    return w * w


def hertz_pressure(points: np.ndarray, center: np.ndarray, radius_m: float, force_n: float):
    """``[n]`` Pa: Hertz contact of ``force_n`` N over a disc of ``radius_m`` at ``center``."""
    if force_n <= 0.0:
        return np.zeros(len(points))
    d2 = np.sum((points - center) ** 2, axis=1) / radius_m**2
    p0 = 3.0 * force_n / (2.0 * math.pi * radius_m**2)
    return p0 * np.sqrt(np.clip(1.0 - d2, 0.0, None))


def peak_hertz_pressure(radius_m: float, force_n: float) -> float:
    """Centre pressure ``3 F / (2 pi a^2)``, Pa."""
    return 3.0 * force_n / (2.0 * math.pi * radius_m**2)


def ring_strain(points: np.ndarray, center: np.ndarray, radius_m: float, peak: float):
    """``[n]`` strain: ring of radial stretch around an indentation (support 0.5a..2.3a)."""
    if peak == 0.0:
        return np.zeros(len(points))
    d = np.linalg.norm(points - center, axis=1)
    return peak * bump((d - 1.4 * radius_m) / (0.9 * radius_m))


def oriented_bump(
    points: np.ndarray, center: np.ndarray, direction: np.ndarray, along_m: float, across_m: float
) -> np.ndarray:
    """``[n]`` elliptic bump: half-axes ``along_m`` on ``direction`` (unit), ``across_m``."""
    rel = points - center
    a = rel @ direction
    c = rel @ np.array([-direction[1], direction[0]])
    return bump(np.sqrt((a / along_m) ** 2 + (c / across_m) ** 2))


@dataclass(frozen=True)
class Stimulus:
    """Common parameters of a touch.

    Attributes:
        t_start_s: time the finger(s) make contact, s.
        duration_s: contact time, s (> 2 ramp_s).
        position: ``[2]`` m: the contact centre (push), start (rub), midpoint (pinch) or centroid
            of the contacts (grab).
        force_n: normal force per contact at full press, N.
        radius_m: contact radius of a fingertip, m.
        ramp_s: press and release time, s.
    """

    t_start_s: float
    duration_s: float
    position: tuple[float, float]
    force_n: float = 4.0
    radius_m: float = 0.006
    ramp_s: float = 0.25

    label = "touch"

    def __post_init__(self) -> None:
        if not self.duration_s > 2.0 * self.ramp_s:
            raise ValueError(
                f"duration: must exceed twice the ramp ({2 * self.ramp_s:g} s), "
                f"got {self.duration_s:g}"
            )
        if not self.force_n > 0:
            raise ValueError(f"force_n: must be > 0 N, got {self.force_n:g}")
        if not self.radius_m > 0:
            raise ValueError(f"radius: must be > 0 m, got {self.radius_m:g}")
        if not self.ramp_s > 0:
            raise ValueError(f"ramp: must be > 0 s, got {self.ramp_s:g}")

    @property
    def t_end_s(self) -> float:
        return self.t_start_s + self.duration_s

    @property
    def settle_s(self) -> float:
        """Time after ``t_end_s`` until every field is exactly zero again, s."""
        return 0.0

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.position, dtype=float)

    def envelope(self, t: float) -> float:
        """Force fraction in [0, 1]: smoothstep up over ``ramp_s``, hold, smoothstep down."""
        up = smoothstep((t - self.t_start_s) / self.ramp_s)
        down = smoothstep((self.t_end_s - t) / self.ramp_s)
        return float(min(up, down))

    def active(self, t: float) -> bool:
        return self.t_start_s < t < self.t_end_s + self.settle_s

    def force(self, t: float) -> float:
        """Total normal force of all contacts, N."""
        return self.envelope(t) * self.force_n * len(self.contacts(t))

    def contacts(self, t: float) -> np.ndarray:
        """``[k, 2]`` contact centres, m."""
        return self.center[None, :]

    def centroid(self, t: float) -> np.ndarray:
        """``[2]`` force-weighted centroid of the contacts, m."""
        return self.contacts(t).mean(axis=0)

    @property
    def peak_pressure_pa(self) -> float:
        return peak_hertz_pressure(self.radius_m, self.force_n)

    def pressure(self, t: float, points: np.ndarray) -> np.ndarray:
        """``[n]`` contact pressure, Pa."""
        f = self.envelope(t) * self.force_n
        out = np.zeros(len(points))
        if f <= 0.0:
            return out
        for c in self.contacts(t):
            out += hertz_pressure(points, c, self.radius_m, f)
        return out

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        """``[n]`` in-plane tensile strain (dimensionless)."""
        return np.zeros(len(points))


@dataclass(frozen=True)
class Push(Stimulus):
    """One fingertip pressing in and releasing; a small ring of stretch around it."""

    label = "push"

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        peak = PUSH_STRAIN_PER_N * self.envelope(t) * self.force_n
        return ring_strain(points, self.center, self.radius_m, peak)


@dataclass(frozen=True)
class Rub(Stimulus):
    """A pressed fingertip sliding from ``position`` along ``direction_rad`` at ``speed_mps``.

    The finger presses for ``ramp_s``, slides during the rest of the touch except the final
    ``ramp_s`` (path length ``speed_mps * (duration_s - 2 ramp_s)``), then lifts.
    """

    direction_rad: float = 0.0
    speed_mps: float = 0.05

    label = "rub"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.speed_mps > 0:
            raise ValueError(f"speed: must be > 0 m/s, got {self.speed_mps:g}")

    @property
    def unit(self) -> np.ndarray:
        return np.array([math.cos(self.direction_rad), math.sin(self.direction_rad)])

    @property
    def path_length_m(self) -> float:
        return self.speed_mps * (self.duration_s - 2.0 * self.ramp_s)

    @property
    def settle_s(self) -> float:
        return 4.0 * RUB_TRAIL_TAU_S

    def travel(self, t: np.ndarray | float) -> np.ndarray:
        """Distance slid by time ``t``, m (same shape as ``t``)."""
        moving = np.clip(np.asarray(t, dtype=float) - self.t_start_s - self.ramp_s, 0.0, None)
        return np.minimum(self.speed_mps * moving, self.path_length_m)

    def contacts(self, t: float) -> np.ndarray:
        return (self.center + float(self.travel(t)) * self.unit)[None, :]

    def end_position(self) -> np.ndarray:
        return self.center + self.path_length_m * self.unit

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        a = self.radius_m
        out = np.zeros(len(points))
        env = self.envelope(t)
        if env > 0.0:
            # lateral traction: tension ahead of and behind the sliding finger
            peak = RUB_STRAIN_PER_N * self.force_n * env * self._sliding(t)
            if peak > 0.0:
                out += peak * oriented_bump(
                    points, self.contacts(t)[0], self.unit, 3.0 * a, 1.8 * a
                )
        # trail: stretch left along the path, relaxing with RUB_TRAIL_TAU_S
        tau = RUB_TRAIL_TAU_S
        lags = (np.arange(TRAIL_SAMPLES) + 0.5) * (4.0 * tau / TRAIL_SAMPLES)
        past = t - lags
        weights = np.array([self.envelope(s) * self._sliding(s) for s in past])
        weights *= np.exp(-lags / tau) * (4.0 / TRAIL_SAMPLES)
        trail_peak = RUB_TRAIL_FRACTION * RUB_STRAIN_PER_N * self.force_n
        for s, w in zip(past, weights, strict=True):
            if w > 0.0:
                c = self.center + float(self.travel(s)) * self.unit
                out += trail_peak * w * bump(np.linalg.norm(points - c, axis=1) / (1.5 * a))
        return out

    def _sliding(self, t: float) -> float:
        """1 while the finger slides, 0 before and after (smooth over 0.1 s)."""
        t0 = self.t_start_s + self.ramp_s
        t1 = self.t_end_s - self.ramp_s
        return float(min(smoothstep((t - t0) / 0.1 + 1.0), smoothstep((t1 - t) / 0.1 + 1.0)))


@dataclass(frozen=True)
class Pinch(Stimulus):
    """Two fingertips on ``axis_rad`` through ``position`` closing from one gap to another.

    They press at ``start_gap_m`` apart over ``ramp_s``, close to ``end_gap_m`` during the first
    70 % of the remaining time, hold, and lift over the last ``ramp_s``.
    """

    axis_rad: float = 0.0
    start_gap_m: float = 0.040
    end_gap_m: float = 0.015

    label = "pinch"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 < self.end_gap_m < self.start_gap_m:
            raise ValueError(
                f"end_gap: must be > 0 and < start_gap ({self.start_gap_m:g} m), "
                f"got {self.end_gap_m:g}"
            )

    @property
    def unit(self) -> np.ndarray:
        return np.array([math.cos(self.axis_rad), math.sin(self.axis_rad)])

    def closure(self, t: float) -> float:
        """0 at the start gap, 1 when closed."""
        t0 = self.t_start_s + self.ramp_s
        span = 0.7 * (self.duration_s - 2.0 * self.ramp_s)
        return float(smoothstep((t - t0) / span))

    def gap(self, t: float) -> float:
        return self.start_gap_m + (self.end_gap_m - self.start_gap_m) * self.closure(t)

    def contacts(self, t: float) -> np.ndarray:
        half = 0.5 * self.gap(t) * self.unit
        return np.stack([self.center - half, self.center + half])

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        env = self.envelope(t)
        if env <= 0.0:
            return np.zeros(len(points))
        peak = PINCH_STRAIN_PER_N * self.force_n * env * (0.2 + 0.8 * self.closure(t))
        along = 0.5 * self.gap(t) + self.radius_m
        return peak * oriented_bump(points, self.center, self.unit, along, 1.5 * self.radius_m)


@dataclass(frozen=True)
class Grab(Stimulus):
    """Several fingertips (``offsets`` from ``position``, m) pressing at once."""

    offsets: tuple[tuple[float, float], ...] = ((-0.02, 0.0), (0.0, 0.02), (0.02, 0.0))

    label = "grab"

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.offsets) < 2:
            raise ValueError(f"positions: a grab needs >= 2 contacts, got {len(self.offsets)}")

    def contacts(self, t: float) -> np.ndarray:
        return self.center + np.asarray(self.offsets, dtype=float)

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        peak = PUSH_STRAIN_PER_N * self.envelope(t) * self.force_n
        out = np.zeros(len(points))
        if peak > 0.0:
            for c in self.contacts(t):
                out += ring_strain(points, c, self.radius_m, peak)
        return out


@dataclass(frozen=True)
class PostureTrack:
    """A joint angle over time and the strain it puts on the sheet over the joint.

    The angle is interpolated between keyframes with a smoothstep (rest at every keyframe), and
    held before the first and after the last. The strain is
    ``peak_strain * angle / full_bend_rad * exp(-((y - crease_y_m) / width_m)^2)``: strongest
    along the crease line ``y = crease_y_m`` (across the arm), smooth and sheet-wide.

    Attributes:
        keys: ``((t_s, angle_rad), ...)`` with increasing times.
        full_bend_rad: angle of full flexion, rad.
        peak_strain: strain on the crease at full flexion (1.5 = 150 %, the seed's elbow).
        crease_y_m: y of the crease line, m.
        width_m: 1/e half-width of the stretched band, m.
    """

    keys: tuple[tuple[float, float], ...]
    full_bend_rad: float = 2.5
    peak_strain: float = 1.5
    crease_y_m: float = 0.0
    width_m: float = 0.04

    def __post_init__(self) -> None:
        times = [k[0] for k in self.keys]
        if not self.keys:
            raise ValueError("posture: needs at least one keyframe")
        if any(b <= a for a, b in itertools.pairwise(times)):
            raise ValueError(f"posture: keyframe times must increase, got {times}")
        for t, angle in self.keys:
            if not 0.0 <= angle <= self.full_bend_rad:
                raise ValueError(
                    f"posture: angle {angle:g} rad at t={t:g} s outside [0, {self.full_bend_rad:g}]"
                )

    def angle(self, t: float) -> float:
        """Joint angle at ``t``, rad."""
        keys = self.keys
        if t <= keys[0][0]:
            return float(keys[0][1])
        for (t0, a0), (t1, a1) in itertools.pairwise(keys):
            if t <= t1:
                return float(a0 + (a1 - a0) * smoothstep((t - t0) / (t1 - t0)))
        return float(keys[-1][1])

    def strain(self, t: float, points: np.ndarray) -> np.ndarray:
        scale = self.peak_strain * self.angle(t) / self.full_bend_rad
        if scale == 0.0:
            return np.zeros(len(points))
        return scale * np.exp(-(((points[:, 1] - self.crease_y_m) / self.width_m) ** 2))

    @property
    def changing_until_s(self) -> float:
        return float(self.keys[-1][0])
