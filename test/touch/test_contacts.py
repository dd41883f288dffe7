"""Noise estimate, hysteresis segmentation and tracking on synthetic images with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from eit_skin.touch.contacts import (
    Contact,
    ContactSegmenter,
    ContactTracker,
    SegmentationConfig,
    estimate_noise,
    estimate_noise_map,
)
from test.support.synthetic_touches import INSIDE, SIGMA_PA, XX, YY, X, Y, blobs

PIXEL_M = X[1] - X[0]


def noise(shape, seed=0):
    return SIGMA_PA * np.random.default_rng(seed).standard_normal(shape)


def test_noise_estimate_is_robust_to_a_touch_and_to_the_static_offset() -> None:
    frames = noise((30, *XX.shape)) + 50.0 * XX / XX.max()  # static offset pattern
    frames[:, ~INSIDE] = np.nan
    clean = estimate_noise(frames)
    frames[5] += np.nan_to_num(blobs([(0.0, 0.0)], 5000.0))
    assert clean == pytest.approx(SIGMA_PA, rel=0.05)
    assert estimate_noise(frames) == pytest.approx(clean, rel=0.05)


def test_noise_estimate_rejects_empty_and_constant_input() -> None:
    with pytest.raises(ValueError, match="no finite"):
        estimate_noise(np.full((4, 3, 3), np.nan))
    with pytest.raises(ValueError, match="zero noise"):
        estimate_noise(np.ones((4, 3, 3)))


def test_two_separate_blobs_give_two_contacts_at_their_centres() -> None:
    seg = ContactSegmenter(X, Y, SIGMA_PA)
    centres = np.array([(-0.015, 0.01), (0.018, -0.012)])
    contacts = seg.segment(blobs(centres, 4000.0) + noise(XX.shape))
    assert len(contacts) == 2
    found = np.array(sorted(c.centroid_m for c in contacts))
    np.testing.assert_allclose(found, centres[np.argsort(centres[:, 0])], atol=0.3 * PIXEL_M)
    for c in contacts:
        assert c.peak == pytest.approx(4000.0, rel=0.05)
        assert 0 < c.mean < c.peak


def test_pure_noise_gives_no_contact() -> None:
    seg = ContactSegmenter(X, Y, SIGMA_PA)
    images = np.where(INSIDE, noise((50, *XX.shape), seed=1), np.nan)
    assert sum(len(seg.segment(im)) for im in images) == 0


def test_hysteresis_seed_above_high_grows_over_low() -> None:
    cfg = SegmentationConfig(k_high=6.0, k_low=3.0, artifact_fraction=0.0)
    seg = ContactSegmenter(X, Y, 1.0, cfg)
    disc_in = (XX**2 + YY**2) <= 0.004**2
    ring = ((XX**2 + YY**2) <= 0.010**2) & ~disc_in
    image = np.where(disc_in, 10.0, np.where(ring, 4.0, 0.0))  # 10 > high, 4 in (low, high)
    (contact,) = seg.segment(image)
    assert contact.n_pixels == int(disc_in.sum() + ring.sum())
    assert contact.area_m2 == pytest.approx((disc_in.sum() + ring.sum()) * PIXEL_M**2)
    assert contact.peak == 10.0
    assert contact.mean == pytest.approx(
        (10.0 * disc_in.sum() + 4.0 * ring.sum()) / contact.n_pixels
    )
    # the same shoulder without a seed above k_high is no contact
    assert seg.segment(np.where(disc_in | ring, 4.0, 0.0)) == []


def test_weak_sidelobe_is_an_artifact_unless_the_fraction_is_zero() -> None:
    image = blobs([(-0.015, 0.0)], 5000.0) + blobs([(0.02, 0.0)], 400.0)
    assert len(ContactSegmenter(X, Y, SIGMA_PA).segment(image)) == 1
    cfg = SegmentationConfig(artifact_fraction=0.0)
    assert len(ContactSegmenter(X, Y, SIGMA_PA, cfg).segment(image)) == 2


def test_merged_blobs_are_split_at_half_maximum() -> None:
    seg = ContactSegmenter(X, Y, SIGMA_PA)
    image = blobs([(-0.01, 0.0), (0.01, 0.0)], 3000.0)  # 27 % of the peak between them
    low = image > max(seg.low, 0.5 * seg.config.artifact_fraction * np.nanmax(image))
    _regions, n_regions = ndimage.label(low)
    labels, n = seg.labels(image)
    assert n_regions == 1 and n == 2
    np.testing.assert_array_equal(labels > 0, low)  # every region pixel goes to a part
    left, right = labels[:, X < -0.001], labels[:, X > 0.001]
    assert set(np.unique(left[left > 0])) | set(np.unique(right[right > 0])) == {1, 2}
    assert len(np.unique(left[left > 0])) == 1 and len(np.unique(right[right > 0])) == 1


def test_segmenter_rejects_a_wrong_image_shape() -> None:
    with pytest.raises(ValueError, match="does not match"):
        ContactSegmenter(X, Y, 1.0).segment(np.zeros((3, 3)))


def _c(x, y):
    return Contact((x, y), 1e-4, 100.0, 50.0, 4)


def test_tracker_keeps_ids_of_moving_contacts_and_drops_lost_ones() -> None:
    tracker = ContactTracker(gate_m=0.005, max_missed=1)
    a, b = tracker.update(0.0, [_c(0.0, 0.0), _c(0.03, 0.0)])
    ids = {a.id, b.id}
    for k in range(1, 6):  # both move 3 mm per frame, listed in swapped order
        seen = tracker.update(0.02 * k, [_c(0.03 + 0.003 * k, 0.0), _c(0.003 * k, 0.0)])
        assert {tr.id for tr in seen} == ids
    left = min(seen, key=lambda tr: tr.contact.centroid_m[0])
    assert left.id == a.id and left.start_m == (0.0, 0.0) and left.frames == 6
    # a jump beyond the gate is a new contact
    (jumped,) = list(tracker.update(0.2, [_c(0.1, 0.1)]))
    assert jumped.id not in ids
    tracker.update(0.22, [])
    tracker.update(0.24, [])
    assert tracker.tracks == []


def test_noise_map_follows_noise_that_differs_over_the_sheet() -> None:
    scale = np.where(XX < 0, 5.0, 20.0)
    frames = scale * np.random.default_rng(3).standard_normal((40, *XX.shape))
    sigma = estimate_noise_map(frames)
    assert np.median(sigma[:, X < -0.01]) == pytest.approx(5.0, rel=0.15)
    assert np.median(sigma[:, X > 0.01]) == pytest.approx(20.0, rel=0.15)
    # a 10-sigma blob on the quiet side is a contact; the same blob on the noisy side is not
    seg = ContactSegmenter(X, Y, sigma, SegmentationConfig(artifact_fraction=0.0))
    image = blobs([(-0.02, 0.0)], 50.0) + blobs([(0.02, 0.0)], 50.0)
    (contact,) = seg.segment(np.nan_to_num(image))
    assert contact.centroid_m[0] < 0
