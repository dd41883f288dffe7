"""Patch descriptions: the YAML file of one skin patch -> validated, SI-unit dataclasses.

Modules: ``model`` (the :class:`Patch` / :class:`Layer` dataclasses and their content hash),
``loading`` (:func:`load_patch`: YAML file -> validated :class:`Patch`), ``yaml_reader`` (the
one YAML reader and typed-field validator, shared with scenario files), ``outline``,
``electrodes``, ``holes`` (reading those sections), ``mesh_budget`` (refusing a mesh too big
to build), ``geometry`` (plane polygons), ``material`` (sheet conductance ->
pressure/stretch), ``device`` (the board a layer is read from: profile names and
options), ``placement`` (the flat sheet on the robot's 3-D surface), ``protocol``
(drive and measurement pattern: the one place that knows the measurement order; with
``patterns``, its pair offsets and current patterns, and ``input_gain``, a board's unequal
input gains),
``cad_import`` (DXF / SVG drawings -> outline, holes, electrode marks), ``cad_patch`` (a
drawing -> a patch file's data),
``yaml_writer`` (writing patch files, keeping the comments of an edited one).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "ConfigError": "yaml_reader",
    "DeviceSpec": "device",
    "Electrode": "model",
    "Layer": "model",
    "Material": "material",
    "MeshCost": "mesh_budget",
    "MeshSpec": "model",
    "Patch": "model",
    "PatchError": "model",
    "Placement": "placement",
    "Protocol": "protocol",
    "ProtocolSpec": "protocol",
    "SolverSpec": "model",
    "build_protocol": "protocol",
    "estimate_layer": "mesh_budget",
    "load_patch": "loading",
    "patch_from_dict": "loading",
}

__all__ = [
    "ConfigError",
    "DeviceSpec",
    "Electrode",
    "Layer",
    "Material",
    "MeshCost",
    "MeshSpec",
    "Patch",
    "PatchError",
    "Placement",
    "Protocol",
    "ProtocolSpec",
    "SolverSpec",
    "build_protocol",
    "estimate_layer",
    "load_patch",
    "patch_from_dict",
]

if TYPE_CHECKING:
    from eit_skin.patch.device import DeviceSpec
    from eit_skin.patch.loading import load_patch, patch_from_dict
    from eit_skin.patch.material import Material
    from eit_skin.patch.mesh_budget import MeshCost, estimate_layer
    from eit_skin.patch.model import Electrode, Layer, MeshSpec, Patch, PatchError, SolverSpec
    from eit_skin.patch.placement import Placement
    from eit_skin.patch.protocol import Protocol, ProtocolSpec, build_protocol
    from eit_skin.patch.yaml_reader import ConfigError


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
