"""Every topic and service name of a skin patch, derived from the patch alone.

The one place these names are made: the nodes (driver, reconstruction, classifier), the
monitor of ``eit-skin run``, the commands that read or write recordings, the benchmarks and
the tests all take them from :func:`patch_topics`, so a publisher and its subscribers cannot
disagree, whatever the patch's layer names. No rclpy here: plain strings.

Names relative to the patch's namespace ``<ns>`` (the namespace of its nodes):

=============================  ==========================  ====================================
name                           type                        from
=============================  ==========================  ====================================
``<layer>/frames``             ``eit_skin_msgs/EitFrame``  driver, one per layer (layer name)
``<image>/image``              ``sensor_msgs/Image``       reconstruction, one per layer
``<image>/image_color``        ``sensor_msgs/Image``       reconstruction, one per layer
``<image>/skin_marker``        ``visualization_msgs/Marker``  reconstruction, one per layer
``eit_reconstruction/rezero``  ``std_srvs/Trigger``        reconstruction (service)
``calibrated_contacts``        ``eit_skin_msgs/ContactArray``  reconstruction (``calibration`` set)
``touch_events``               ``eit_skin_msgs/TouchEvent``  classifier
``contacts``                   ``eit_skin_msgs/ContactArray``  classifier
``/diagnostics``               ``DiagnosticArray``         every node (absolute)
``/joint_states``              ``sensor_msgs/JointState``  the robot (absolute)
=============================  ==========================  ====================================

``<image>`` is the layer's material quantity (``pressure``, ``stretch``), or the layer's name
when another layer of the same patch measures the same quantity.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from eit_skin.frames import FRAMES_TOPIC_NAME

if TYPE_CHECKING:
    from eit_skin.patch.model import Patch

DIAGNOSTICS = "/diagnostics"
"""Diagnostics of every node (absolute: one topic for the whole robot)."""
JOINT_STATES = "/joint_states"
"""Joint angles (posture compensation; published by the simulator for posture scripts)."""
RECONSTRUCTION_NODE = "eit_reconstruction"
"""Node name of the reconstruction; its re-zero service lives under it."""


@dataclass(frozen=True)
class LayerTopics:
    """Topics of one layer.

    Attributes:
        frames: raw frames (``EitFrame``), named after the layer.
        image: physical image (``Image`` 32FC1), named after the layer's quantity.
        image_color: the same image rendered rgb8.
        marker: the layer on the patch's 3-D surface (``Marker``); one topic per layer, so
            stacked layers never draw over each other in one display.
    """

    frames: str
    image: str
    image_color: str
    marker: str


@dataclass(frozen=True)
class PatchTopics:
    """Every topic and service name of one patch (see the module docstring).

    Attributes:
        namespace: ``""`` (names relative to the node's namespace) or ``"/ns"``.
        layers: layer name -> its topics, in the patch's layer order.
        rezero: the reconstruction's re-zero service (``std_srvs/Trigger``).
        calibrated_contacts: press-calibrated contacts of every imaged frame of the
            calibrated layer (``ContactArray``; docs/press-calibration.md).
        touch_events: classified touches (``TouchEvent``).
        contacts: contacts of every image (``ContactArray``).
        diagnostics: ``/diagnostics`` (absolute).
        joint_states: ``/joint_states`` (absolute).
    """

    namespace: str
    layers: dict[str, LayerTopics]
    rezero: str
    calibrated_contacts: str
    touch_events: str
    contacts: str
    diagnostics: str = DIAGNOSTICS
    joint_states: str = JOINT_STATES


def image_prefixes(patch: Patch) -> dict[str, str]:
    """Layer name -> ``<image>``: its quantity, or its name if another layer shares it."""
    quantities = [layer.material.quantity for layer in patch.layers]
    return {
        layer.name: (
            layer.material.quantity
            if quantities.count(layer.material.quantity) == 1
            else layer.name
        )
        for layer in patch.layers
    }


def patch_topics(patch: Patch, namespace: str = "") -> PatchTopics:
    """The topic map of ``patch``.

    Args:
        patch: the validated patch.
        namespace: ``""`` for names relative to the node's namespace (what the nodes use),
            else the patch's namespace (``"/arm"`` or ``"arm"``) for absolute names (what
            a client outside the patch's namespace uses).
    """
    prefix = _prefix(namespace)
    layers = {
        layer: LayerTopics(
            frames=frames_topic(layer, namespace),
            image=f"{prefix}{image}/image",
            image_color=f"{prefix}{image}/image_color",
            marker=f"{prefix}{image}/skin_marker",
        )
        for layer, image in image_prefixes(patch).items()
    }
    return PatchTopics(
        namespace=prefix.rstrip("/") or ("/" if namespace else ""),
        layers=layers,
        rezero=f"{prefix}{RECONSTRUCTION_NODE}/rezero",
        calibrated_contacts=f"{prefix}calibrated_contacts",
        touch_events=f"{prefix}touch_events",
        contacts=f"{prefix}contacts",
    )


def frames_topic(layer: str, namespace: str = "") -> str:
    """``<ns>/<layer>/frames`` of a layer known by its name only (e.g. in a recording)."""
    return f"{_prefix(namespace)}{layer}/{FRAMES_TOPIC_NAME}"


def _prefix(namespace: str) -> str:
    """``""`` (relative names), ``"/"`` (root namespace) or ``"/ns/"``."""
    if not namespace:
        return ""
    ns = namespace.strip("/")
    return f"/{ns}/" if ns else "/"
