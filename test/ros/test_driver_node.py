"""eit_driver as a real process over real DDS: serial pty, unplug/replug, record, bad config."""

from __future__ import annotations

import re
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame
from rclpy.parameter_client import AsyncParameterClient

from eit_skin.hardware.fake_device import FakeDevice
from eit_skin.hardware.sources import REJECT_REASONS
from eit_skin.hardware.wire import DeviceFrame, PatternId
from eit_skin.io.mcap import read_mcap_frames
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import READ_ONLY_NOTE
from eit_skin.ros.probe import BIN, Probe, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.sim.faults import FAULT_KINDS, Fault, parse_faults
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

ARM = load_patch(config_path("arm"))
TOPIC = patch_topics(ARM, "/arm").layers["pressure"].frames


def pattern_frames(n: int = 64, m: int = 208, seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 0.05, size=(n, m))


@pytest.fixture
def probe():
    probe = Probe()
    probe.subscribe(EitFrame, TOPIC)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    yield probe
    probe.close()


STARTUP_S = EVENT_S
"""Safety net of every wait below, which returns as soon as its event happens: a node process
starting on a loaded machine (imports, discovery) can take tens of seconds."""


def _driver_status(probe: Probe) -> list:
    return [s for _, m in probe.messages[DIAGNOSTICS] for s in m.status if "eit_driver" in s.name]


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _first_status(probe: Probe, since: int, condition, timeout: float = STARTUP_S):
    """The first driver status after the first ``since`` ones that meets ``condition``, or None.

    Waits for the event itself: whatever other statuses arrive meanwhile (a WARN for a
    diagnostics period without frames on a loaded machine) are passed over.
    """
    found = []

    def check() -> bool:
        found[:] = [s for s in _driver_status(probe)[since:] if condition(s)][:1]
        return bool(found)

    probe.spin_until(check, timeout)
    return found[0] if found else None


def _arm_driver(link: Path, log: Path, **parameters) -> subprocess.Popen:
    """The arm's pressure-layer driver on the serial port ``link`` (its log to ``log``)."""
    params = {"patch_config": "arm", "layer": "pressure", "port": str(link)}
    return start_node(
        "eit_driver", "/arm", params | {"diagnostics_period_s": 0.2} | parameters, log
    )


def test_pty_frames_arrive_bit_exact_and_survive_unplug(probe: Probe, tmp_path) -> None:
    frames = pattern_frames()
    device = FakeDevice(lambda i: frames[i % len(frames)], rate_hz=100.0)
    device.open()
    link = tmp_path / "eit_skin_arm"
    device.link(link)
    device.start()
    record = tmp_path / "rec.mcap"
    node = _arm_driver(link, tmp_path / "driver.log", record_path=str(record))
    try:
        assert probe.spin_until(lambda: len(probe.messages[TOPIC]) >= 20, STARTUP_S), (
            tmp_path / "driver.log"
        ).read_text()
        for _, msg in probe.messages[TOPIC][:20]:
            sent = device.frame(msg.sequence)
            np.testing.assert_array_equal(
                np.asarray(msg.voltages, np.float32), sent.voltages_v.astype(np.float32)
            )
            assert msg.header.frame_id == "arm_skin_link"
            assert (msg.patch, msg.layer, msg.n_electrodes) == (ARM.name, "pressure", 16)
            assert msg.drive_pattern == "adjacent"
            assert msg.current_a == pytest.approx(1e-3)
        seqs = [m.sequence for _, m in probe.messages[TOPIC]]
        assert seqs == sorted(seqs)
        stamps = [  # integer ns: a stamp held 1 ns after its predecessor is below float64's
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec  # resolution in seconds
            for _, m in probe.messages[TOPIC]
        ]
        assert np.all(np.diff(np.array(stamps, dtype=np.int64)) > 0)

        # Unplug: the node keeps running and reports ERROR; replug: frames resume and the
        # node reports OK for frames received over the new connection.
        device.stop()
        device.unplug()
        unplugged = len(_driver_status(probe))
        error = _first_status(probe, unplugged, lambda s: s.level == DiagnosticStatus_ERROR)
        assert error is not None, [s.message for s in _driver_status(probe)[unplugged:]]
        assert str(link) in error.message and _values(error)["state"] == "disconnected"
        assert node.poll() is None
        published = int(_values(error)["frames_published"])
        count = len(probe.messages[TOPIC])
        replugged = len(_driver_status(probe))
        device.open()
        device.link(link)
        device.start()
        assert probe.spin_until(lambda: len(probe.messages[TOPIC]) >= count + 10, STARTUP_S)
        ok = _first_status(
            probe,
            replugged,
            lambda s: (
                s.level == DiagnosticStatus_OK
                and int(_values(s)["reconnects"]) >= 1
                and int(_values(s)["frames_published"]) > published
            ),
        )
        assert ok is not None, [s.message for s in _driver_status(probe)[replugged:]]
        assert _values(ok)["port"] == str(link) and _values(ok)["state"] == "connected"
    finally:
        device.stop()
        device.close()
        assert stop_node(node) == 0
    recorded = list(read_mcap_frames(record))
    assert len(recorded) >= len(probe.messages[TOPIC]) - 5
    assert {topic for topic, _, _ in recorded} == {TOPIC}
    by_seq = {r.sequence: r for _, _, r in recorded}
    for _, msg in probe.messages[TOPIC][:10]:
        assert (
            by_seq[msg.sequence].voltages.tobytes()
            == np.asarray(msg.voltages, np.float32).tobytes()
        )


DiagnosticStatus_OK = b"\x00"
DiagnosticStatus_ERROR = b"\x02"


def test_absent_port_at_start_keeps_node_alive(probe: Probe, tmp_path) -> None:
    link = tmp_path / "eit_skin_missing"
    node = _arm_driver(link, tmp_path / "driver.log")
    try:
        assert probe.spin_until(lambda: len(_driver_status(probe)) >= 2, STARTUP_S)
        status = _driver_status(probe)[-1]
        assert status.level == DiagnosticStatus_ERROR
        assert str(link) in status.message
        frames = pattern_frames(8)
        device = FakeDevice(lambda i: frames[i % 8], rate_hz=100.0)
        device.open()
        device.link(link)
        device.start()
        try:
            assert probe.spin_until(lambda: len(probe.messages[TOPIC]) >= 5, STARTUP_S)
        finally:
            device.stop()
            device.close()
    finally:
        assert stop_node(node) == 0


class MisbehavingDevice(FakeDevice):
    """Frame ``i`` carries the header fault ``i % 7`` (0 and 1 are the layer's own frames)."""

    def frame(self, index: int, device_time_us: int | None = None) -> DeviceFrame:
        good = super().frame(index, device_time_us)
        return [
            good,
            replace(good, pattern_id=PatternId.SKIP, pattern_param=0),  # adjacent, other name
            replace(good, pattern_id=PatternId.OPPOSITE),
            replace(good, n_electrodes=12),
            replace(good, current_a=0.0),
            replace(good, current_a=-1e-3),
            replace(good, voltages_v=good.voltages_v[:192], flags=good.flags[:192]),
        ][index % 7]


def test_frames_not_of_the_layer_are_counted_per_reason_never_published(
    probe: Probe, tmp_path
) -> None:
    frames = pattern_frames(7)
    device = MisbehavingDevice(lambda i: frames[i % 7], rate_hz=100.0)
    device.open()
    link = tmp_path / "eit_skin_arm"
    device.link(link)
    device.start()
    node = _arm_driver(link, tmp_path / "driver.log")
    expected = {"values": 3, "electrodes": 3, "pattern": 3, "current": 6, "published": 6}

    def counts(status) -> dict[str, int]:
        values = _values(status)
        rejected = {k: int(values[f"rejected_{k}"]) for k in REJECT_REASONS}
        return rejected | {"published": int(values["frames_published"])}

    try:  # the layer's own frames arrive (DDS discovery done), and every reason is counted
        assert probe.spin_until(lambda: len(probe.messages[TOPIC]) >= 6, STARTUP_S), (
            tmp_path / "driver.log"
        ).read_text()
        status = _first_status(
            probe, 0, lambda s: all(counts(s)[k] >= n for k, n in expected.items())
        )
        assert status is not None, (tmp_path / "driver.log").read_text()
        statuses = _driver_status(probe)
    finally:
        device.stop()
        device.close()
        assert stop_node(node) == 0
    rejected = counts(status)
    assert int(_values(status)["frames_rejected"]) == sum(rejected[k] for k in REJECT_REASONS)
    published = probe.messages[TOPIC]
    assert all(m.sequence % 7 in (0, 1) for _, m in published), [m.sequence for _, m in published]
    warned = [s.message for s in statuses if s.message.startswith("frames rejected")]
    assert warned and all(re.match(r"frames rejected: frame \d+: ", m) for m in warned), warned


def test_every_fault_in_the_faults_help_parses(probe: Probe, tmp_path) -> None:
    """The description the running driver gives for ``faults`` names every kind, parseably."""
    node = start_node(
        "eit_driver",
        "/arm",
        {"patch_config": "arm", "layer": "pressure", "port": str(tmp_path / "absent")},
        tmp_path / "driver.log",
    )
    try:
        client = AsyncParameterClient(probe.node, "/arm/eit_driver")
        assert client.wait_for_services(EVENT_S), (tmp_path / "driver.log").read_text()
        future = client.describe_parameters(["faults"])
        assert probe.spin_until(future.done, EVENT_S)
        (descriptor,) = future.result().descriptors
    finally:
        assert stop_node(node) == 0
    examples = re.findall(r"([a-z][a-z-]*):(\d+)", descriptor.description)
    assert {kind for kind, _ in examples} == set(FAULT_KINDS), descriptor.description
    for kind, index in examples:
        assert parse_faults(f"{kind}:{index}") == (Fault(kind, int(index)),)
    assert descriptor.read_only and descriptor.description.endswith(READ_ONLY_NOTE)
    meaning = descriptor.description.removesuffix(READ_ONLY_NOTE)
    listed = meaning.rsplit(" ", 1)[-1]  # the comma-separated example itself
    assert {f.kind for f in parse_faults(listed)} == set(FAULT_KINDS)


def test_bad_patch_config_refuses_to_start(tmp_path) -> None:
    import subprocess

    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nframe_id: f\nlayers: []\n")
    result = subprocess.run(
        [str(BIN / "eit_driver"), "--ros-args", "-p", f"patch_config:={bad}"],
        capture_output=True,
        text=True,
        timeout=EVENT_S,
    )
    assert result.returncode == 2
    assert str(bad) in result.stderr and "layers" in result.stderr
