"""The per-frame pipeline of one layer, shared by the reconstruction node and the CLI.

Modules: ``builder`` (the only place that builds layer -> forward model -> reconstruction
matrix, cached on disk by content hash), ``reference`` (no-load reference: capture, drift,
posture), ``colour_scale`` (false colour for rviz).
"""

from __future__ import annotations

from eit_skin.pipeline.builder import LayerImager, default_cache_dir
from eit_skin.pipeline.colour_scale import ColourScale
from eit_skin.pipeline.reference import PostureReferences, ReferenceTracker

__all__ = [
    "ColourScale",
    "LayerImager",
    "PostureReferences",
    "ReferenceTracker",
    "default_cache_dir",
]
