"""An rviz2 configuration for the launched patches, made from their topic map.

The launch files write one per launch (``rviz:=true``): per patch and layer a Marker display
(``<image>/skin_marker``; the first layer's enabled, the others off, since stacked layers
lie on one surface) and an Image display (``<image>/image_color``), with the names
:func:`eit_skin.ros.topics.patch_topics` gives for the patch in its namespace, so a renamed
patch or namespace is drawn on first launch. No rclpy here.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import yaml

from eit_skin.patch.model import DEFAULT_MOUNT_PARENT, Patch
from eit_skin.ros.topics import patch_topics


def _display(kind: str, name: str, topic: str, enabled: bool, reliable: bool) -> dict:
    return {
        "Class": f"rviz_default_plugins/{kind}",
        "Name": name,
        "Enabled": enabled,
        "Topic": {
            "Value": topic,
            "Depth": 5,
            "Durability Policy": "Volatile",
            "Reliability Policy": "Reliable" if reliable else "Best Effort",
        },
    }


def rviz_config(patches: Sequence[tuple[Patch, str]]) -> dict:
    """The rviz2 configuration (a mapping, as the .rviz YAML) showing ``patches``.

    Args:
        patches: (patch, namespace) of every launched patch, namespace as ``/arm``.

    The fixed frame is the patches' common mount parent (``mount.parent_frame``), else
    ``base_link``. Markers are reliable (the node publishes them reliably), images best
    effort (sensor-data QoS).
    """
    parents = {patch.mount.parent_frame for patch, _ in patches}
    fixed = parents.pop() if len(parents) == 1 else DEFAULT_MOUNT_PARENT
    displays: list[dict] = [
        {
            "Class": "rviz_default_plugins/Grid",
            "Name": "Grid",
            "Enabled": True,
            "Cell Size": 0.1,
            "Plane Cell Count": 20,
            "Reference Frame": "<Fixed Frame>",
        },
        {"Class": "rviz_default_plugins/TF", "Name": "TF", "Enabled": True, "Show Names": True},
    ]
    for patch, namespace in patches:
        topics = patch_topics(patch, namespace)
        for index, (layer, names) in enumerate(topics.layers.items()):
            label = f"{topics.namespace.strip('/') or patch.name} {layer}"
            displays.append(_display("Marker", f"{label} skin", names.marker, index == 0, True))
            displays.append(_display("Image", label, names.image_color, True, False))
    return {
        "Panels": [{"Class": "rviz_common/Displays", "Name": "Displays"}],
        "Visualization Manager": {
            "Class": "",
            "Global Options": {
                "Background Color": "48; 48; 48",
                "Fixed Frame": fixed,
                "Frame Rate": 30,
            },
            "Displays": displays,
            "Tools": [
                {"Class": "rviz_default_plugins/MoveCamera"},
                {"Class": "rviz_default_plugins/Select"},
            ],
            "Views": {
                "Current": {
                    "Class": "rviz_default_plugins/Orbit",
                    "Distance": 0.8,
                    "Focal Point": {"X": 0, "Y": 0, "Z": 0},
                    "Pitch": 0.6,
                    "Yaw": 0.8,
                }
            },
        },
        "Window Geometry": {"Height": 900, "Width": 1400},
    }


def write_rviz_config(patches: Sequence[tuple[Patch, str]], folder: str | Path = "") -> Path:
    """Write :func:`rviz_config` to a new ``.rviz`` file; returns its path.

    ``folder``: where; empty: a fresh temporary folder (never ``~/.ros``).
    """
    directory = Path(folder) if folder else Path(tempfile.mkdtemp(prefix="eit_skin_rviz_"))
    path = directory / "skin.rviz"
    path.write_text(yaml.safe_dump(rviz_config(patches), sort_keys=False))
    return path
