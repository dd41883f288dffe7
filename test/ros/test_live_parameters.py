"""Live tuning over real DDS: a writable parameter set while the node runs takes effect on the
next frames, a value out of its bounds is refused with the reason, a read-only one is
refused, and `ros2 param describe` says which is which.

The reconstruction's colour scale is set with the real `ros2 param set` (skipped where the
ros2 CLI is not installed); the classifier's thresholds through the SetParameters service,
as a robot's tuning tool would.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from eit_skin_msgs.msg import ContactArray, TouchEvent
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.colour_scale import ColourScale
from eit_skin.resources import config_path
from eit_skin.ros.probe import Probe, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import patch_topics
from eit_skin.touch.shapes import layer_image_grid
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros
ROS2 = Path(sys.executable).with_name("ros2")


def ros2(*args: str) -> str:
    """Output of the real ``ros2 param ...`` (stdout and stderr), without the daemon; it
    waits for the node's discovery up to ``EVENT_S``."""
    command = [str(ROS2), *args, "--no-daemon", "--timeout", str(int(EVENT_S))]
    result = subprocess.run(command, capture_output=True, text=True, timeout=2 * EVENT_S)
    return result.stdout + result.stderr


def as_array(msg: Image) -> np.ndarray:
    return np.frombuffer(bytes(msg.data), "<f4").reshape(msg.height, msg.width)


@pytest.mark.skipif(not ROS2.is_file(), reason="ros2 CLI not installed (../shared/ros2-tools)")
def test_colour_scale_set_with_ros2_param_set_colours_the_next_images(tmp_path) -> None:
    namespace = "/live_face"
    topics = patch_topics(load_patch(config_path("face")), namespace).layers["pressure"]
    probe = Probe("live_reconstruction_probe")
    probe.subscribe(Image, topics.image)
    probe.subscribe(Image, topics.image_color)
    logs = tmp_path / "driver.log", tmp_path / "reconstruction.log"
    driver = start_node("eit_driver", namespace, {"patch_config": "face"}, logs[0])
    node = start_node("eit_reconstruction", namespace, {"patch_config": "face"}, logs[1])
    name = f"{namespace}/eit_reconstruction"

    def pairs(after_ns: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
        """(float image, colour image) of one stamp, stamped after ``after_ns``."""
        floats = {stamp_ns(m): as_array(m) for _, m in probe.messages[topics.image]}
        return [
            (floats[stamp_ns(m)], np.frombuffer(bytes(m.data), np.uint8).reshape(-1, 3))
            for _, m in probe.messages[topics.image_color]
            if stamp_ns(m) in floats and stamp_ns(m) > after_ns
        ]

    def coloured_with(top: float, image: np.ndarray, rgb: np.ndarray) -> bool:
        return np.array_equal(ColourScale.named(0.0, top).to_rgb(image).reshape(-1, 3), rgb)

    try:
        assert probe.spin_until(lambda: len(pairs()) >= 3, EVENT_S), logs[1].read_text()
        image, rgb = pairs()[-1]
        assert coloured_with(10000.0, image, rgb)  # the default scale

        output = ros2("param", "set", name, "pressure_range_pa", "0.5")
        assert "Set parameter successful" in output, output
        set_ns = time.time_ns()
        assert probe.spin_until(lambda: len(pairs(set_ns)) >= 2, EVENT_S)
        for image, rgb in pairs(set_ns):
            assert coloured_with(0.5, image, rgb)
            assert not coloured_with(10000.0, image, rgb)  # a visible change

        refused = ros2("param", "set", name, "pressure_range_pa", "0.0")
        assert "Setting parameter failed" in refused, refused
        assert "pressure_range_pa must be > 0, got 0.0" in refused, refused
        after_ns = time.time_ns()
        assert probe.spin_until(lambda: len(pairs(after_ns)) >= 1, EVENT_S)
        assert coloured_with(0.5, *pairs(after_ns)[-1])  # unchanged

        client = AsyncParameterClient(probe.node, name)  # quicker than another CLI start
        future = client.set_parameters([Parameter("jump_k", value=3.0)])
        assert probe.spin_until(future.done, EVENT_S)
        (result,) = future.result().results
        assert not result.successful and "read-only parameter: jump_k" in result.reason
        described = ros2("param", "describe", name, "jump_k", "pressure_range_pa")
        assert "[read-only: read once at start]" in described, described
        assert "[writable while running" in described and "> 0" in described, described
    finally:
        for process, log in zip((node, driver), logs, strict=True):
            assert stop_node(process) == 0, log.read_text()
        probe.close()


def test_classifier_thresholds_set_while_running_stop_events_from_the_next_frame(
    tmp_path,
) -> None:
    namespace, log = "/live_elbow", tmp_path / "classifier.log"
    patch = load_patch(config_path("elbow"))
    topics = patch_topics(patch, namespace)
    grid = layer_image_grid(patch.layer("pressure"))
    probe = Probe("live_classifier_probe")
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    probe.subscribe(TouchEvent, topics.touch_events, reliable)
    probe.subscribe(ContactArray, topics.contacts, 10)
    publisher = probe.node.create_publisher(
        Image, topics.layers["pressure"].image, qos_profile_sensor_data
    )
    node = start_node("eit_classifier", namespace, {"patch_config": "elbow"}, log)
    client = AsyncParameterClient(probe.node, f"{namespace}/eit_classifier")
    rng = np.random.default_rng(0)
    xx, yy = np.meshgrid(grid.x, grid.y)
    blob = 6000.0 * np.exp(-((xx - 0.012) ** 2 + (yy + 0.03) ** 2) / 2e-5)
    contacts = probe.messages[topics.contacts]
    events = probe.messages[topics.touch_events]

    def send(k: int, touch: bool) -> Image:
        values = np.where(grid.inside, 10.0 * rng.standard_normal(xx.shape) + touch * blob, np.nan)
        msg = Image(encoding="32FC1", height=grid.shape[0], width=grid.shape[1])
        msg.header.stamp = Time(sec=1000 + k // 50, nanosec=(k % 50) * 20_000_000)
        msg.step, msg.data = 4 * msg.width, values.astype("<f4").tobytes()
        publisher.publish(msg)
        return msg

    def paced(k: int, touch: bool) -> None:
        """Image ``k``, then its contacts (sent again if none came in 1 s: best effort)."""
        for _ in range(5):
            stamp = stamp_ns(send(k, touch))
            if probe.spin_until(
                lambda stamp=stamp: bool(contacts) and stamp_ns(contacts[-1][1]) >= stamp,
                1.0,
            ):
                return
        raise AssertionError(f"no contacts for image {k}\n{log.read_text()}")

    def set_parameters(**values: float) -> list:
        future = client.set_parameters([Parameter(n, value=v) for n, v in values.items()])
        assert probe.spin_until(future.done, EVENT_S)
        return future.result().results

    def scene(first: int) -> list[int]:
        """0.4 s quiet, 1 s touch, 0.6 s quiet; the states of the events it gave."""
        before = len(events)
        for j in range(100):
            paced(first + j, 20 <= j < 70)
        return [m.state for _, m in events[before:]]

    try:
        assert client.wait_for_services(EVENT_S), log.read_text()
        assert probe.spin_until(lambda: publisher.get_subscription_count() > 0, EVENT_S)
        k = 0
        while not contacts:  # calibrating on quiet images, then it answers each image
            send(k, False)
            probe.spin_until(lambda: bool(contacts), 0.05)
            k += 1
            assert k < 5000, log.read_text()
        states = scene(k)
        assert states[0] == TouchEvent.START and states[-1] == TouchEvent.END, states

        (result,) = set_parameters(k_high=1e6)
        assert result.successful, result.reason
        (result,) = set_parameters(k_detect=1e6)
        assert result.successful, result.reason
        assert scene(k + 100) == []  # the same touch, from its first frame on: no event
        touched = [m for _, m in contacts[-80:-30]]
        assert not any(m.contacts for m in touched)

        # refused with the reason, nothing changed: bounds, a contradiction, read-only
        (result,) = set_parameters(k_detect=-1.0)
        assert not result.successful and "k_detect must be > 0, got -1.0" in result.reason
        (result,) = set_parameters(k_low=2e6)
        assert not result.successful and "k_low" in result.reason and "k_high" in result.reason
        (result,) = set_parameters(calibration_s=1.0)
        assert not result.successful and "read-only" in result.reason
        future = client.get_parameters(["k_detect", "k_low", "calibration_s"])
        assert probe.spin_until(future.done, EVENT_S)
        assert [v.double_value for v in future.result().values] == [1e6, 3.0, 0.5]
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
