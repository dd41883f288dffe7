"""eit_driver as a lifecycle node over real DDS, driven from the `ros2` CLI and a manager.

Some transitions with `ros2 lifecycle set <node> <transition>` where ros2lifecycle is
installed, else the same request with `ros2 service call`
(:func:`eit_skin.ros.probe.lifecycle_set`), the others with the ChangeState service from
this process, as a lifecycle manager node sends them (quicker than a CLI start). Publishing
stops on deactivate and resumes on activate; a board's port stays open while inactive and
is closed by cleanup; ``managed:=false`` has no lifecycle services.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState

from eit_skin.hardware.fake_device import FakeDevice
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.probe import Probe, lifecycle_set, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from test.support.patience import EVENT_S

ROS2 = Path(sys.executable).with_name("ros2")
pytestmark = [
    pytest.mark.ros,
    pytest.mark.skipif(not ROS2.is_file(), reason="ros2 CLI not installed (../shared/ros2-tools)"),
]


def driver_states(probe: Probe) -> list[dict[str, str]]:
    """The values of every driver status heard so far, oldest first (with ``message``)."""
    return [
        {"message": s.message, **{kv.key: kv.value for kv in s.values}}
        for _, msg in probe.messages[DIAGNOSTICS]
        for s in msg.status
        if "eit_driver" in s.name
    ]


def wait_for_state(probe: Probe, state: str, count: int = 1, since: int = 0) -> list[dict]:
    """Wait until ``count`` driver statuses after the first ``since`` report ``state``."""

    def found() -> list[dict]:
        return [v for v in driver_states(probe)[since:] if v["lifecycle_state"] == state]

    assert probe.spin_until(lambda: len(found()) >= count, EVENT_S), driver_states(probe)[-3:]
    return found()


def change_state(probe: Probe, node: str, transition: int) -> bool:
    """The ChangeState service, called from the test process (quicker than the CLI)."""
    client = probe.node.create_client(ChangeState, f"{node}/change_state")
    assert client.wait_for_service(EVENT_S)
    future = client.call_async(ChangeState.Request(transition=Transition(id=transition)))
    assert probe.spin_until(future.done, EVENT_S)
    probe.node.destroy_client(client)
    return future.result().success


def test_simulator_transitions_from_the_cli_stop_and_resume_publishing(tmp_path) -> None:
    namespace, log = "/lc_face", tmp_path / "driver.log"
    topic = patch_topics(load_patch(config_path("face")), namespace).layers["pressure"].frames
    probe = Probe("lifecycle_probe")
    probe.subscribe(EitFrame, topic)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    params = {"patch_config": "face", "autostart": False, "diagnostics_period_s": 0.1}
    node = start_node("eit_driver", namespace, params, log)
    name = f"{namespace}/eit_driver"
    frames = probe.messages[topic]
    try:
        # waits unconfigured for its manager: no source, no frames
        (first,) = wait_for_state(probe, "unconfigured")[:1]
        assert first["message"].startswith("unconfigured") and not frames
        assert change_state(probe, name, Transition.TRANSITION_CONFIGURE)
        wait_for_state(probe, "inactive")
        assert not frames  # configured is not publishing

        assert change_state(probe, name, Transition.TRANSITION_ACTIVATE)
        assert probe.spin_until(lambda: len(frames) >= 10, EVENT_S), log.read_text()

        lifecycle_set(name, "deactivate")
        deactivated_ns = time.time_ns()  # the driver had deactivated before it answered
        since = len(driver_states(probe))
        quiet = wait_for_state(probe, "inactive", 5, since)
        assert len({v["frames_published"] for v in quiet}) == 1  # the script paused
        activating_ns = time.time_ns()
        assert change_state(probe, name, Transition.TRANSITION_ACTIVATE)
        assert probe.spin_until(lambda: stamp_ns(frames[-1][1]) > activating_ns, EVENT_S)
        # a loaded probe may still be taking older frames: judge by acquisition stamps
        stamps = np.array([stamp_ns(m) for _, m in frames])
        assert not np.any((stamps > deactivated_ns) & (stamps < activating_ns)), "inactive"
        sequences = [m.sequence for _, m in frames]
        assert sequences == sorted(sequences)

        assert change_state(probe, name, Transition.TRANSITION_DEACTIVATE)
        lifecycle_set(name, "cleanup")
        since = len(driver_states(probe))
        (cleaned,) = wait_for_state(probe, "unconfigured", 1, since)[:1]
        assert "no source open" in cleaned["message"]
        assert change_state(probe, name, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
        wait_for_state(probe, "finalized", 1, since)
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
    assert "Traceback" not in log.read_text()


def test_deactivated_board_keeps_its_port_and_cleanup_closes_it(tmp_path) -> None:
    frames_v = np.random.default_rng(3).normal(0.0, 0.05, size=(64, 208))
    device = FakeDevice(lambda i: frames_v[i % len(frames_v)], rate_hz=100.0)
    device.open()
    port = tmp_path / "eit_skin_arm"
    device.link(port)
    device.start()
    namespace, log = "/lc_arm", tmp_path / "driver.log"
    topic = patch_topics(load_patch(config_path("arm")), namespace).layers["pressure"].frames
    probe = Probe("lifecycle_board_probe")
    probe.subscribe(EitFrame, topic)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    params = {
        "patch_config": "arm",
        "layer": "pressure",
        "port": str(port),
        "diagnostics_period_s": 0.1,
    }
    node = start_node("eit_driver", namespace, params, log)  # autostart: active at once
    name = f"{namespace}/eit_driver"
    frames = probe.messages[topic]
    try:
        assert probe.spin_until(lambda: len(frames) >= 10, EVENT_S), log.read_text()
        assert change_state(probe, name, Transition.TRANSITION_DEACTIVATE)
        deactivated_ns = time.time_ns()
        since = len(driver_states(probe))
        inactive = wait_for_state(probe, "inactive", 5, since)
        # the board is still read (port open, connected, never reconnected); frames held
        held = [int(v["frames_held_inactive"]) for v in inactive]
        assert held[-1] > held[0] > 0
        assert {(v["state"], v["reconnects"]) for v in inactive} == {("connected", "0")}
        activating_ns = time.time_ns()
        lifecycle_set(name, "activate")
        assert probe.spin_until(lambda: stamp_ns(frames[-1][1]) > activating_ns, EVENT_S)
        stamps = np.array([stamp_ns(m) for _, m in frames])
        assert not np.any((stamps > deactivated_ns) & (stamps < activating_ns)), "inactive"
        assert change_state(probe, name, Transition.TRANSITION_DEACTIVATE)
        assert change_state(probe, name, Transition.TRANSITION_CLEANUP)
        since = len(driver_states(probe))
        (closed,) = wait_for_state(probe, "unconfigured", 1, since)[:1]
        assert "no source open" in closed["message"] and "state" not in closed
    finally:
        device.stop()
        device.close()
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_unmanaged_driver_publishes_at_once_without_lifecycle_services(tmp_path) -> None:
    namespace, log = "/lc_plain", tmp_path / "driver.log"
    topic = patch_topics(load_patch(config_path("face")), namespace).layers["pressure"].frames
    probe = Probe("lifecycle_plain_probe")
    probe.subscribe(EitFrame, topic)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    params = {"patch_config": "face", "managed": False, "diagnostics_period_s": 0.1}
    node = start_node("eit_driver", namespace, params, log)
    try:
        assert probe.spin_until(lambda: len(probe.messages[topic]) >= 5, EVENT_S), log.read_text()
        (status,) = wait_for_state(probe, "active")[:1]
        assert status["managed"] == "false"
        services = {n for n, _ in probe.node.get_service_names_and_types()}
        assert f"{namespace}/eit_driver/get_parameters" in services  # the node's own are there
        assert not [s for s in services if s.startswith(f"{namespace}/eit_driver/change_state")]
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()


def test_a_failed_configure_stays_unconfigured_and_says_why(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nframe_id: f\nlayers: []\n")
    namespace, log = "/lc_bad", tmp_path / "driver.log"
    probe = Probe("lifecycle_bad_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    params = {"patch_config": str(bad), "autostart": False, "diagnostics_period_s": 0.1}
    node = start_node("eit_driver", namespace, params, log)
    name = f"{namespace}/eit_driver"
    try:
        assert not change_state(probe, name, Transition.TRANSITION_CONFIGURE)
        since = len(driver_states(probe))
        wait_for_state(probe, "unconfigured", 1, since)
        assert node.poll() is None  # the manager may fix the file and configure again
    finally:
        assert stop_node(node) == 0, log.read_text()
        probe.close()
    text = log.read_text()
    assert "configure failed" in text and str(bad) in text and "layers" in text, text
