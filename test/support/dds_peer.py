"""A separate process for the DDS exchange test.

``python dds_peer.py pub`` publishes a known EitFrame and TouchEvent at 20 Hz
until killed; ``python dds_peer.py echo`` prints the first EitFrame and the
first TouchEvent it receives as one JSON line each, then exits.
"""

from __future__ import annotations

import json
import sys

import rclpy
from eit_skin_msgs.msg import EitFrame, TouchEvent
from rclpy.qos import qos_profile_sensor_data

VOLTAGES = [0.001 * i - 0.1 for i in range(208)]


def make_frame(seq: int) -> EitFrame:
    msg = EitFrame()
    msg.header.stamp.sec = 1700000000
    msg.header.stamp.nanosec = 123456789
    msg.header.frame_id = "arm_skin_link"
    msg.patch = "arm"
    msg.layer = "pressure"
    msg.n_electrodes = 16
    msg.drive_pattern = "adjacent"
    msg.current_a = 1e-3
    msg.sequence = seq
    msg.voltages = VOLTAGES
    msg.channel_flags = [
        EitFrame.FLAG_SATURATED if i == 7 else EitFrame.FLAG_OK for i in range(208)
    ]
    return msg


def make_event(seq: int) -> TouchEvent:
    msg = TouchEvent()
    msg.header.frame_id = "arm_skin_link"
    msg.patch = "arm"
    msg.id = seq
    msg.label = TouchEvent.PINCH
    msg.state = TouchEvent.START
    msg.confidence = 0.75
    msg.centroid.x = 0.01
    msg.centroid.y = -0.02
    msg.area_m2 = 2.5e-4
    msg.peak = 1500.0
    msg.duration.sec = 1
    msg.duration.nanosec = 500000000
    return msg


def main(mode: str) -> None:
    rclpy.init()
    node = rclpy.create_node(f"dds_peer_{mode}")
    if mode == "pub":
        frames = node.create_publisher(EitFrame, "/arm/pressure/frames", qos_profile_sensor_data)
        events = node.create_publisher(TouchEvent, "/arm/touch_events", 10)
        seq = [0]

        def tick() -> None:
            seq[0] += 1
            frames.publish(make_frame(seq[0]))
            events.publish(make_event(seq[0]))

        node.create_timer(0.05, tick)
        rclpy.spin(node)
        return
    got: dict[str, dict] = {}

    def on_frame(msg: EitFrame) -> None:
        got.setdefault(
            "frame",
            {
                "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "frame_id": msg.header.frame_id,
                "patch": msg.patch,
                "layer": msg.layer,
                "n_electrodes": msg.n_electrodes,
                "drive_pattern": msg.drive_pattern,
                "current_a": msg.current_a,
                "sequence": msg.sequence,
                "voltages": [float(v) for v in msg.voltages],
                "flags": [int(f) for f in msg.channel_flags],
            },
        )

    def on_event(msg: TouchEvent) -> None:
        got.setdefault(
            "event",
            {
                "label": msg.label,
                "state": msg.state,
                "confidence": msg.confidence,
                "centroid": [msg.centroid.x, msg.centroid.y, msg.centroid.z],
                "area_m2": msg.area_m2,
                "peak": msg.peak,
                "duration": [msg.duration.sec, msg.duration.nanosec],
                "id": msg.id,
            },
        )

    node.create_subscription(EitFrame, "/arm/pressure/frames", on_frame, qos_profile_sensor_data)
    node.create_subscription(TouchEvent, "/arm/touch_events", on_event, 10)
    while rclpy.ok() and len(got) < 2:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps(got), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1])
