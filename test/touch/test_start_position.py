"""A START carries a position, area and peak from the evidence that fired it (issue 37, 6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.assembly import early_estimate
from eit_skin.touch.classifier import TouchClassifier, classify_stream
from eit_skin.touch.contacts import PooledDetector
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.shapes import raw_patterns, single_contact_spread


def test_the_early_estimate_is_the_located_maps_peak_region_and_the_images_half_peak_area():
    x = y = np.linspace(-0.03, 0.03, 61)  # 1 mm pixels
    xx, yy = np.meshgrid(x, y)
    centre, s = (0.0073, -0.0121), 0.004  # between pixel centres
    r2 = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2
    located = np.exp(-r2 / (2 * s**2))
    located[5, 5] = 0.4  # a far pixel below the fraction: not in the region
    signal = 300.0 * np.exp(-r2 / (2 * s**2))
    detector = PooledDetector(np.ones_like(xx, dtype=bool), 2.0, 5.0)
    detector.z = np.full(xx.shape, 5.0)  # on the threshold: confidence 0.5
    est = early_estimate(located, signal, detector, xx, yy, 0.5, 2.0)
    np.testing.assert_allclose(est.centroid_m, centre, atol=2e-4)
    assert est.peak_pa == pytest.approx(300.0, rel=0.01)
    # half-maximum disc of a Gaussian: pi * 2 ln 2 * s^2
    assert est.area_m2 == pytest.approx(math.pi * 2 * math.log(2) * s**2, rel=0.1)
    assert est.confidence == pytest.approx(0.5)
    detector.z[30, 30] = 10.0
    assert early_estimate(located, signal, detector, xx, yy, 0.5, 2.0).confidence > 0.9


@pytest.fixture(scope="module")
def face_push(tmp_path_factory):
    """Events of the simulator's push on the face, classified with its raw frames (as the node)."""
    patch = load_patch(config_path("face"))
    imager = LayerImager.build(patch.layers[0], cache_dir=tmp_path_factory.mktemp("cache"))
    rec = SkinSimulator(patch, "push", 50.0, seed=3).run()
    layer = rec.layers[patch.layers[0].name]
    images = imager.physical(imager.images(imager.relative_change(layer.frames, layer.reference)))
    disc, contact = raw_patterns(patch.layers[0], imager)
    clf = TouchClassifier(
        imager.grid.x,
        imager.grid.y,
        contact_spread_m=single_contact_spread(imager),
        channel_electrodes=channel_electrodes(imager.protocol),
        disc_rel=disc,
        contact_rel=contact,
    )
    return classify_stream(clf, rec.t, images, None, layer.frames), rec.truth


def test_a_simulated_push_starts_where_it_is_and_updates_follow_until_its_end(face_push):
    events, truth = face_push
    assert [e.state for e in events if e.state != "update"] == ["start", "end"]
    start, end = events[0], events[-1]
    track = np.asarray(truth[0].track)
    true_xy = [np.interp(start.t_s, track[:, 0], track[:, k]) for k in (1, 2)]
    assert np.linalg.norm(np.subtract(start.centroid_m, true_xy)) <= 0.008
    assert start.area_m2 > 0 and start.peak_pa > 0 and 0 < start.confidence <= 1
    updates = [e for e in events if e.state == "update"]
    assert updates and all(start.t_s < e.t_s <= end.t_s for e in updates)
    assert all(e.area_m2 > 0 and e.peak_pa > 0 for e in updates)
    assert end.label == "push"
    np.testing.assert_allclose(end.centroid_m, truth[0].contacts[0], atol=0.008)
    assert start.n_contacts == 0  # the raw frames' filter fired it, before any contact
