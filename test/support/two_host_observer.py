"""An observer on one emulated host (test_two_hosts.py): one JSON line per message heard.

``python two_host_observer.py NAMESPACE`` subscribes the patch's pressure frames (best
effort), pressure images (best effort) and touch events (reliable) and prints
``{"topic": "frames" | "image" | "event", "rx_ns": ..., "stamp_ns": ...}`` per message
(``rx_ns``: time.time_ns() on arrival; the hosts share the machine's clock, so
``rx_ns - stamp_ns`` is the latency from acquisition across the link). Runs until killed.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time

import rclpy
from eit_skin_msgs.msg import EitFrame, TouchEvent
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image


def main() -> None:
    namespace = sys.argv[1]
    rclpy.init()
    node = Node("two_host_observer")

    def report(topic: str):
        def callback(msg) -> None:
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            line = {"topic": topic, "rx_ns": time.time_ns(), "stamp_ns": stamp}
            print(json.dumps(line), flush=True)

        return callback

    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        EitFrame, f"{namespace}/pressure/frames", report("frames"), qos_profile_sensor_data
    )
    node.create_subscription(
        Image, f"{namespace}/pressure/image", report("image"), qos_profile_sensor_data
    )
    node.create_subscription(TouchEvent, f"{namespace}/touch_events", report("event"), reliable)
    with contextlib.suppress(KeyboardInterrupt):  # killed: the test has what it needs
        rclpy.spin(node)


if __name__ == "__main__":
    main()
