"""A START carries a position, area and peak from the evidence that fired it (issue 37, 6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.sim.scripts import builtin_scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.assembly import disc_centroid, early_estimate
from eit_skin.touch.classifier import TouchClassifier, classify_stream
from eit_skin.touch.contacts import PooledDetector
from eit_skin.touch.frame_evidence import TouchFilter, channel_electrodes
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
def face(tmp_path_factory):
    """The face patch, its imager and the classifier's fingertip patterns (built once)."""
    patch = load_patch(config_path("face"))
    imager = LayerImager.build(patch.layers[0], cache_dir=tmp_path_factory.mktemp("cache"))
    disc, contact = raw_patterns(patch.layers[0], imager)
    return patch, imager, disc, contact, single_contact_spread(imager)


def simulated_events(face, script: str, seed: int):
    """Events of a built-in ``script`` on the face, classified with its raw frames (as the node)."""
    patch, imager, disc, contact, spread = face
    rec = SkinSimulator(patch, script, 50.0, seed=seed).run()
    layer = rec.layers[patch.layers[0].name]
    images = imager.physical(imager.images(imager.relative_change(layer.frames, layer.reference)))
    clf = TouchClassifier(
        imager.grid.x,
        imager.grid.y,
        contact_spread_m=spread,
        channel_electrodes=channel_electrodes(imager.protocol),
        disc_rel=disc,
        contact_rel=contact,
    )
    return classify_stream(clf, rec.t, images, None, layer.frames), rec.truth


@pytest.fixture(scope="module")
def face_push(face):
    return simulated_events(face, "push", 3)


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


def disc_scene(face):
    """``(inside [H, W], xx, yy [H, W] m, reference [M] V, sigma [M] V)`` for synthetic changes."""
    _, imager, disc, _, _ = face
    inside = np.isfinite(disc).all(axis=2)
    xx, yy = np.meshgrid(imager.grid.x, imager.grid.y)
    rng = np.random.default_rng(5)
    reference = 0.01 + 0.05 * rng.random(disc.shape[2])  # V
    return inside, xx, yy, reference, 1e-5 * reference


def nearest_pixel(inside, xx, yy, point) -> tuple[int, int]:
    """(row, column) of the pixel inside the sheet nearest ``point`` ``(x, y)`` m."""
    d = np.where(inside, np.hypot(xx - point[0], yy - point[1]), np.inf)
    return np.unravel_index(int(np.argmin(d)), xx.shape)


def test_fit_discs_finds_each_finger_of_a_pinch_and_weighs_them_by_strength(face):
    _, _, disc, contact, _ = face
    inside, xx, yy, reference, sigma = disc_scene(face)
    noise = np.ones(inside.shape)  # the map's noise (a noiseless change: the penalty's unit)
    fingers = [(0.03, 0.04), (-0.03, -0.04)]  # m, 100 mm apart: a wide grab's two fingers
    pixels = [nearest_pixel(inside, xx, yy, p) for p in fingers]

    def fit(amplitudes, fraction=0.3):
        rel = sum(a * disc[p] for a, p in zip(amplitudes, pixels, strict=True))
        change = reference * rel / sigma  # whitened: (v - reference) / sigma
        return TouchFilter(disc, inside, contact).fit_discs(
            change, sigma, reference, noise, fraction
        )

    found, amplitude = fit([0.02, 0.01])  # a pinch, one finger pressing half as hard
    np.testing.assert_allclose(found, pixels, atol=1e-3)  # each finger on its own pixel
    # each finger's strength, to the between-pixel fit's own spread: a disc at a pixel centre
    # is matched nearly as well by a mix of its neighbours (patterns vary smoothly), whose
    # summed amplitude differs by a few per cent (4.5 % here after a 1e-13 change of the
    # forward model's round-off; exactly 0 before it)
    np.testing.assert_allclose(amplitude, [0.02, 0.01], rtol=0.08)
    np.testing.assert_allclose(
        disc_centroid((found, amplitude), xx, yy),
        (2 * np.array([xx[pixels[0]], yy[pixels[0]]]) + [xx[pixels[1]], yy[pixels[1]]]) / 3,
        atol=1e-3,  # m: a third of the way, to the amplitudes' spread over 100 mm
    )
    # between pixel centres: its place and strength from the pixels around it
    half = 0.5 * (disc[pixels[0]] + disc[pixels[0][0], pixels[0][1] + 1])
    change = reference * (0.02 * half + 0.01 * disc[pixels[1]]) / sigma
    found, amplitude = TouchFilter(disc, inside, contact).fit_discs(
        change, sigma, reference, noise, 0.3
    )
    np.testing.assert_allclose(found, [(pixels[0][0], pixels[0][1] + 0.5), pixels[1]], atol=0.05)
    np.testing.assert_allclose(amplitude, [0.02, 0.01], rtol=0.15)
    # a push is one disc; a finger below blob_fraction of the other does not join
    assert len(fit([0.02, 0.0])[0]) == 1
    assert len(fit([0.02, 0.004])[0]) == 1
    assert len(fit([0.02, 0.004], fraction=0.1)[0]) == 2
    # no change at all: no disc (the START keeps the filter map's peak region)
    assert len(fit([0.0, 0.0])[0]) == 0


def test_a_simulated_pinch_starts_at_the_centre_of_its_fingers_not_on_one(face):
    """Issue 37 item 6: a pinch STARTs near the centre of its two fingers at the START time.

    The built-in pinch presses its fingers 0.9 of the face's half extent apart (45 mm); the
    START's error is measured against the fingers' force-weighted centroid at its frame.
    """
    patch = face[0]
    pinch = builtin_scenario("pinch", patch).touches[0]
    errors, beside = [], []
    for seed in range(4):  # the noise's seed: four presses of the same pinch
        events, _ = simulated_events(face, "pinch", seed)
        start = next(e for e in events if e.state == "start")
        fingers = pinch.contacts(start.t_s)
        assert pinch.envelope(start.t_s) > 0  # START after contact: both fingers press
        at = np.asarray(start.centroid_m)
        errors.append(float(np.linalg.norm(at - pinch.centroid(start.t_s))))
        beside.append(float(np.min(np.linalg.norm(fingers - at, axis=1))))
        assert start.area_m2 > 0 and start.peak_pa > 0 and 0 < start.confidence <= 1
        assert events[-1].label == "pinch"
    half_gap = 0.5 * float(np.linalg.norm(np.subtract(*pinch.contacts(pinch.t_start_s))))
    assert half_gap > 0.02
    assert np.median(errors) <= 0.008
    assert sum(e <= 0.008 for e in errors) >= 3
    # one finger's best match would lie half a gap (22 mm) from the centre
    assert all(e < b for e, b in zip(errors, beside, strict=True))


def test_equal_forces_by_an_electrode_and_in_the_middle_weigh_alike(face):
    """A disc's amplitude is its force, not its match: the centre lands between two equal fingers.

    Beside an electrode a finger's pattern is several times stronger than in the face's
    middle; weighed by the filter's match (what the map reads) their centre would lie by the
    electrode, weighed by the fitted amplitudes (coefficient over pattern norm) halfway.
    """
    patch, _, disc, contact, _ = face
    inside, xx, yy, reference, sigma = disc_scene(face)
    middle = np.array([np.median(xx[inside]), np.median(yy[inside])])
    electrode = patch.layers[0].electrodes[0].center
    near = electrode + 0.012 * (middle - electrode) / np.linalg.norm(middle - electrode)
    pixels = [nearest_pixel(inside, xx, yy, p) for p in (near, middle)]
    at = np.array([[xx[p], yy[p]] for p in pixels])
    assert np.linalg.norm(at[0] - at[1]) > 0.05  # m: two fingers, far apart
    change = reference * 0.01 * (disc[pixels[0]] + disc[pixels[1]]) / sigma
    filt = TouchFilter(disc, inside, contact)
    match = filt.statistic(change, sigma, reference)
    assert match[pixels[0]] > 3 * match[pixels[1]]  # the map sees the electrode's finger
    found, amplitude = filt.fit_discs(change, sigma, reference, np.ones(inside.shape), 0.3)
    assert len(amplitude) == 2
    np.testing.assert_allclose(amplitude, [0.01, 0.01], rtol=0.02)
    centre = disc_centroid((found, amplitude), xx, yy)
    np.testing.assert_allclose(centre, at.mean(axis=0), atol=5e-4)  # m
    by_match = (match[pixels[0]] * at[0] + match[pixels[1]] * at[1]) / (
        match[pixels[0]] + match[pixels[1]]
    )
    assert np.linalg.norm(by_match - at[0]) < 0.25 * np.linalg.norm(at[1] - at[0])


def test_a_further_disc_joins_when_the_polished_fit_explains_more_than_noise_would(face):
    """The number of discs: the whole polished fit against ``2 ln P`` noise units squared.

    A pinch's two equal fingers 40 mm apart in the face's middle: the first disc lies
    between them and leaves little for a second one to match where it stands (below
    ``sqrt(2 ln P)`` here: the rule before 2026-11-27 kept one disc), but two discs moved
    onto the fingers explain well above the penalty, so both are found. Half as strong a
    change stays one disc between them.
    """
    _, _, disc, contact, _ = face
    inside, xx, yy, reference, sigma = disc_scene(face)
    unit = 0.02 * np.array([math.cos(0.3), math.sin(0.3)])  # m: the fingers at +-unit
    pixels = [nearest_pixel(inside, xx, yy, p) for p in (unit, -unit)]
    at = np.array([[xx[p], yy[p]] for p in pixels])
    filt = TouchFilter(disc, inside, contact)

    def fit(amplitude):
        change = reference * amplitude * (disc[pixels[0]] + disc[pixels[1]]) / sigma
        found = filt.fit_discs(change, sigma, reference, np.ones(inside.shape), 0.3)
        return found, filt.statistic(change, sigma, reference)

    (found, amplitude), match = fit(8e-4)
    k = math.sqrt(2 * math.log(np.count_nonzero(inside)))
    assert np.nanmax(match) < 4 * k  # a weak pinch: a few noise units per finger
    assert len(amplitude) == 2
    order = np.argsort(found[:, 1])  # by column: match the fingers' order
    expected = np.argsort([p[1] for p in pixels])
    # each on its finger (12 pixels apart), within the 2 pixels a coordinate-wise polish leaves
    np.testing.assert_allclose(found[order], np.array(pixels, float)[expected], atol=2.0)
    np.testing.assert_allclose(disc_centroid((found, amplitude), xx, yy), at.mean(0), atol=1e-3)
    (found, amplitude), _ = fit(4e-4)  # two discs would explain less than the penalty
    assert len(amplitude) == 1
    assert np.linalg.norm(disc_centroid((found, amplitude), xx, yy) - at.mean(0)) < 0.01
