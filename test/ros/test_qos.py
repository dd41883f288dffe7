"""Issue 38, point 2: QoS as REP 2003 asks, overridable by parameters (real nodes, real DDS).

The driver publishes raw frames reliable with a bounded depth, the consumers read them best
effort; a driver started with ``qos_overrides`` parameters publishes with those instead, and
the read-only parameters say what each endpoint uses."""

from __future__ import annotations

import pytest
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import ReliabilityPolicy

from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.qos import RAW_FRAMES_DEPTH
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

OVERRIDE = "qos_overrides./qos_b/pressure/frames.publisher"


def test_raw_frames_are_reliable_consumers_best_effort_and_both_overridable(tmp_path) -> None:
    probe = Probe("qos_probe")
    nodes = []
    try:
        for namespace, extra in (
            ("/qos_a", {}),
            ("/qos_b", {f"{OVERRIDE}.reliability": "best_effort", f"{OVERRIDE}.depth": 3}),
        ):
            log = tmp_path / f"{namespace[1:]}_driver.log"
            params = {"patch_config": "elbow", "wait_for_subscribers": 0, **extra}
            nodes.append((start_node("eit_driver", namespace, params, log), log))
        log = tmp_path / "classifier.log"
        nodes.append((start_node("eit_classifier", "/qos_a", {"patch_config": "elbow"}, log), log))

        def endpoints():
            return (
                probe.node.get_publishers_info_by_topic("/qos_a/pressure/frames"),
                probe.node.get_subscriptions_info_by_topic("/qos_a/pressure/frames"),
                probe.node.get_publishers_info_by_topic("/qos_b/pressure/frames"),
            )

        assert probe.spin_until(lambda: all(endpoints()), EVENT_S), "\n".join(
            log.read_text() for _, log in nodes
        )
        (driver,), (classifier,), (overridden,) = endpoints()
        assert driver.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert classifier.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert overridden.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        values = {}
        for namespace, topic in (("/qos_a", "/qos_a"), ("/qos_b", "/qos_b")):
            client = AsyncParameterClient(probe.node, f"{namespace}/eit_driver")
            assert client.wait_for_services(EVENT_S)
            prefix = f"qos_overrides.{topic}/pressure/frames.publisher"
            names = [f"{prefix}.{policy}" for policy in ("reliability", "depth", "history")]
            got = client.get_parameters(names)
            described = client.describe_parameters(names)
            assert probe.spin_until(lambda g=got, d=described: g.done() and d.done(), EVENT_S)
            values[namespace] = [v.string_value or v.integer_value for v in got.result().values]
            assert all(d.read_only for d in described.result().descriptors)
    finally:
        for process, log in nodes:
            assert stop_node(process) == 0, log.read_text()
        probe.close()
    assert values["/qos_a"] == ["reliable", RAW_FRAMES_DEPTH, "keep_last"]
    assert values["/qos_b"] == ["best_effort", 3, "keep_last"]
