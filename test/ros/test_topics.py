"""The one topic map: names derived from the patch, and no topic name made anywhere else."""

from __future__ import annotations

import ast
import copy
import re
from pathlib import Path

from eit_skin.frames import is_frames_topic
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.resources import config_path
from eit_skin.ros.topics import frames_topic, patch_topics
from test.support.patch_copies import shipped_patch_data

PACKAGE = Path(__file__).resolve().parents[2] / "eit_skin"


def test_arm_names_relative_and_in_its_namespace() -> None:
    arm = load_patch(config_path("arm"))
    rel = patch_topics(arm)
    assert rel.namespace == ""
    assert {k: (v.frames, v.image, v.image_color, v.marker) for k, v in rel.layers.items()} == {
        "pressure": (
            "pressure/frames",
            "pressure/image",
            "pressure/image_color",
            "pressure/skin_marker",
        ),
        "stretch": (
            "stretch/frames",
            "stretch/image",
            "stretch/image_color",
            "stretch/skin_marker",
        ),
    }
    assert (rel.touch_events, rel.contacts, rel.rezero) == (
        "touch_events",
        "contacts",
        "eit_reconstruction/rezero",
    )
    assert (rel.diagnostics, rel.joint_states) == ("/diagnostics", "/joint_states")
    for ns in ("/arm", "arm", "/arm/"):
        full = patch_topics(arm, ns)
        assert full.namespace == "/arm"
        assert full.layers["stretch"].image_color == "/arm/stretch/image_color"
        assert full.touch_events == "/arm/touch_events"
        assert full.rezero == "/arm/eit_reconstruction/rezero"
        assert full.diagnostics == "/diagnostics"
    root = patch_topics(arm, "/")
    assert (root.namespace, root.layers["pressure"].frames) == ("/", "/pressure/frames")
    assert frames_topic("stretch", "/leg") == "/leg/stretch/frames"
    assert frames_topic("stretch") == "stretch/frames"
    # recordings are read back by the same rule, whatever namespace they were made in
    for namespace in ("", "/", "/leg", "/robot/leg"):
        assert is_frames_topic(frames_topic("stretch", namespace), "stretch")
        assert not is_frames_topic(frames_topic("stretch", namespace), "pressure")
    assert not is_frames_topic("/leg/prestretch/frames", "stretch")
    assert not is_frames_topic("/leg/stretch/image", "stretch")


def test_frames_follow_the_layer_name_and_images_its_quantity() -> None:
    data = shipped_patch_data("arm")
    data["layers"][0]["name"] = "front"
    data["layers"][1]["name"] = "back"
    topics = patch_topics(patch_from_dict(data), "/arm")
    assert topics.layers["front"].frames == "/arm/front/frames"
    assert topics.layers["front"].image == "/arm/pressure/image"
    assert topics.layers["back"].image == "/arm/stretch/image"
    # two layers measuring pressure: each image is named after its layer
    second = copy.deepcopy(data["layers"][0])
    second["name"] = "inner"
    data["layers"].append(second)
    topics = patch_topics(patch_from_dict(data), "/arm")
    assert [t.image for t in topics.layers.values()] == [
        "/arm/front/image",
        "/arm/stretch/image",
        "/arm/inner/image",
    ]
    assert list(topics.layers) == ["front", "back", "inner"]


#: a whole string without spaces that ends in a topic's last name (bare ``frames`` and
#: ``contacts`` are common dictionary keys, so only with a slash)
TOPIC_LITERAL = re.compile(
    r"^(\S*/(frames|image|image_color|diagnostics|joint_states|rezero|touch_events|contacts"
    r"|skin_marker)|skin_marker|touch_events|image_color)$"
)


def topic_literals(path: Path) -> list[str]:
    """String constants (docstrings aside, f-string pieces included) that look like topics."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [
        f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {node.value!r}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in docstrings
        and TOPIC_LITERAL.search(node.value)
    ]


def test_no_topic_name_is_made_outside_the_topic_map() -> None:
    found = [
        hit
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "topics.py"
        for hit in topic_literals(path)
    ]
    assert found == []
    # the scan does find them: the topic map itself is full of them
    assert len(topic_literals(PACKAGE / "ros" / "topics.py")) >= 5
