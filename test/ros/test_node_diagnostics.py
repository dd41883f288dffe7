"""Diagnostics tell the truth: ERROR when frames stop, OK while a driver waits for listeners,
and a mistyped patch is refused with the list of valid ones (real nodes over real DDS)."""

from __future__ import annotations

from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.node_graph import ROBOT_PATCHES, patch_nodes
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

STARTUP_S = EVENT_S
"""Ceiling of every wait below (each returns as soon as its event happens)."""


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cache")
    for layer in load_patch(config_path("face")).layers:
        LayerImager.build(layer, cache_dir=path)
    return path


def statuses(probe: Probe, node: str) -> list:
    return [s for _, m in probe.messages[DIAGNOSTICS] for s in m.status if node in s.name]


def test_reconstruction_reports_error_while_no_frames_arrive(tmp_path: Path, cache: Path) -> None:
    probe = Probe("diag_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    publisher = probe.node.create_publisher(EitFrame, "/face/pressure/frames", 10)
    log = tmp_path / "recon.log"
    params = {
        "patch_config": "face",
        "cache_dir": str(cache),
        "frame_timeout_s": 1.0,
        "diagnostics_period_s": 0.2,
    }
    recon = start_node("eit_reconstruction", "/face", params, log)
    try:

        def silent() -> list:
            return [s for s in statuses(probe, "eit_reconstruction") if s.level[0] == 2]

        assert probe.spin_until(lambda: bool(silent()) or recon.poll() is not None, STARTUP_S)
        status = silent()[0]
        assert "no frame on /face/pressure/frames" in status.message, status.message
        assert {kv.key: kv.value for kv in status.values}["last_frame_age_s"] == "never"
        # frames arrive: the error clears
        seen = len(statuses(probe, "eit_reconstruction"))
        frame = EitFrame(n_electrodes=16, drive_pattern="adjacent", voltages=[0.01] * 208)

        def recovered() -> bool:
            frame.sequence += 1
            publisher.publish(frame)
            return any(s.level[0] == 0 for s in statuses(probe, "eit_reconstruction")[seen:])

        assert probe.spin_until(recovered, STARTUP_S), log.read_text()
    finally:
        assert stop_node(recon) == 0
        probe.close()


def test_driver_waiting_for_subscribers_is_ok_not_an_error(tmp_path: Path) -> None:
    """Nobody listens to the frames: the simulator holds its script and says so at level OK."""
    probe = Probe("diag_probe")
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    log = tmp_path / "driver.log"
    # TF off: without tf2_msgs (a bare pip install) the driver rightly warns once about it
    params = {"patch_config": "face", "faults": "", "publish_tf": False}
    driver = start_node("eit_driver", "/face", params, log)
    try:
        assert probe.spin_until(
            lambda: len(statuses(probe, "eit_driver")) >= 2 or driver.poll() is not None,
            STARTUP_S,
        )
        for status in statuses(probe, "eit_driver"):
            assert status.level[0] == 0, status.message
            assert "waiting for 1 subscriber(s) on /face/pressure/frames" in status.message
    finally:
        assert stop_node(driver) == 0
        probe.close()
    text = log.read_text()
    assert "[ERROR]" not in text and "[WARN]" not in text, text


def test_unknown_patch_is_refused_with_the_valid_ones() -> None:
    with pytest.raises(ValueError) as error:
        patch_nodes("leg")
    assert "'leg'" in str(error.value)
    assert all(name in str(error.value) for name in ROBOT_PATCHES)
