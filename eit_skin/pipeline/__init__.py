"""The per-frame pipeline of one layer, shared by the reconstruction node and the CLI.

Modules: ``builder`` (the only place that builds layer -> meshes -> forward model -> the
layer's reconstruction method, cached on disk by content hash), ``model_choice`` (the
coarsest model meeting a layer's accuracy target), ``reference`` (no-load
reference: capture, drift, posture), ``processor`` (the per-frame pipeline of one layer:
reference, drift, flags, faults, units, images), ``frame_plan`` (its common frame planned
once: the frozen plan and the numpy reference step), ``frame_kernel`` (the same step compiled
with numba, bit for bit), ``colour_scale`` (false colour for rviz),
``accuracy_map`` (a design's predicted position error, resolution and amplitude response over
the sheet, from simulated small targets: ``eit-skin patch --predict`` and the designer).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "ColourScale": "colour_scale",
    "FramePlan": "frame_plan",
    "LayerImager": "builder",
    "Operator": "builder",
    "LayerImages": "processor",
    "LayerProcessor": "processor",
    "PostureReferences": "reference",
    "ReferenceTracker": "reference",
    "build_operator": "builder",
    "choose_layer_model": "builder",
    "resolve_layer": "builder",
    "default_cache_dir": "builder",
    "forward_model": "builder",
    "with_method": "builder",
}

__all__ = [
    "ColourScale",
    "FramePlan",
    "LayerImager",
    "LayerImages",
    "LayerProcessor",
    "Operator",
    "PostureReferences",
    "ReferenceTracker",
    "build_operator",
    "choose_layer_model",
    "default_cache_dir",
    "forward_model",
    "resolve_layer",
    "with_method",
]

if TYPE_CHECKING:
    from eit_skin.pipeline.builder import (
        LayerImager,
        Operator,
        build_operator,
        choose_layer_model,
        default_cache_dir,
        forward_model,
        resolve_layer,
        with_method,
    )
    from eit_skin.pipeline.colour_scale import ColourScale
    from eit_skin.pipeline.frame_plan import FramePlan
    from eit_skin.pipeline.processor import LayerImages, LayerProcessor
    from eit_skin.pipeline.reference import PostureReferences, ReferenceTracker


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
