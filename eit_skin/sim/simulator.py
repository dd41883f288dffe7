"""Physics simulator of a skin patch: scripted touches -> forward model -> board ADC -> frames.

For every layer and frame time ``t = k / rate_hz``:

1. the scenario's active stimuli give contact pressure (Pa) and touch strain per element of a
   simulation mesh **finer than the reconstruction mesh** (``mesh_factor * max_edge``, no
   inverse crime); a joint posture adds a sheet-wide strain;
2. the layer material maps them to conductance: pressure layers
   ``sigma0 (1 + p / pressure_scale) / (1 + knit_gauge_factor * posture_strain)`` (the knit's
   stretch sensitivity, only from the joint), stretch layers
   ``sigma0 / (1 + gauge_factor * (touch_strain + posture_strain))``;
3. the forward model gives the voltages: no touch -> the cached no-load (or posture) solve;
   a touch changes a bounded set of elements -> exact low-rank update
   (:class:`~eit_skin.fem.forward_update.LocalForwardUpdate`); identical fields (holds) reuse the
   previous solve;
4. slow drift of sigma0 (temperature) scales the voltages by ``1 / (1 + d(t))``;
5. faults, then the :class:`~eit_skin.sim.adc.AdcModel` (gain, 12-bit quantisation of 1000
   averaged conversions, noise, saturation flags).

Noise of frame ``k`` of layer ``i`` comes from ``numpy.random.default_rng([seed, i, k])``, so
any frame can be computed on its own, in any order, and is reproducible.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import threading
from collections import OrderedDict
from typing import Any

import numpy as np

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.forward_update import LocalForwardUpdate
from eit_skin.fem.mesh import Mesh, build_mesh
from eit_skin.frames import FLAG_SATURATED
from eit_skin.patch.model import Layer, Patch
from eit_skin.patch.protocol import Protocol
from eit_skin.pipeline.builder import forward_model
from eit_skin.sim.adc import AdcConfig, AdcModel
from eit_skin.sim.drift import DriftModel
from eit_skin.sim.faults import Fault, apply_faults
from eit_skin.sim.recording import LayerRecording, SimFrame, SimulatedRecording
from eit_skin.sim.scenario import Scenario, TouchTruth
from eit_skin.sim.scripts import resolve_scenario


class _LayerSim:
    """Forward model of one layer on the simulation mesh, with solve caches."""

    def __init__(self, layer: Layer, mesh_factor: float, knit_gauge_factor: float) -> None:
        self.layer = layer
        self.mesh: Mesh = build_mesh(layer, mesh_factor * layer.mesh.max_edge_m)
        self.model: ForwardModel = forward_model(layer, self.mesh)  # the reconstruction's physics
        self.protocol: Protocol = self.model.protocol
        self.points = self.mesh.centroids
        self.sigma0 = layer.material.sheet_conductance_s
        self.knit_gauge_factor = knit_gauge_factor
        self.no_load = np.full(self.mesh.n_triangles, self.sigma0)
        self.reference_v = self.model.voltages(self.no_load)
        self._volts: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self._updates: OrderedDict[bytes, LocalForwardUpdate] = OrderedDict()
        self.solves = {"direct": 0, "update": 0, "cached": 0}

    def conductance(
        self, pressure: np.ndarray | None, touch_strain: np.ndarray | None, posture_strain
    ) -> tuple[np.ndarray, np.ndarray]:
        """(base sigma without touch, sigma with touch), ``[n_triangles]`` S."""
        material = self.layer.material
        if material.quantity == "pressure":
            base = self.no_load
            if posture_strain is not None:
                base = self.sigma0 / (1.0 + self.knit_gauge_factor * posture_strain)
            sigma = base if pressure is None else base * (1.0 + material.from_physical(pressure))
            return base, sigma
        base = self.no_load
        if posture_strain is not None:
            base = self.sigma0 * (1.0 + material.from_physical(posture_strain))
        if touch_strain is None:
            return base, base
        total = touch_strain if posture_strain is None else touch_strain + posture_strain
        sigma = self.sigma0 * (1.0 + material.from_physical(total))
        sigma = np.where(touch_strain == 0.0, base, sigma)
        return base, sigma

    def voltages(self, base: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """``[M]`` noise-free voltages, V, of ``sigma`` (``base``: the untouched conductance)."""
        key = hashlib.sha1(sigma.tobytes()).digest()
        hit = self._volts.get(key)
        if hit is not None:
            self._volts.move_to_end(key)
            self.solves["cached"] += 1
            return hit
        if sigma is base or np.array_equal(sigma, base):
            volts = self.model.voltages(sigma)
            self.solves["direct"] += 1
        else:
            base_key = hashlib.sha1(base.tobytes()).digest()
            update = self._updates.get(base_key)
            if update is None:
                update = LocalForwardUpdate(self.model, base)
                self._updates[base_key] = update
                while len(self._updates) > 2:
                    self._updates.popitem(last=False)
            direct_before = update.direct_solves
            volts = update.voltages(sigma)
            self.solves["direct" if update.direct_solves > direct_before else "update"] += 1
        self._volts[key] = volts
        while len(self._volts) > 64:
            self._volts.popitem(last=False)
        return volts


class SkinSimulator:
    """Frames of every layer of ``patch`` under a touch scenario.

    Args:
        patch: the skin patch.
        scenario: a :class:`~eit_skin.sim.scenario.Scenario`, a built-in name or a YAML path.
        rate_hz: frame rate, Hz.
        seed: seed of the noise, the drift and (for ``"random"``) the script.
        faults: hardware faults (``Fault`` or ``"dead-electrode:5"`` strings).
        adc: acquisition settings (default :class:`~eit_skin.sim.adc.AdcConfig`).
        drift: sigma0 drift; ``None`` draws a random slow drift from the seed; ``NO_DRIFT``.
        mesh_factor: simulation mesh edge as a fraction of the layer's ``mesh.max_edge``.
        knit_gauge_factor: stretch sensitivity of pressure layers to the joint strain.
        duration_s: length of a ``random`` script, s.
    """

    def __init__(
        self,
        patch: Patch,
        scenario: Scenario | str = "demo",
        rate_hz: float = 50.0,
        seed: int = 0,
        faults: tuple[Fault | str, ...] | list[Fault | str] = (),
        adc: AdcConfig | None = None,
        drift: DriftModel | None = None,
        mesh_factor: float = 0.6,
        knit_gauge_factor: float = 1.0,
        duration_s: float | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: must be > 0, got {rate_hz}")
        self.patch = patch
        self.scenario = resolve_scenario(scenario, patch, seed, duration_s)
        self.rate_hz = float(rate_hz)
        self.seed = int(seed)
        self.drift = DriftModel.random(seed) if drift is None else drift
        self.faults = tuple(Fault.parse(f) if isinstance(f, str) else f for f in faults)
        self._layers = {
            layer.name: _LayerSim(layer, mesh_factor, knit_gauge_factor) for layer in patch.layers
        }
        self._adc = {
            layer.name: AdcModel(_adc_config(adc, layer), self._layers[layer.name].reference_v)
            for layer in patch.layers
        }
        for fault in self.faults:
            if fault.layer is not None and fault.layer not in self._layers:
                raise ValueError(
                    f"fault {fault}: patch {patch.name!r} has no layer {fault.layer!r}"
                )
            for name in self._layers_of(fault):
                fault.check(self._layers[name].protocol, name)
        self._frames: OrderedDict[int, dict[str, SimFrame]] = OrderedDict()
        # one simulator may feed several boards' threads (fake devices of a two-board arm):
        # frames, their cache and the forward models' factorisations are not thread-safe
        self._frame_lock = threading.Lock()

    # ------------------------------------------------------------------ properties
    @property
    def layer_names(self) -> tuple[str, ...]:
        return tuple(self._layers)

    @property
    def n_frames(self) -> int:
        """Frames in one pass of the scenario."""
        return max(1, math.ceil(self.scenario.duration_s * self.rate_hz - 1e-9))

    @property
    def truth(self) -> tuple[TouchTruth, ...]:
        return self.scenario.truth(self.rate_hz)

    @property
    def posture_track(self) -> tuple[tuple[float, float], ...]:
        return self.scenario.posture_track(self.rate_hz)

    def protocol(self, layer: str) -> Protocol:
        return self._layers[layer].protocol

    def mesh(self, layer: str) -> Mesh:
        """The simulation (forward) mesh of ``layer``."""
        return self._layers[layer].mesh

    def forward_model(self, layer: str) -> ForwardModel:
        return self._layers[layer].model

    def adc(self, layer: str) -> AdcModel:
        return self._adc[layer]

    def reference(self, layer: str) -> np.ndarray:
        """``[M]`` noise-free, drift-free no-load voltages of ``layer``, V."""
        return self._layers[layer].reference_v.copy()

    def solve_counts(self) -> dict[str, dict[str, int]]:
        """Per layer: how many frames were solved directly, by update, or from the cache."""
        return {name: dict(sim.solves) for name, sim in self._layers.items()}

    # ------------------------------------------------------------------ fields
    def fields(self, layer: str, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(base sigma, sigma), ``[n_triangles]`` S, of ``layer`` at ``t`` s (no drift)."""
        sim = self._layers[layer]
        active = self.scenario.active(t)
        pressure = touch_strain = None
        if active:
            if sim.layer.material.quantity == "pressure":
                pressure = sum(s.pressure(t, sim.points) for s in active)
            else:
                touch_strain = sum(s.strain(t, sim.points) for s in active)
        posture = self.scenario.posture
        posture_strain = None
        if posture is not None and posture.angle(t) != 0.0:
            posture_strain = posture.strain(t, sim.points)
        if pressure is not None and not np.any(pressure):
            pressure = None
        if touch_strain is not None and not np.any(touch_strain):
            touch_strain = None
        return sim.conductance(pressure, touch_strain, posture_strain)

    def clean_voltages(self, layer: str, t: float) -> np.ndarray:
        """``[M]`` noise-free voltages at ``t`` s, V (physics and drift, before faults/ADC)."""
        sim = self._layers[layer]
        base, sigma = self.fields(layer, t)
        volts = sim.reference_v if sigma is sim.no_load else sim.voltages(base, sigma)
        return volts / (1.0 + self.drift.offset(t))

    # ------------------------------------------------------------------ frames
    def frame(self, k: int) -> dict[str, SimFrame]:
        """Frame ``k`` (time ``k / rate_hz``) of every layer; computed once, then cached.

        Safe to call from several threads (one simulator feeding several fake boards).

        Past the end of the scenario the sheet is unloaded (drift goes on).
        """
        if k < 0:
            raise ValueError(f"frame index must be >= 0, got {k}")
        with self._frame_lock:
            hit = self._frames.get(k)
            if hit is not None:
                return hit
            t = k / self.rate_hz
            out = {}
            for i, name in enumerate(self._layers):
                volts = self.clean_voltages(name, t)
                out[name] = self._acquire(name, i, k, t, volts)
            self._frames[k] = out
            while len(self._frames) > 4096:
                self._frames.popitem(last=False)
            return out

    def _layers_of(self, fault: Fault) -> tuple[str, ...]:
        return tuple(self._layers) if fault.layer is None else (fault.layer,)

    def _acquire(self, name: str, i: int, k: int, t: float, volts: np.ndarray) -> SimFrame:
        adc = self._adc[name]
        faults = [f for f in self.faults if name in self._layers_of(f)]
        rails = None
        if faults:
            fault_rng = np.random.default_rng([self.seed, i, k, 1])
            protocol = self._layers[name].protocol
            volts, rails = apply_faults(volts, protocol, faults, adc.full_scale_v, fault_rng)
        values, flags = adc.convert(volts, np.random.default_rng([self.seed, i, k]))
        if rails is not None:
            values[rails] = adc.rail_v(positive=True)
            flags[rails] |= FLAG_SATURATED
        if self._layers[name].protocol.magnitude:  # a board reporting |V| (values: magnitude)
            values = np.abs(values)
        return SimFrame(values, flags, t)

    def run(self, n_frames: int | None = None, duration_s: float | None = None):
        """Frames ``0..T-1`` of every layer as a :class:`SimulatedRecording`.

        ``T`` = ``n_frames``, or ``duration_s * rate_hz``, or one pass of the scenario.
        """
        if n_frames is None:
            n_frames = (
                self.n_frames
                if duration_s is None
                else max(1, math.ceil(duration_s * self.rate_hz - 1e-9))
            )
        t = np.arange(n_frames) / self.rate_hz
        frames = {name: np.empty((n_frames, self._n_meas(name))) for name in self._layers}
        flags = {name: np.empty((n_frames, self._n_meas(name)), np.uint8) for name in self._layers}
        for k in range(n_frames):
            for name, f in self.frame(k).items():
                frames[name][k] = f.voltages_v
                flags[name][k] = f.flags
        quiet_until = self._quiet_until()
        layers = {}
        for name in self._layers:
            pre = t < quiet_until
            if pre.any():
                reference = frames[name][pre].mean(axis=0)
                kind = f"pre-touch mean of {int(pre.sum())} frames"
            else:
                reference, _ = self._adc[name].convert(self._layers[name].reference_v, None)
                kind = "noise-free"
            layers[name] = LayerRecording(
                frames[name], flags[name], reference, kind, self.reference(name)
            )
        return SimulatedRecording(
            t=t,
            layers=layers,
            truth=tuple(tr for tr in self.truth if tr.t_start_s < t[-1]),
            posture=tuple(p for p in self.posture_track if p[0] <= t[-1]),
            meta=self._meta(),
        )

    def _n_meas(self, name: str) -> int:
        return self._layers[name].protocol.n_measurements

    def _quiet_until(self) -> float:
        """End of the initial no-load period: first touch or first posture change, s."""
        end = self.scenario.first_touch_s()
        posture = self.scenario.posture
        if posture is not None:
            keys = posture.keys
            if keys[0][1] != 0.0:
                return 0.0
            for (t0, _), (_, a1) in itertools.pairwise(keys):
                if a1 != keys[0][1]:
                    end = min(end, t0)
                    break
        return end

    def _meta(self) -> dict[str, Any]:
        layers = {}
        for name, sim in self._layers.items():
            adc = self._adc[name]
            median_snr, min_snr = adc.snr_db(sim.reference_v)
            layers[name] = {
                "n_measurements": sim.protocol.n_measurements,
                "sim_mesh_triangles": sim.mesh.n_triangles,
                "adc_gain": adc.gain,
                "full_scale_v": adc.full_scale_v,
                "lsb_v": adc.lsb_v,
                "noise_v": adc.noise_v,
                "snr_db_median": median_snr,
                "snr_db_min": min_snr,
            }
        return {
            "patch": self.patch.name,
            "scenario": self.scenario.name,
            "rate_hz": self.rate_hz,
            "seed": self.seed,
            "duration_s": self.scenario.duration_s,
            "drift_per_min": self.drift.rate_per_min,
            "faults": [str(f) for f in self.faults],
            "layers": layers,
        }


def _adc_config(adc: AdcConfig | None, layer: Layer) -> AdcConfig:
    """The given settings, else the default ones with the layer's ``full_scale_v`` if stated."""
    if adc is not None:
        return adc
    if layer.full_scale_v is None:
        return AdcConfig()
    return AdcConfig().with_full_scale(layer.full_scale_v)
