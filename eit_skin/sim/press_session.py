"""Simulated press sessions: a robot pressing a probe at random places of any patch.

Press ``k`` is a :class:`~eit_skin.sim.stimuli.Push` from ``k + 0.2`` s to ``k + 0.8`` s
(ramps 0.1 s); the simulator runs at 2 Hz, so frame ``2k`` (t = k s) is the unloaded sheet just
before the press (its own baseline) and frame ``2k + 1`` (t = k + 0.5 s) the full press. Every
frame goes through the simulator's physics, sigma0 drift and ADC noise.

Positions are uniform over the sheet with the contact disc at least ``EDGE_MARGIN_M`` inside
every outline and outside the layer's holes. Depths are uniform in ``depth_range_m``; the probe
force follows Hertz's law ``F ~ depth^1.5``, scaled so the depth range spans ``force_range_n``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from eit_skin.calibration.session import PressSession
from eit_skin.fem.device_fit import DeviceFit, fit_device
from eit_skin.fem.elements import layer_depth
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.device import NEGATIVE_INPUT_GAIN
from eit_skin.patch.geometry import points_in_polygon
from eit_skin.patch.model import Patch
from eit_skin.sim.drift import NO_DRIFT
from eit_skin.sim.scenario import EDGE_MARGIN_M, Scenario, SheetFrame
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Push

PRESS_PERIOD_S = 1.0
"""Time per press (baseline frame, then the press), s."""


def random_press_positions(
    patch: Patch, layer: str, n: int, radius_m: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """``[n, 2]`` uniform points whose disc of ``radius_m`` [n] fits the sheet, m."""
    frame = SheetFrame.of(patch)
    holes = patch.layer(layer).holes
    out = np.empty((0, 2))
    for _ in range(100):
        candidates = frame.center + rng.uniform(-1.0, 1.0, size=(4 * n, 2)) * frame.half_extent
        r = radius_m[len(out) : len(out) + len(candidates)]
        r = np.pad(r, (0, len(candidates) - len(r)), constant_values=float(radius_m.max()))
        ok = frame.clearance(candidates) >= r + EDGE_MARGIN_M
        for hole in holes:
            ok &= ~points_in_polygon(candidates, hole)
        out = np.vstack([out, candidates[ok][: n - len(out)]])
        if len(out) == n:
            return out
    raise ValueError(f"patch {patch.name!r} layer {layer!r}: no room for a press of the probe")


@dataclass(frozen=True)
class PressDraw:
    """What the presses of a simulated session are drawn from.

    Attributes:
        depth_range_m: press depths, m (uniform).
        force_range_n: probe force at the shallowest and deepest press, N.
        radius_range_m: probe contact radius, m (uniform per press).
        drift: slow random sigma0 drift (temperature); per-press baselines follow it.
    """

    depth_range_m: tuple[float, float] = (0.002, 0.006)
    force_range_n: tuple[float, float] = (2.0, 8.0)
    radius_range_m: tuple[float, float] = (0.005, 0.0075)
    drift: bool = True


def simulate_press_session(
    patch: Patch,
    n_presses: int,
    layer: str | None = None,
    seed: int = 0,
    draw: PressDraw = PressDraw(),
) -> PressSession:
    """A press session of ``n_presses`` random presses on ``layer`` (default: the first).

    Args:
        patch: the skin patch.
        n_presses: presses.
        layer: layer whose frames are recorded.
        seed: seed of positions, depths, probe radii, noise and drift.
        draw: the ranges the presses are drawn from, and whether sigma0 drifts.

    Returns:
        The session with ``reference`` (unloaded, t = 0), ``frames``, ``press_xy``, ``depth``
        and per-press ``references``.
    """
    name = layer or patch.layers[0].name
    rng = np.random.default_rng([int(seed), 0x9E55])
    depth = rng.uniform(*draw.depth_range_m, size=n_presses)
    d0, d1 = draw.depth_range_m
    f0, f1 = draw.force_range_n
    share = (depth**1.5 - d0**1.5) / max(d1**1.5 - d0**1.5, np.finfo(float).tiny)
    force = f0 + (f1 - f0) * share
    radius = rng.uniform(*draw.radius_range_m, size=n_presses)
    xy = random_press_positions(patch, name, n_presses, radius, rng)
    touches = tuple(
        Push(
            k * PRESS_PERIOD_S + 0.2,
            0.6,
            (float(xy[k, 0]), float(xy[k, 1])),
            float(force[k]),
            float(radius[k]),
            0.1,
        )
        for k in range(n_presses)
    )
    frames, baselines = simulate_press_frames(
        patch,
        Scenario(f"presses-{seed}", touches, n_presses * PRESS_PERIOD_S),
        name,
        seed,
        draw.drift,
    )
    return PressSession(
        baselines[0], frames, xy, depth, baselines, f"simulated:{patch.name}/{name}/seed={seed}"
    )


def simulate_press_frames(
    patch: Patch, scenario: Scenario, layer: str, seed: int, drift: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Frames of ``layer`` for a scenario with one touch per :data:`PRESS_PERIOD_S`.

    Touch ``k`` of ``scenario`` must be at full press at ``(k + 0.5) * PRESS_PERIOD_S`` and
    released by ``(k + 1) * PRESS_PERIOD_S``.

    Args:
        patch: the skin patch.
        scenario: the touches, one per press period.
        layer: layer whose frames are recorded.
        seed: seed of noise and drift.
        drift: slow random sigma0 drift.

    Returns:
        (``[P, M]`` frames at full press, ``[P, M]`` the unloaded frame just before each), V.
    """
    sim = SkinSimulator(
        patch,
        scenario,
        rate_hz=2.0 / PRESS_PERIOD_S,
        seed=seed,
        drift=None if drift else NO_DRIFT,
    )
    n = len(scenario.touches)
    frames = np.array([sim.frame(2 * k + 1)[layer].voltages_v for k in range(n)])
    baselines = np.array([sim.frame(2 * k)[layer].voltages_v for k in range(n)])
    return frames, baselines


def calibrated_to_device(
    patch: Patch, layer: str, reference: np.ndarray
) -> tuple[Patch, DeviceFit]:
    """``patch`` with ``layer``'s contact impedance and input gains fitted to a device's frame.

    The fit (:func:`~eit_skin.fem.device_fit.fit_device`, gain 1) gives a conductance that
    absorbs the device's unknown gain; only ``z sigma`` shapes relative changes. The layer keeps
    its own sheet conductance (the simulator's ADC works in volts) and takes the contact
    impedance with the fitted ``z sigma``: the frames of the device at the gain that
    conductance implies (``fit-device``'s "gain at the patch's conductance"). Where the board
    has a differential input (its profile offers ``device.negative_input_gain``) and the
    protocol a pair drive, the input gain ratio is fitted too (``fit-device --fit-input-gain``)
    and written to the layer's device section.

    Args:
        patch: the skin patch.
        layer: the layer the device measures.
        reference: ``[M]`` the device's unloaded frame (protocol order, any gain).

    Returns:
        The calibrated patch and the fit (residual, bad contacts).
    """
    chosen = patch.layer(layer)
    protocol = chosen.measured_protocol
    device = chosen.device
    fit_gain = protocol.pair_drive and device.offers(NEGATIVE_INPUT_GAIN.name)
    fit = fit_device(
        build_mesh(chosen),
        protocol,
        np.asarray(reference, float),
        chosen.material.sheet_conductance_s,
        chosen.contact_impedance_ohm_m,
        chosen.current_a,
        magnitude=protocol.magnitude,
        fit_input_gain=fit_gain,
        depth=layer_depth(chosen),
    )
    ratio = fit.sheet_conductance_s / chosen.material.sheet_conductance_s
    z = [float(v) * ratio for v in fit.contact_impedance_ohm_m]
    if fit_gain:
        options = dict(device.options) | {NEGATIVE_INPUT_GAIN.name: fit.negative_input_gain}
        device = replace(device, options=tuple(options.items()))
    fitted = replace(
        chosen,
        contact_impedance_ohm_m=tuple(z) if fit.per_electrode else z[0],
        device=device,
    )
    layers = tuple(fitted if lay.name == layer else lay for lay in patch.layers)
    return replace(patch, layers=layers), fit
