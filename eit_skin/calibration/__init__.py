"""Calibration of a real skin from labelled presses: a data-driven press localiser.

Modules: ``session`` (press session files: frames of presses at known positions, pairing a
robot's probe log with a recording), ``features`` (relative change, pattern, magnitude),
``kernel_ridge`` (RBF kernel ridge with leave-one-out hyperparameters), ``response_map``
(position by matching the pattern to a learnt position -> pattern map), ``physics_prior``
(presses simulated on the device's model as the localiser's prior), ``localiser``
(:class:`PressLocaliser`: fit, k-fold cross-validation, locate, calibration files),
``template`` (a printable 1:1 template of numbered press targets), ``guide`` (calibration by
hand: presses found in a frame stream, judged and paired with the targets), ``online``
(:class:`OnlineLocaliser`: a calibration bound to one layer of a running patch, one frame at a
time; used by the reconstruction node), ``multi_touch`` (several touches at once from
single-press calibrations: superposition), ``stored_fields`` (how each model's fields are
named in a calibration file).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "CalibrationError": "localiser",
    "PressLocaliser": "localiser",
    "PressSession": "session",
    "PressSessionError": "session",
    "PhysicsPrior": "physics_prior",
    "cross_validate": "localiser",
    "load_press_session": "session",
    "pair_probe_csv": "session",
}

__all__ = [
    "CalibrationError",
    "PhysicsPrior",
    "PressLocaliser",
    "PressSession",
    "PressSessionError",
    "cross_validate",
    "load_press_session",
    "pair_probe_csv",
]

if TYPE_CHECKING:
    from eit_skin.calibration.localiser import CalibrationError, PressLocaliser, cross_validate
    from eit_skin.calibration.physics_prior import PhysicsPrior
    from eit_skin.calibration.session import (
        PressSession,
        PressSessionError,
        load_press_session,
        pair_probe_csv,
    )


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
