"""eit_reconstruction with a press calibration, as a real process over DDS.

Simulated presses on the shipped elbow patch are calibrated with ``eit-skin calibrate``; the
node gets the file as its ``calibration`` parameter and frames of new presses at known
positions; its ``calibrated_contacts`` must put them where they were.
"""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import ContactArray, EitFrame

from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.sim.press_session import PressDraw, simulate_press_session
from test.support.calibrated_node import CalibratedFeed, wait_linked
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

NAMESPACE = "/elbow_calibrated_test"
TRAIN_PRESSES = 150
TEST_PRESSES = 10


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """(calibration file, matrix cache, training press positions [N, 2] m) of the elbow."""
    folder = tmp_path_factory.mktemp("calibration")
    presses, model = folder / "presses.npz", folder / "calibration.npz"
    argv = ["presses", "simulate", "--patch", "elbow", "--count", str(TRAIN_PRESSES)]
    assert main([*argv, "--seed", "3", "--out", str(presses)]) == 0
    argv = ["calibrate", "--patch", "elbow", "--presses", str(presses), "--physics-prior", "0"]
    assert main([*argv, "--out", str(model)]) == 0
    cache = folder / "cache"
    LayerImager.build(load_patch(config_path("elbow")).layer("pressure"), cache_dir=cache)
    with np.load(presses) as data:
        return model, cache, data["press_xy"]


def test_calibrated_contacts_put_presses_where_they_were(tmp_path, calibrated) -> None:
    """Presses at known places arrive on calibrated_contacts within a few millimetres.

    Bound: median error 5 mm and under a fifth of the centre guess's (the mean training
    position; ~35 mm on the 90 x 160 mm elbow sheet). The offline localiser gets ~1 mm
    median on this patch (docs/press-calibration.md); a wrong reference, channel order or
    layer cannot meet 5 mm.
    """
    model, cache, train_xy = calibrated
    patch = load_patch(config_path("elbow"))
    layer = patch.layer("pressure")
    topics = patch_topics(patch, NAMESPACE)
    presses = simulate_press_session(patch, TEST_PRESSES, seed=11, draw=PressDraw(drift=False))
    probe = Probe()
    probe.subscribe(ContactArray, topics.calibrated_contacts, 100)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10)
    publisher = probe.node.create_publisher(EitFrame, topics.layers["pressure"].frames, 100)
    log = tmp_path / "recon.log"
    params = {
        "patch_config": "elbow",
        "cache_dir": str(cache),
        "calibration": str(model),
        "reference_frames": TEST_PRESSES,
        "diagnostics_period_s": 0.2,
        "marker_period_s": 0.0,
    }
    node = start_node("eit_reconstruction", NAMESPACE, params, log)
    try:
        wait_linked(probe, node, publisher, topics.calibrated_contacts, log)
        # the no-load reference: the presses' own unloaded frames, again until it is taken
        feed = CalibratedFeed(probe, publisher, layer, topics.calibrated_contacts, log)
        feed.take_reference(presses.references[:TEST_PRESSES], 50 * TEST_PRESSES)
        send = feed.send
        unloaded = [send(presses.references[i]) for i in range(3)]
        located = [send(presses.frames[i]) for i in range(TEST_PRESSES)]
    finally:
        code = stop_node(node)
        probe.close()
    assert code == 0, log.read_text()

    # untouched frames: an array per frame, without contacts (the processor's touch rule)
    assert all(len(m.contacts) == 0 for m in unloaded)
    assert all(len(m.contacts) == 1 for m in located)
    contacts = [m.contacts[0] for m in located]
    assert all(m.header.frame_id == "elbow_link" and m.patch == "elbow" for m in located)
    assert all(c.layer == "pressure" and 0.0 <= c.confidence <= 1.0 for c in contacts)
    xy = np.array([(c.centroid.x, c.centroid.y) for c in contacts])
    error = np.linalg.norm(xy - presses.press_xy, axis=1)
    centre = np.linalg.norm(presses.press_xy - train_xy.mean(axis=0), axis=1)
    assert np.median(error) < 0.005 and np.median(error) < 0.2 * np.median(centre), error
    depth = np.array([c.depth_m for c in contacts])
    assert np.median(np.abs(depth - presses.depth)) < 0.001, depth
    assert np.median([c.confidence for c in contacts]) > 0.05


def test_a_calibration_of_another_patch_is_refused(tmp_path, calibrated) -> None:
    """The arm's pressure layer is not the elbow's: the node exits 2 and says why."""
    model, cache, _ = calibrated
    log = tmp_path / "recon.log"
    params = {"patch_config": "arm", "cache_dir": str(cache), "calibration": str(model)}
    node = start_node("eit_reconstruction", "/arm_refusal_test", params, log)
    try:
        code = node.wait(EVENT_S)
    finally:
        stop_node(node)
    text = log.read_text()
    assert code == 2, text
    assert "refusing to start" in text and str(model) in text
    assert "calibrated on layer 'pressure'" in text and "calibrate again" in text
