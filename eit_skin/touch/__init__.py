"""Touches from reconstructed images: contacts, shapes, and the push/rub/pinch/grab classifier.

Modules: ``contacts`` (noise, segmentation, tracking, early detection), ``shapes`` (blob
moments, one fingertip's blur), ``classifier`` (:class:`TouchClassifier`: events and labels).
"""

from __future__ import annotations

from eit_skin.touch.classifier import ClassifierConfig, TouchClassifier, TouchEvent
from eit_skin.touch.contacts import ContactSegmenter, SegmentationConfig
from eit_skin.touch.shapes import single_contact_spread

__all__ = [
    "ClassifierConfig",
    "ContactSegmenter",
    "SegmentationConfig",
    "TouchClassifier",
    "TouchEvent",
    "single_contact_spread",
]
