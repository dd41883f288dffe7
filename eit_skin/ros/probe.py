"""Test-side ROS plumbing: start node processes, collect what they publish."""

from __future__ import annotations

import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data

from eit_skin.ros.bringup import find_executable, ros_arguments
from eit_skin.ros.node_graph import NodeSpec

BIN = Path(sys.executable).parent


def stamp_ns(msg: Any) -> int:
    """A stamped message's ``header.stamp`` as integer nanoseconds (the frames' convention)."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def frame_msg(layer, k: int, voltages, patch: str = "elbow", frame_id: str = "elbow_link"):
    """``EitFrame`` number ``k`` of a 50 Hz stream of a patch ``layer``; ``voltages`` [M] V.

    Stamped 1000 s + k * 20 ms: nodes need increasing stamps, not real time.
    """
    import numpy as np

    from eit_skin.frames import FrameRecord
    from eit_skin.hardware.sources import pattern_name

    return FrameRecord(
        stamp_ns=1_000_000_000_000 + k * 20_000_000,
        frame_id=frame_id,
        patch=patch,
        layer=layer.name,
        n_electrodes=layer.n_electrodes,
        drive_pattern=pattern_name(layer),
        current_a=1e-3,
        sequence=k,
        voltages=np.asarray(voltages, np.float32),
        channel_flags=np.zeros(0, np.uint8),
    ).to_msg()


def start_node(
    executable: str, namespace: str, params: dict[str, Any], log: Path
) -> subprocess.Popen:
    """Start an eit_skin console script as its own process with ROS parameters."""
    spec = NodeSpec(executable, executable, namespace, params)
    args = [str(find_executable(executable)), *ros_arguments(spec)]
    return subprocess.Popen(args, stdout=log.open("w"), stderr=subprocess.STDOUT)


def stop_node(process: subprocess.Popen, timeout: float = 10.0) -> int:
    """SIGINT, then wait; returns the exit code."""
    if process.poll() is None:
        process.send_signal(2)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


def lifecycle_set(node: str, transition: str, timeout_s: float = 120.0) -> str:
    """``ros2 lifecycle set NODE TRANSITION`` with the real CLI; its output.

    The venv's ros2cli (../shared/ros2-tools) has no ros2lifecycle: there the same request
    goes to the same service with ``ros2 service call NODE/change_state`` (what
    ``ros2 lifecycle set`` sends).

    Raises:
        AssertionError: the CLI failed or the node refused the transition, with the output.
    """
    ros2 = str(BIN / "ros2")
    if "lifecycle" in {e.name for e in entry_points(group="ros2cli.command")}:
        command, ok = [ros2, "lifecycle", "set", node, transition], "Transitioning successful"
    else:
        request = f"{{transition: {{label: {transition}}}}}"
        service = [f"{node}/change_state", "lifecycle_msgs/srv/ChangeState", request]
        command, ok = [ros2, "service", "call", *service], "success=True"
    result = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
    output = result.stdout + result.stderr
    assert result.returncode == 0 and ok in output, output
    return output


class Probe:
    """An rclpy node in the test process that records messages per topic."""

    def __init__(self, name: str = "probe") -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages: dict[str, list[tuple[float, Any]]] = defaultdict(list)

    def subscribe(self, msg_type: type, topic: str, qos: QoSProfile | int | None = None):
        """Keep every message of ``topic`` in ``messages[topic]``; the subscription."""
        if qos is None:  # sensor-data QoS with a deep queue: the test must not drop frames
            qos = QoSProfile(
                depth=1000,
                reliability=qos_profile_sensor_data.reliability,
                durability=qos_profile_sensor_data.durability,
            )
        return self.node.create_subscription(
            msg_type, topic, lambda m, t=topic: self.messages[t].append((time.monotonic(), m)), qos
        )

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
