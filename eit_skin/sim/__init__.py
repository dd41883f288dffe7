"""The physics simulator: scripted touches -> forward model -> board ADC -> frames.

Modules: ``stimuli`` (touch primitives), ``scenario`` (touch scripts: built-in, random, YAML),
``adc`` (the board's gain, 12-bit ADC and averaging), ``simulator`` (:class:`SkinSimulator`).
"""

from __future__ import annotations

from eit_skin.sim.adc import AdcConfig, AdcModel
from eit_skin.sim.scenario import Scenario, load_scenario, resolve_scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.sim.stimuli import Grab, Pinch, Push, Rub

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
]
