"""eit_classifier as a real process over DDS: synthetic 32FC1 images in, touch events out."""

from __future__ import annotations

import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from eit_skin_msgs.msg import ContactArray, TouchEvent
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image

from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.probe import Probe, start_node, stop_node

pytestmark = pytest.mark.ros

NS = "/elbow_cls_test"
LAYER = load_patch(config_path("elbow")).layers[0]
GRID = ImageGrid.build(build_mesh(LAYER, LAYER.mesh.inverse_max_edge_m), LAYER.solver.image_pixels)
CENTRE = (0.012, -0.03)


def image_msg(k: int, touch: bool, rng) -> Image:
    xx, yy = np.meshgrid(GRID.x, GRID.y)
    values = 10.0 * rng.standard_normal(xx.shape)
    if touch:
        values += 6000.0 * np.exp(-((xx - CENTRE[0]) ** 2 + (yy - CENTRE[1]) ** 2) / 2e-5)
    values = np.where(GRID.inside, values, np.nan).astype("<f4")
    msg = Image()
    msg.header.stamp = Time(sec=1000 + k // 50, nanosec=(k % 50) * 20_000_000)
    msg.header.frame_id = "elbow_skin_link"
    msg.height, msg.width = values.shape
    msg.encoding = "32FC1"
    msg.is_bigendian = 0
    msg.step = 4 * msg.width
    msg.data = values.tobytes()
    return msg


def test_blob_appears_stays_disappears(tmp_path) -> None:
    probe = Probe("classifier_probe")
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    probe.subscribe(TouchEvent, f"{NS}/touch_events", reliable)
    probe.subscribe(ContactArray, f"{NS}/contacts", 10)
    pub = probe.node.create_publisher(Image, f"{NS}/pressure/image", qos_profile_sensor_data)
    log = tmp_path / "classifier.log"
    node = start_node("eit_classifier", NS, {"patch_config": "elbow"}, log)
    try:
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 20), log.read_text()
        assert probe.spin_until(lambda: probe.node.count_publishers(f"{NS}/touch_events") > 0, 10)
        probe.spin_for(0.5)
        rng = np.random.default_rng(0)
        for k in range(110):  # 0.6 s quiet, 1.0 s touch, 0.6 s quiet at 50 Hz
            pub.publish(image_msg(k, 30 <= k < 80, rng))
            probe.spin_for(0.01)
            time.sleep(0.01)
        topic = f"{NS}/touch_events"
        probe.spin_until(
            lambda: any(m.state == TouchEvent.END for _, m in probe.messages[topic]), 10
        )
        events = [m for _, m in probe.messages[topic]]
        assert events, log.read_text()
        states = [e.state for e in events]
        assert states[0] == TouchEvent.START and states[-1] == TouchEvent.END
        assert TouchEvent.UPDATE in states and states.count(TouchEvent.START) == 1
        assert {e.id for e in events} == {events[0].id}
        start, end = events[0], events[-1]
        assert (
            start.header.stamp.sec * 1e9 + start.header.stamp.nanosec - (1000e9 + 30 * 20e6)
            <= 150e6
        )
        assert end.label == TouchEvent.PUSH and end.patch == "elbow"
        assert end.header.frame_id == "elbow_skin_link"
        pixel = GRID.x[1] - GRID.x[0]
        mid = events[len(events) // 2]
        assert (mid.centroid.x, mid.centroid.y) == pytest.approx(CENTRE, abs=pixel)
        assert end.duration.sec + 1e-9 * end.duration.nanosec == pytest.approx(1.0, abs=0.1)
        arrays = [m for _, m in probe.messages[f"{NS}/contacts"] if m.contacts]
        assert arrays and arrays[len(arrays) // 2].contacts[0].peak > 3000.0
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_bad_patch_refuses_to_start(tmp_path) -> None:
    log = tmp_path / "bad.log"
    node = start_node("eit_classifier", NS, {"patch_config": str(tmp_path / "none.yaml")}, log)
    assert node.wait(30) == 2
    assert "refusing to start" in log.read_text()
