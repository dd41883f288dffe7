"""The driver's static transform of its patch frame on /tf_static (real node, real DDS)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from eit_skin.ros.driver import quaternion_from_rpy
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS
from test.support.patch_copies import shipped_patch_data, write_patch
from test.support.patience import EVENT_S

tf2_msgs = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed")
pytestmark = pytest.mark.ros

STARTUP_S = EVENT_S
LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)


def test_quaternion_of_a_quarter_turn_about_z() -> None:
    x, y, z, w = quaternion_from_rpy(0.0, 0.0, math.pi / 2)
    assert (x, y) == (0.0, 0.0) and z == pytest.approx(w) == pytest.approx(math.sqrt(0.5))
    assert quaternion_from_rpy(math.pi, 0.0, 0.0)[0] == pytest.approx(1.0)


def test_late_subscriber_gets_the_patch_transform(tmp_path: Path) -> None:
    """Subscribed only once the driver runs: transient-local QoS still delivers it."""
    probe = Probe("tf_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    log = tmp_path / "driver.log"
    params = {
        "patch_config": "face",
        "tf_parent_frame": "head",
        "tf_pose": "[0.1, 0.0, 0.2, 0.0, 0.0, 1.5707963]",
    }
    driver = start_node("eit_driver", "/face", params, log)
    try:
        assert probe.spin_until(
            lambda: bool(probe.messages[DIAGNOSTICS]) or driver.poll() is not None, STARTUP_S
        ), log.read_text()
        probe.subscribe(tf2_msgs.TFMessage, "/tf_static", LATCHED)
        assert probe.spin_until(lambda: bool(probe.messages["/tf_static"]), STARTUP_S)
    finally:
        assert stop_node(driver) == 0
        probe.close()
    (transform,) = probe.messages["/tf_static"][0][1].transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("head", "face_skin_link")
    t = transform.transform
    assert (t.translation.x, t.translation.y, t.translation.z) == pytest.approx((0.1, 0.0, 0.2))
    assert (t.rotation.z, t.rotation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))


def _driver_transforms(tmp_path: Path, namespace: str, params: dict) -> tuple[list, set[str]]:
    """Start a driver; once it reports, its /tf_static transforms and its publishers' topics."""
    probe = Probe("tf_mount_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    probe.subscribe(tf2_msgs.TFMessage, "/tf_static", LATCHED)
    log = tmp_path / "driver.log"
    driver = start_node("eit_driver", namespace, params, log)
    try:
        assert probe.spin_until(
            lambda: bool(probe.messages[DIAGNOSTICS]) or driver.poll() is not None, STARTUP_S
        ), log.read_text()
        assert driver.poll() is None, log.read_text()
        publishers = probe.node.get_publisher_names_and_types_by_node("eit_driver", namespace)
        topics = {name for name, _ in publishers}
        if "/tf_static" in topics:
            assert probe.spin_until(lambda: bool(probe.messages["/tf_static"]), STARTUP_S)
        transforms = [t for _, m in probe.messages["/tf_static"] for t in m.transforms]
    finally:
        assert stop_node(driver) == 0
        probe.close()
    return transforms, topics


def test_the_patch_mount_places_the_frame_and_publish_tf_false_sends_none(tmp_path: Path) -> None:
    data = shipped_patch_data("face")
    data["mount"] = {"parent_frame": "head_link", "xyz": [0.05, 0.0, 0.1], "rpy": [0, 0, 3.14159]}
    patch = write_patch(tmp_path, data, "mounted_face")
    transforms, _ = _driver_transforms(tmp_path, "/mounted_face", {"patch_config": str(patch)})
    (transform,) = [t for t in transforms if t.child_frame_id == "face_skin_link"]
    assert transform.header.frame_id == "head_link"
    t = transform.transform
    assert (t.translation.x, t.translation.y, t.translation.z) == pytest.approx((0.05, 0, 0.1))
    assert abs(t.rotation.z) == pytest.approx(1.0, abs=1e-5)
    # the URDF has the frame: no publisher of /tf_static at all
    params = {"patch_config": str(patch), "publish_tf": False}
    _, topics = _driver_transforms(tmp_path, "/urdf_face", params)
    assert "/tf_static" not in topics and "/face/pressure/frames" not in topics
    assert "/urdf_face/pressure/frames" in topics
