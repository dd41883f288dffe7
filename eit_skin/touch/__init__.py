"""Touches from reconstructed images: contacts, shapes, and the push/rub/pinch/grab classifier.

Modules: ``contacts`` (noise, segmentation, tracking, early detection), ``shapes`` (blob
moments, one fingertip's blur), ``classifier`` (:class:`TouchClassifier`: the per-frame
chain), its concerns ``background`` (baseline and noise following; ``noise_count``: how
well a learnt noise map is known), ``start_gates`` (pooled image, matched filter, flicker and
roughness), ``assembly`` (START / UPDATE / END), ``events`` (events, features, labels) and
``sheet_change`` (after a withdrawn touch: is the sheet still again?), its settings ``config``
(:class:`ClassifierConfig`,
each setting declared once with ``settings``), ``pairing`` (:class:`StampPairer`: pressure
and stretch images of the same moment, also from two boards), ``frame_evidence`` (the raw
frames' shape change over a touch: a close pinch).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "ClassifierConfig": "config",
    "ContactGeometry": "shapes",
    "ContactSegmenter": "contacts",
    "SegmentationConfig": "contacts",
    "StampPairer": "pairing",
    "TouchClassifier": "classifier",
    "TouchEvent": "events",
    "classifier_layers": "classifier",
    "contact_geometry": "shapes",
    "layer_image_grid": "shapes",
    "single_contact_spread": "shapes",
}

__all__ = [
    "ClassifierConfig",
    "ContactGeometry",
    "ContactSegmenter",
    "SegmentationConfig",
    "StampPairer",
    "TouchClassifier",
    "TouchEvent",
    "classifier_layers",
    "contact_geometry",
    "layer_image_grid",
    "single_contact_spread",
]

if TYPE_CHECKING:
    from eit_skin.touch.classifier import TouchClassifier, classifier_layers
    from eit_skin.touch.config import ClassifierConfig
    from eit_skin.touch.contacts import ContactSegmenter, SegmentationConfig
    from eit_skin.touch.events import TouchEvent
    from eit_skin.touch.pairing import StampPairer
    from eit_skin.touch.shapes import (
        ContactGeometry,
        contact_geometry,
        layer_image_grid,
        single_contact_spread,
    )


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
