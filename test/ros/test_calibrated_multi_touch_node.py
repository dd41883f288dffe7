"""eit_reconstruction with ``calibration_max_touches`` 2, as a real process over DDS.

Simulated single presses on the hydrogel patch are calibrated with ``eit-skin calibrate
--max-touches 2``; the node gets frames of true two-probe presses and of single presses; its
``calibrated_contacts`` must carry two contacts the probes' distance apart, and one; a press
held beyond the drift time constant is a changed sheet (no contacts, a WARN diagnostic).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import ContactArray, EitFrame

from eit_skin.calibration.localiser import PressLocaliser
from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.sim.multi_press import simulate_simultaneous_presses
from eit_skin.sim.press_session import PressDraw, simulate_press_session
from test.support.calibrated_node import CalibratedFeed, wait_linked
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

PATCH = Path(__file__).resolve().parents[2] / "data" / "real" / "hydrogel_ohmc16.yaml"
NAMESPACE = "/hydrogel_multi_touch_test"
SEPARATIONS_M = (0.06, 0.08, 0.10)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """(two-touch calibration, one-touch calibration, matrix cache) of the hydrogel patch."""
    folder = tmp_path_factory.mktemp("calibration")
    presses = folder / "presses.npz"
    argv = ["presses", "simulate", "--patch", str(PATCH), "--count", "110", "--seed", "3"]
    assert main([*argv, "--out", str(presses)]) == 0
    two, one = folder / "calibration2.npz", folder / "calibration1.npz"
    argv = ["calibrate", "--patch", str(PATCH), "--presses", str(presses), "--out", str(two)]
    assert main([*argv, "--max-touches", "2", "--physics-prior", "0"]) == 0
    replace(PressLocaliser.load(two), multi_touch=None).save(one)  # as without --max-touches
    cache = folder / "cache"
    LayerImager.build(load_patch(PATCH).layers[0], cache_dir=cache)
    return two, one, cache


def sheet_changed_warning(probe: Probe) -> bool:
    return any(
        status.level[0] == 1 and "sheet changed" in status.message
        for _, msg in probe.messages[DIAGNOSTICS]
        for status in msg.status
        if status.name.endswith("eit_reconstruction: pressure")
    )


def test_two_probe_presses_give_two_calibrated_contacts(tmp_path, calibrated) -> None:
    model, _, cache = calibrated
    patch = load_patch(PATCH)
    layer = patch.layers[0]
    topics = patch_topics(patch, NAMESPACE)
    half = np.array(SEPARATIONS_M)[:, None] / 2.0 * np.array([[0.6, 0.8]])
    frames, baselines = simulate_simultaneous_presses(
        patch, np.stack([half, -half], axis=1), seed=8, drift=False
    )
    single = simulate_press_session(patch, 10, seed=11, draw=PressDraw(drift=False)).frames[:2]
    probe = Probe()
    probe.subscribe(ContactArray, topics.calibrated_contacts, 100)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    publisher = probe.node.create_publisher(EitFrame, topics.layers["pressure"].frames, 100)
    log = tmp_path / "recon.log"
    params = {
        "patch_config": str(PATCH),
        "cache_dir": str(cache),
        "calibration": str(model),
        "calibration_max_touches": 2,
        "reference_frames": 3,
        "drift_time_constant_s": 0.5,
        "diagnostics_period_s": 0.2,
        "marker_period_s": 0.0,
    }
    node = start_node("eit_reconstruction", NAMESPACE, params, log)
    try:
        wait_linked(probe, node, publisher, topics.calibrated_contacts, log)
        feed = CalibratedFeed(probe, publisher, layer, topics.calibrated_contacts, log)
        feed.take_reference(baselines, 150)
        send = feed.send
        pairs = [send(f) for f in frames]
        singles = [send(f) for f in single]
        # held for longer than the drift time constant (0.5 s of frame time): the sheet
        # changed, not a touch: no contacts, a WARN on /diagnostics
        held = [send(frames[0]) for _ in range(40)]
        warned = probe.spin_until(lambda: sheet_changed_warning(probe), EVENT_S)
    finally:
        code = stop_node(node)
        probe.close()
    assert code == 0, log.read_text()
    assert [len(m.contacts) for m in pairs] == [2, 2, 2]
    for msg, separation in zip(pairs, SEPARATIONS_M, strict=True):
        a, b = (np.array([c.centroid.x, c.centroid.y]) for c in msg.contacts)
        assert abs(np.linalg.norm(a - b) - separation) < 0.01
        assert all(0.0 <= c.confidence <= 1.0 and c.layer == "pressure" for c in msg.contacts)
    assert [len(m.contacts) for m in singles] == [1, 1]
    assert [len(m.contacts) for m in held[:15]] == [2] * 15 and not held[-1].contacts
    assert warned, log.read_text()
    assert "sheet changed" in log.read_text()


def test_two_touches_with_a_one_touch_calibration_are_refused(tmp_path, calibrated) -> None:
    _, one_touch, cache = calibrated
    log = tmp_path / "recon.log"
    params = {
        "patch_config": str(PATCH),
        "cache_dir": str(cache),
        "calibration": str(one_touch),
        "calibration_max_touches": 2,
    }
    node = start_node("eit_reconstruction", "/hydrogel_refusal_test", params, log)
    try:
        code = node.wait(EVENT_S)
    finally:
        stop_node(node)
    text = log.read_text()
    assert code == 2, text
    assert "refusing to start" in text and "--max-touches 2" in text
