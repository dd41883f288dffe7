"""The rviz2 configuration the launch files generate names exactly the topics the nodes publish."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray

from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.node_graph import ROBOT_PATCHES
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.rviz_config import write_rviz_config
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from test.support.patch_copies import shipped_patch_data, write_patch

STARTUP_S = 300.0
"""Ceiling of the wait for the node (returns as soon as it reports)."""


def displayed(path: Path) -> dict[str, dict[str, bool]]:
    """Display class -> {topic: enabled} of an .rviz file."""
    config = yaml.safe_load(path.read_text())
    shown: dict[str, dict[str, bool]] = {}
    for display in config["Visualization Manager"]["Displays"]:
        if "Topic" in display:
            kind = display["Class"].rsplit("/", 1)[1]
            shown.setdefault(kind, {})[display["Topic"]["Value"]] = display["Enabled"]
    return shown


def custom_arm(folder: Path) -> Path:
    """The arm with renamed layers, a mount on the forearm and small meshes."""
    data = shipped_patch_data("arm")
    data["name"] = "sleeve"
    data["layers"][0]["name"], data["layers"][1]["name"] = "front", "back"
    for layer in data["layers"]:
        layer["mesh"] = {"max_edge": 0.008, "electrode_edge": 0.002, "inverse_max_edge": 0.012}
    data["mount"] = {"parent_frame": "forearm_link", "xyz": [0.1, 0.0, 0.02]}
    return write_patch(folder, data, "sleeve")


def test_every_shipped_patch_in_any_namespace(tmp_path: Path) -> None:
    patches = [(load_patch(config_path(name)), f"/robot/{name}_skin") for name in ROBOT_PATCHES]
    path = write_rviz_config(patches, tmp_path)
    shown = displayed(path)
    expected_images, expected_markers = set(), set()
    for patch, namespace in patches:
        for topics in patch_topics(patch, namespace).layers.values():
            expected_images.add(topics.image_color)
            expected_markers.add(topics.marker)
    assert set(shown["Image"]) == expected_images
    assert set(shown["Marker"]) == expected_markers
    # stacked layers share a surface: only the first layer's marker is on at first
    assert shown["Marker"]["/robot/arm_skin/pressure/skin_marker"] is True
    assert shown["Marker"]["/robot/arm_skin/stretch/skin_marker"] is False
    fixed = yaml.safe_load(path.read_text())["Visualization Manager"]["Global Options"]
    assert fixed["Fixed Frame"] == "base_link"


@pytest.mark.ros
def test_a_renamed_patch_shows_what_its_reconstruction_publishes(tmp_path: Path) -> None:
    """A real node of a custom patch: its marker and colour image topics, as listed by the
    ROS graph, are exactly the configuration's; the fixed frame is the patch's mount."""
    patch_file = custom_arm(tmp_path)
    patch = load_patch(patch_file)
    namespace = "/left/forearm_skin"
    path = write_rviz_config([(patch, namespace)], tmp_path)
    shown = displayed(path)
    options = yaml.safe_load(path.read_text())["Visualization Manager"]["Global Options"]
    assert options["Fixed Frame"] == "forearm_link"

    probe = Probe("rviz_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    log = tmp_path / "reconstruction.log"
    params = {"patch_config": str(patch_file), "cache_dir": str(tmp_path / "cache")}
    node = start_node("eit_reconstruction", namespace, params, log)
    try:
        reported = probe.spin_until(  # its first diagnostics: every publisher is created
            lambda: (
                node.poll() is not None
                or any(
                    s.name.startswith(f"{namespace}/eit_reconstruction")
                    for _, m in probe.messages[DIAGNOSTICS]
                    for s in m.status
                )
            ),
            STARTUP_S,
        )
        assert reported and node.poll() is None, log.read_text()
        published = {
            name
            for name, _ in probe.node.get_publisher_names_and_types_by_node(
                "eit_reconstruction", namespace
            )
        }
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
    drawable = {t for t in published if t.endswith(("/skin_marker", "/image_color"))}
    assert len(drawable) == 4, published
    assert set(shown["Marker"]) | set(shown["Image"]) == drawable
    assert {t for t in drawable if t.endswith("/skin_marker")} == set(shown["Marker"])


@pytest.mark.parametrize("name", ROBOT_PATCHES)
def test_shipped_patch_alone_in_its_own_namespace(tmp_path: Path, name: str) -> None:
    patch = load_patch(config_path(name))
    shown = displayed(write_rviz_config([(patch, f"/{name}")], tmp_path))
    topics = patch_topics(patch, f"/{name}").layers.values()
    assert set(shown["Image"]) == {t.image_color for t in topics}
    assert set(shown["Marker"]) == {t.marker for t in topics}
