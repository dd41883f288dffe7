"""The physics simulator: scripted touches -> forward model -> board ADC -> frames.

Modules: ``stimuli`` (touch primitives), ``scenario`` (touch scripts: built-in, random, YAML),
``adc`` (the board's gain, 12-bit ADC and averaging), ``simulator`` (:class:`SkinSimulator`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "AdcConfig": "adc",
    "AdcModel": "adc",
    "Grab": "stimuli",
    "Pinch": "stimuli",
    "Push": "stimuli",
    "Rub": "stimuli",
    "Scenario": "scenario",
    "SkinSimulator": "simulator",
    "load_scenario": "scenario",
    "resolve_scenario": "scenario",
    "simulate_press_session": "press_session",
}

__all__ = [
    "AdcConfig",
    "AdcModel",
    "Grab",
    "Pinch",
    "Push",
    "Rub",
    "Scenario",
    "SkinSimulator",
    "load_scenario",
    "resolve_scenario",
    "simulate_press_session",
]

if TYPE_CHECKING:
    from eit_skin.sim.adc import AdcConfig, AdcModel
    from eit_skin.sim.press_session import simulate_press_session
    from eit_skin.sim.scenario import Scenario, load_scenario, resolve_scenario
    from eit_skin.sim.simulator import SkinSimulator
    from eit_skin.sim.stimuli import Grab, Pinch, Push, Rub


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
