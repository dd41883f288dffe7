"""The physics simulator: scripted touches -> forward model -> board ADC -> frames.

Modules: ``stimuli`` (touch primitives), ``scenario`` (the touch script model and where touches
fit), ``scripts`` (built-in scripts; a scenario by name or path), ``random_scenes`` (random and
hard scenes), ``scenario_yaml`` (scenario files),
``adc`` (the board's gain, 12-bit ADC and averaging), ``faults`` (hardware faults), ``drift``
(background drift), ``recording`` (simulated frames and recordings), ``simulator``
(:class:`SkinSimulator`), ``press_session`` (simulated labelled presses for press calibration),
``multi_press`` (presses at several places at once), ``hand_session`` (a simulated
hand-guided calibration: a finger on printed targets).
The phantom set of every accuracy figure is ``eit_skin.fem.phantoms``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "AdcConfig": "adc",
    "AdcModel": "adc",
    "DriftModel": "drift",
    "FAULT_KINDS": "faults",
    "Fault": "faults",
    "Grab": "stimuli",
    "LayerRecording": "recording",
    "NO_DRIFT": "drift",
    "Pinch": "stimuli",
    "Push": "stimuli",
    "Rub": "stimuli",
    "Scenario": "scenario",
    "SimFrame": "recording",
    "SimulatedRecording": "recording",
    "SkinSimulator": "simulator",
    "load_scenario": "scenario_yaml",
    "resolve_scenario": "scripts",
    "simulate_press_session": "press_session",
}

__all__ = [
    "FAULT_KINDS",
    "NO_DRIFT",
    "AdcConfig",
    "AdcModel",
    "DriftModel",
    "Fault",
    "Grab",
    "LayerRecording",
    "Pinch",
    "Push",
    "Rub",
    "Scenario",
    "SimFrame",
    "SimulatedRecording",
    "SkinSimulator",
    "load_scenario",
    "resolve_scenario",
    "simulate_press_session",
]

if TYPE_CHECKING:
    from eit_skin.sim.adc import AdcConfig, AdcModel
    from eit_skin.sim.drift import NO_DRIFT, DriftModel
    from eit_skin.sim.faults import FAULT_KINDS, Fault
    from eit_skin.sim.press_session import simulate_press_session
    from eit_skin.sim.recording import LayerRecording, SimFrame, SimulatedRecording
    from eit_skin.sim.scenario import Scenario
    from eit_skin.sim.scenario_yaml import load_scenario
    from eit_skin.sim.scripts import resolve_scenario
    from eit_skin.sim.simulator import SkinSimulator
    from eit_skin.sim.stimuli import Grab, Pinch, Push, Rub


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
