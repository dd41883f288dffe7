"""Finite elements on the sheet: mesh, complete-electrode forward model, image grid.

Modules: ``mesh`` (triangle meshes of a layer), ``forward`` (:class:`ForwardModel`: sparse CEM
assembly, one factorisation for every injection, voltages and Jacobian), ``elements`` (its
element matrices: a sheet's triangles, or a tank of some depth as prism layers),
``forward_update``
(exact Woodbury updates for local changes), ``image_grid`` (element values -> ``[H, W]``
pixels), ``disk`` (disc meshes with exact electrode geometry, for analytic checks),
``device_fit`` (calibrate sheet conductance, contact impedance and a tank's depth to a no-load
frame),
``phantoms`` (small disc targets simulated exactly: the phantom set of every accuracy figure).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "DeviceFit": "device_fit",
    "ForwardModel": "forward",
    "ImageGrid": "image_grid",
    "LocalForwardUpdate": "forward_update",
    "Mesh": "mesh",
    "build_mesh": "mesh",
    "fit_device": "device_fit",
}

__all__ = [
    "DeviceFit",
    "ForwardModel",
    "ImageGrid",
    "LocalForwardUpdate",
    "Mesh",
    "build_mesh",
    "fit_device",
]

if TYPE_CHECKING:
    from eit_skin.fem.device_fit import DeviceFit, fit_device
    from eit_skin.fem.forward import ForwardModel
    from eit_skin.fem.forward_update import LocalForwardUpdate
    from eit_skin.fem.image_grid import ImageGrid
    from eit_skin.fem.mesh import Mesh, build_mesh


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
