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

tf2_msgs = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed")
pytestmark = pytest.mark.ros

STARTUP_S = 120.0
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
