"""TouchClassifier on synthetic blob sequences whose labels and timing are known exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.patch.model import PatchError
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.classifier import TouchClassifier, classifier_layers, classify_stream
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.contacts import PooledDetector, SegmentationConfig, noise_sample_frames
from eit_skin.touch.events import SHAPE_DTYPE, ShapeHistory
from eit_skin.touch.shapes import (
    blob_moments,
    contact_geometry,
    fingertip_discs,
    layer_image_grid,
    single_contact_spread,
)
from test.support.patch_copies import shipped_patch_data
from test.support.synthetic_touches import (
    INSIDE,
    SIGMA_PA,
    WIDTH_M,
    XX,
    YY,
    X,
    Y,
    blobs,
    envelope,
    sequence,
)

ONSET_S, RELEASE_S = 1.0, 2.2


def run(script, duration_s=3.0, seed=0):
    t, images = sequence(script, duration_s, seed=seed)
    return classify_stream(TouchClassifier(X, Y), t, images)


def one_touch(events):
    ids = {e.touch_id for e in events}
    assert len(ids) == 1, events
    states = [e.state for e in events]
    assert states[0] == "start" and states[-1] == "end"
    assert set(states[1:-1]) <= {"update"}
    return events[0], events[1:-1], events[-1]


def test_push_gives_start_updates_end_with_its_centroid_and_timing() -> None:
    events = run(lambda t: ([(0.01, -0.005)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)))
    start, updates, end = one_touch(events)
    assert ONSET_S < start.t_s <= ONSET_S + 0.15  # START within 150 ms of onset
    assert start.t_start_s >= ONSET_S
    assert end.label == "push"
    assert end.t_end_s == pytest.approx(RELEASE_S, abs=0.05)
    assert end.duration_s == pytest.approx(end.t_end_s - start.t_start_s)
    np.testing.assert_allclose(updates[len(updates) // 2].centroid_m, (0.01, -0.005), atol=5e-4)
    gaps = np.diff([e.t_s for e in updates])
    assert gaps.min() >= 0.1 - 1e-9 and len(updates) >= 8
    assert 0.5 < end.confidence <= 1.0


def test_images_sharing_a_stamp_are_classified_without_error() -> None:
    """Two boards' images may carry one acquisition time (dt = 0 between steps): the noise
    follower has nothing to learn then, and the push is still one push."""
    t, images = sequence(
        lambda t: ([(0.01, -0.005)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)), 3.0
    )
    events = classify_stream(TouchClassifier(X, Y), np.repeat(t, 2), np.repeat(images, 2, axis=0))
    _, _, end = one_touch(events)
    assert end.label == "push"


def test_rub_is_a_contact_that_travels() -> None:
    def script(t):
        x = -0.015 + 0.02 * np.clip((t - ONSET_S - 0.1) / 1.0, 0, 1)  # 20 mm sideways
        return [(x, 0.0)], 5000.0 * envelope(t, ONSET_S, RELEASE_S)

    start, _, end = one_touch(run(script))
    assert start.label == "push"  # provisional: it has not moved yet
    assert end.label == "rub"
    assert end.centroid_m[0] == pytest.approx(0.005, abs=1e-3)


def test_pinch_is_two_contacts_closing() -> None:
    def script(t):
        half = 0.02 - 0.013 * np.clip((t - ONSET_S - 0.1) / 1.0, 0, 1)  # gap 40 -> 14 mm
        return [(0.0, -half), (0.0, half)], 4000.0 * envelope(t, ONSET_S, RELEASE_S)

    _, _, end = one_touch(run(script))
    assert end.label == "pinch"


@pytest.mark.parametrize("n", [2, 4])
def test_grab_is_several_still_contacts(n) -> None:
    angles = 2 * np.pi * np.arange(n) / n
    centres = 0.02 * np.column_stack([np.cos(angles), np.sin(angles)])
    start, _, end = one_touch(run(lambda t: (centres, 4000.0 * envelope(t, ONSET_S, RELEASE_S))))
    assert start.label == "grab" and end.label == "grab"
    np.testing.assert_allclose(start.centroid_m, (0.0, 0.0), atol=1e-3)


def test_two_touches_get_two_ids() -> None:
    def script(t):
        if t < 2.0:
            return [(0.01, 0.0)], 5000.0 * envelope(t, 0.8, 1.6)
        return [(-0.01, 0.0)], 5000.0 * envelope(t, 2.2, 3.0)

    events = run(script, duration_s=3.5)
    ends = [e for e in events if e.state == "end"]
    assert [e.touch_id for e in ends] == [1, 2]
    assert ends[0].centroid_m[0] > 0 > ends[1].centroid_m[0]


def test_no_touch_with_slow_drift_gives_no_event() -> None:
    # a uniform offset drifting by 8 sigma over 30 s: the baseline follows it
    t, images = sequence(lambda t: ([], 0.0), 30.0, seed=4)
    images = images + (8 * SIGMA_PA * t / 30.0)[:, None, None].astype(np.float32)
    assert classify_stream(TouchClassifier(X, Y), t, images) == []


def test_calibration_frames_never_produce_events_and_noise_is_estimated() -> None:
    clf = TouchClassifier(X, Y, ClassifierConfig(calibration_s=0.5))
    t, images = sequence(lambda t: ([(0.0, 0.0)], 5000.0 * (t > 0.3)), 1.0)
    events = [e for k in range(len(t)) for e in clf.step(t[k], images[k])]
    assert all(e.t_s > 0.5 for e in events)
    assert clf.calibrated


def test_noise_from_calibration_matches_the_image_noise() -> None:
    clf = TouchClassifier(X, Y)
    t, images = sequence(lambda t: ([], 0.0), 1.0, seed=2)
    for k in range(len(t)):
        clf.step(t[k], images[k])
    assert clf.pressure_noise_pa == pytest.approx(SIGMA_PA, rel=0.05)
    assert np.isnan(images[0][~INSIDE]).all()


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="pinch_closing"):
        ClassifierConfig(pinch_closing=1.5)
    with pytest.raises(ValueError, match="start_frames"):
        ClassifierConfig(start_frames=0)


def test_every_tuning_constant_is_a_validated_config_field() -> None:
    for field, bad in [
        ("closing_window", 0),
        ("lookback_frames", 0),
        ("noise_window", 0),
        ("track_missed_frames", -1),
        ("noise_floor_fraction", -0.1),
        ("learn_fraction", 0.0),
        ("learn_fraction", 1.5),
        ("blob_fraction", 1.0),
        ("finger_radius_m", 0.0),
        ("confidence_gain", 0.0),
    ]:
        with pytest.raises(ValueError, match=field):
            ClassifierConfig(**{field: bad})

    # they act: a wider closing window smooths a pinch's narrowing away (the steady-narrowing
    # rule, which would still call it a pinch, switched off)
    def pinch(t):
        half = 0.02 - 0.013 * np.clip((t - ONSET_S - 0.1) / 1.0, 0, 1)
        return [(0.0, -half), (0.0, half)], 4000.0 * envelope(t, ONSET_S, RELEASE_S)

    t, images = sequence(pinch, 3.0)
    narrow = classify_stream(TouchClassifier(X, Y, ClassifierConfig(pinch_trend=1e9)), t, images)
    assert narrow[-1].label == "pinch"
    config = ClassifierConfig(closing_window=200, pinch_trend=1e9)
    wide = classify_stream(TouchClassifier(X, Y, config), t, images)
    assert wide[-1].label != "pinch"


def test_shape_history_grows_and_keeps_every_record_by_name() -> None:
    history = ShapeHistory()
    for k in range(150):  # past the initial capacity, twice
        history.append(np.array((k, 2.0 * k, 0.0, 0.0, 1.0, 1.0, np.nan), dtype=SHAPE_DTYPE))
    assert len(history) == 150
    np.testing.assert_array_equal(history.rows["t_s"], np.arange(150))
    np.testing.assert_array_equal(history.rows["peak"], 2.0 * np.arange(150))
    copy = ShapeHistory(history.rows[100:])
    copy.append(history.rows[0])
    assert list(copy.rows["t_s"]) == [*range(100, 150), 0]


def test_layers_are_chosen_by_quantity_whatever_their_names() -> None:
    data = shipped_patch_data("arm")
    stretch, pressure = data["layers"][1], data["layers"][0]
    stretch["name"], pressure["name"] = "sleeve", "front"
    second = {**pressure, "name": "inner"}
    data["layers"] = [stretch, pressure, second]  # stretch first, two pressure layers
    p, s = classifier_layers(patch_from_dict(data, "arm_copy.yaml"))
    assert (p.name, s.name) == ("front", "sleeve")  # the first of each quantity
    data["layers"] = [second]
    p, s = classifier_layers(patch_from_dict(data, "arm_copy.yaml"))
    assert (p.name, s) == ("inner", None)
    data["layers"] = [stretch]
    with pytest.raises(PatchError, match=r"arm_copy.yaml: layers: no layer measures pressure"):
        classifier_layers(patch_from_dict(data, "arm_copy.yaml"))


# --------------------------------------------------------------------------- blob shape


def test_blob_moments_of_an_elliptic_gaussian_are_its_standard_deviations() -> None:
    x = np.linspace(-0.06, 0.06, 241)
    xx, yy = np.meshgrid(x, x)
    sx, sy, angle = 0.008, 0.004, 0.5  # m, m, rad
    u = (xx - 0.01) * np.cos(angle) + (yy + 0.005) * np.sin(angle)
    v = -(xx - 0.01) * np.sin(angle) + (yy + 0.005) * np.cos(angle)
    image = 300.0 * np.exp(-0.5 * ((u / sx) ** 2 + (v / sy) ** 2))
    peak, cx, cy, major, minor, axis = blob_moments(image, xx, yy, fraction=0.0)
    assert peak == pytest.approx(300.0)
    assert (cx, cy) == pytest.approx((0.01, -0.005), abs=1e-6)
    assert (major, minor) == pytest.approx((sx, sy), rel=1e-3)
    assert axis == pytest.approx(angle, abs=1e-3)
    # the weighting above a fraction of the peak does not depend on the amplitude
    np.testing.assert_allclose(
        blob_moments(7.0 * image, xx, yy)[1:], blob_moments(image, xx, yy)[1:], rtol=1e-9
    )
    # a mask leaves far-away pixels out
    far = image.copy()
    far[10, 10] = 200.0
    masked = blob_moments(far, xx, yy, fraction=0.0, mask=far < 250.0)
    assert masked[3] > major
    assert blob_moments(far, xx, yy, fraction=0.0, mask=np.hypot(xx, yy) < 0.05)[3] == (
        pytest.approx(major, rel=1e-3)
    )


def test_two_blobs_apart_give_the_major_spread_of_half_their_distance() -> None:
    # two equal narrow blobs 2d apart: second moment along the axis -> d^2 + w^2
    m = blob_moments(blobs([(-0.012, 0.0), (0.012, 0.0)], 1000.0), XX, YY, fraction=0.0)
    assert m[3] == pytest.approx(np.hypot(0.012, WIDTH_M), rel=0.05)
    assert m[4] == pytest.approx(WIDTH_M, rel=0.1)


# --------------------------------------------------------------------------- simulated skins


@pytest.fixture(scope="module")
def imager_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("imager-cache")


def simulated_ends(patch_name: str, scenario: str, cache, seed: int = 3):
    """END events of a built-in simulator script on a shipped patch, and its truth."""
    patch = load_patch(config_path(patch_name))
    imager = LayerImager.build(patch.layers[0], cache_dir=cache)
    rec = SkinSimulator(patch, scenario, 50.0, seed=seed).run()
    layer = rec.layers[patch.layers[0].name]
    images = imager.physical(imager.images(imager.relative_change(layer.frames, layer.reference)))
    spread = single_contact_spread(imager)
    events = classify_stream(
        TouchClassifier(imager.grid.x, imager.grid.y, contact_spread_m=spread), rec.t, images
    )
    return [e for e in events if e.state == "end"], rec.truth, spread, imager


def test_a_fingertip_disc_holds_the_elements_within_its_radius_and_the_nearest() -> None:
    mesh = build_mesh(load_patch(config_path("elbow")).layers[0])
    c = mesh.centroids
    points = np.array([[0.0, 0.0], [0.02, -0.01]])
    disc = fingertip_discs(points, mesh, 0.006)
    d = np.linalg.norm(c[None, :, :] - points[:, None, :], axis=-1)  # [P, N]
    nearest = d.argmin(axis=1)
    assert disc.shape == (2, mesh.n_triangles)
    np.testing.assert_array_equal(disc[[0, 1], nearest], 1.0)
    far = np.ones_like(disc, dtype=bool)
    far[[0, 1], nearest] = False
    np.testing.assert_array_equal(disc[far], (d <= 0.006)[far].astype(float))
    assert 5 < disc[0].sum() < mesh.n_triangles / 4  # a fingertip, not a point nor the sheet
    # a radius below every centroid distance: the nearest element alone
    np.testing.assert_array_equal(fingertip_discs(points, mesh, 0.0).sum(axis=1), 1.0)


def test_one_fingertip_blurs_least_next_to_the_electrodes(imager_cache) -> None:
    patch = load_patch(config_path("elbow"))  # electrodes on the long edges x = +-45 mm
    imager = LayerImager.build(patch.layers[0], cache_dir=imager_cache)
    spread = single_contact_spread(imager)
    x, y = imager.grid.x, imager.grid.y
    row = np.argmin(np.abs(y - 0.0))
    edge = spread[row, np.argmin(np.abs(x - 0.035))]
    middle = spread[row, np.argmin(np.abs(x - 0.0))]
    assert 0.002 < edge < middle < 0.015


def test_classifier_geometry_comes_from_the_cache_without_the_matrix(tmp_path, monkeypatch) -> None:
    layer = load_patch(config_path("elbow")).layers[0]
    imager = LayerImager.build(layer, cache_dir=None)  # the reference, no cache
    grid = layer_image_grid(layer)  # the same pixels as the reconstruction's, no matrix
    np.testing.assert_array_equal(grid.x, imager.grid.x)
    np.testing.assert_array_equal(grid.y, imager.grid.y)
    np.testing.assert_array_equal(grid.inside, imager.grid.inside)
    expected = single_contact_spread(imager)
    # an empty cache: the matrix is built (and cached for the reconstruction), then the map
    first = contact_geometry(layer, tmp_path / "empty")
    assert first.source == "built"
    np.testing.assert_allclose(first.spread_m, expected, rtol=1e-9)
    # the reconstruction already cached its matrix: no forward model
    LayerImager.build(layer, cache_dir=tmp_path / "matrix")
    assert contact_geometry(layer, tmp_path / "matrix").source == "matrix cache"

    # the spread map cached: no matrix at all (building one would raise)
    def no_matrix(*args, **kwargs):
        raise AssertionError("LayerImager.build called although the spread map is cached")

    monkeypatch.setattr(LayerImager, "build", no_matrix)
    again = contact_geometry(layer, tmp_path / "empty")
    assert again.source == "spread cache"
    np.testing.assert_array_equal(again.spread_m, first.spread_m)
    np.testing.assert_array_equal(again.grid.inside, imager.grid.inside)
    # another disc radius, or a damaged file: recomputed, never used
    with pytest.raises(AssertionError, match="spread map is cached"):
        contact_geometry(layer, tmp_path / "empty", radius_m=0.004)
    (spread_file,) = (tmp_path / "empty").glob("*-spread.npz")
    spread_file.write_bytes(b"not an npz")
    with pytest.raises(AssertionError, match="spread map is cached"):
        contact_geometry(layer, tmp_path / "empty")


@pytest.mark.parametrize(
    ("patch_name", "scenario"), [("elbow", "pinch"), ("elbow", "grab"), ("elbow", "rub")]
)
def test_simulated_touch_on_a_pressure_only_knit_gets_its_label(
    patch_name, scenario, imager_cache
) -> None:
    ends, truth, _, _ = simulated_ends(patch_name, scenario, imager_cache)
    assert [e.label for e in ends] == [scenario]
    assert ends[0].t_start_s == pytest.approx(truth[0].t_start_s, abs=0.15)


def test_simulated_grab_on_the_face_is_one_wide_blob_labelled_grab(imager_cache) -> None:
    clf_ends, truth, _, _ = simulated_ends("face", "grab", imager_cache)
    assert [e.label for e in clf_ends] == ["grab"]
    np.testing.assert_allclose(
        clf_ends[0].centroid_m, np.mean(truth[0].contacts, axis=0), atol=0.02
    )


def test_noise_keeps_being_learnt_from_no_touch_frames() -> None:
    # after calibration a patch of the sheet gets three times noisier (a loose electrode)
    t, images = sequence(lambda t: ([], 0.0), 40.0, seed=6)
    hot = (np.abs(XX - 0.02) < 0.006) & (np.abs(YY) < 0.006)
    rng = np.random.default_rng(1)
    extra = 2.0 * SIGMA_PA * rng.standard_normal(images.shape) * hot
    images = images + np.where(t[:, None, None] > 0.5, extra, 0.0).astype(np.float32)
    clf = TouchClassifier(X, Y)
    for k in range(len(t)):
        clf.step(t[k], images[k])
    learnt = clf.segmenter.noise_sigma[hot]
    # mean of 2 frames: per-pixel sigma sqrt(1 + 2^2) * SIGMA / sqrt(2)
    assert np.median(learnt) == pytest.approx(np.sqrt(5 / 2) * SIGMA_PA, rel=0.15)
    assert np.median(clf.segmenter.noise_sigma[INSIDE & ~hot]) == pytest.approx(
        SIGMA_PA / np.sqrt(2), rel=0.15
    )


# --------------------------------------------------------------------------- early START detector


LATE_ONSET_S = 2.0  # the pooled noise has been learnt from 2 s of frames


def ramp_touch(amplitude_pa: float, ramp_s: float = 0.3, hold_s: float = 1.0):
    """A blob at (5, -5) mm pressed linearly over ``ramp_s`` from LATE_ONSET_S, held, released."""

    def script(t):
        rise = np.clip((t - LATE_ONSET_S) / ramp_s, 0.0, 1.0)
        fall = np.clip((LATE_ONSET_S + 2 * ramp_s + hold_s - t) / ramp_s, 0.0, 1.0)
        return [(0.005, -0.005)], amplitude_pa * min(rise, fall)

    return script


def test_pooling_a_white_noise_image_divides_its_noise_as_the_kernel_says() -> None:
    # all pixels inside: a Gaussian kernel of s pixels keeps sigma / (2 sqrt(pi) s) of white
    # noise and A w^2 / (w^2 + s^2) of a Gaussian blob of width w pixels at its centre
    inside = np.ones((64, 64), dtype=bool)
    s, w = 4.0, 3.0
    detector = PooledDetector(inside, kernel_px=s, k=5.0)
    rng = np.random.default_rng(11)
    frames = SIGMA_PA * rng.standard_normal((400, 64, 64))
    centre = detector.pool(frames)[:, 24:40, 24:40]
    assert np.std(centre) == pytest.approx(SIGMA_PA / (2 * np.sqrt(np.pi) * s), rel=0.05)
    i = np.arange(64) - 32.0
    blob = 300.0 * np.exp(-(i[:, None] ** 2 + i[None, :] ** 2) / (2 * w**2))
    assert detector.pool(blob)[32, 32] == pytest.approx(300.0 * w**2 / (w**2 + s**2), rel=0.02)
    # a sheet-wide offset (drift the baseline has not followed yet) is removed
    assert np.abs(detector.pool(blob + 50.0) - detector.pool(blob)).max() < 1e-9
    # the noise map from 400 frames: that noise, inflated by 1 + sqrt(2 / 400)
    detector.learn_noise(frames)
    expected = SIGMA_PA / (2 * np.sqrt(np.pi) * s) * (1 + np.sqrt(2 / 400))
    assert np.median(detector.noise[24:40, 24:40]) == pytest.approx(expected, rel=0.1)


def running_mean(frames: np.ndarray, n: int) -> np.ndarray:
    """Means of ``n`` consecutive frames ``[T - n + 1, ...]``."""
    return np.mean([frames[i : len(frames) - n + 1 + i] for i in range(n)], axis=0)


def ar1_frames(rho: float, shape: tuple[int, int, int], seed: int) -> np.ndarray:
    """Unit-variance Gaussian frames ``[T, H, W]`` correlated ``rho ** k`` at lag ``k``."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(shape)
    out = np.empty(shape)
    out[0] = e[0]
    for t in range(1, shape[0]):
        out[t] = rho * out[t - 1] + np.sqrt(1 - rho**2) * e[t]
    return out


def test_the_noise_counts_frames_per_independent_sample_from_their_correlation_in_time() -> None:
    white = np.random.default_rng(21).standard_normal((800, 8, 8))
    assert noise_sample_frames(white) == pytest.approx(1.0, abs=0.02)
    # a running mean of n white frames measures 1 + 2 sum ((n - k) / n)^2 = (2 n^2 + 1) / (3 n)
    # (below n): the count keeps one sample per running mean
    for n in (2, 4):
        assert noise_sample_frames(running_mean(white, n), 1) == pytest.approx(
            (2 * n * n + 1) / (3 * n), rel=0.05
        )
        assert noise_sample_frames(running_mean(white, n), n) == n
    # frames correlated rho^k in time (a real device's drift-like noise): 1 + 2 sum rho^2k
    rho = 0.8
    expected = 1 + 2 * sum(rho ** (2 * k) for k in range(1, 11))
    ar = ar1_frames(rho, (2000, 6, 6), seed=22)
    assert noise_sample_frames(ar) == pytest.approx(expected, rel=0.1)
    # a short record: too few lags to measure, the running mean's count
    assert noise_sample_frames(white[:3], 2) == 2.0
    # the pooled detector counts its calibration's independent samples the same way
    inside = np.ones((32, 32), dtype=bool)
    detector = PooledDetector(inside, kernel_px=3.0, k=5.0, frames_per_sample=2)
    detector.learn_noise(running_mean(SIGMA_PA * ar1_frames(rho, (400, 32, 32), seed=23), 2))
    assert detector.sample_frames > 4.0  # not the 2 of the running mean alone
    detector.learn_noise(running_mean(SIGMA_PA * ar1_frames(0.0, (400, 32, 32), seed=24), 2))
    assert detector.sample_frames == 2.0


def test_a_rising_press_counts_the_frame_before_its_crossing_when_the_two_average_k() -> None:
    # pooled z-scores at the blob's centre set exactly (noise-free blobs on a calibrated map)
    inside = np.ones((64, 64), dtype=bool)
    k = 5.0
    detector = PooledDetector(inside, kernel_px=4.0, k=k)
    detector.learn_noise(SIGMA_PA * np.random.default_rng(14).standard_normal((200, 64, 64)))
    i = np.arange(64) - 32.0
    blob = np.exp(-(i[:, None] ** 2 + i[None, :] ** 2) / (2 * 3.0**2))
    per_unit = detector.pool(blob)[32, 32] / detector.noise[32, 32]

    def runs(levels):
        detector.reset()
        return [detector.update(blob * (level * k / per_unit)) for level in levels]

    assert runs([0.0, 0.8, 1.3]) == [0, 0, 2]  # 0.8 k + 1.3 k >= 2 k: the 0.8 k frame counts
    assert runs([0.0, 0.4, 1.3]) == [0, 0, 1]  # 0.4 k is below k / 2: a first crossing
    assert runs([0.0, 0.7, 1.2]) == [0, 0, 1]  # 1.9 k: a first crossing
    assert runs([0.0, 0.0, 2.5]) == [0, 0, 1]  # one frame, however strong, is one frame
    assert runs([0.0, 1.1, 1.3, 1.4]) == [0, 1, 2, 3]  # crossings count as before
    detector.rising = False  # noise not as calibrated (the classifier's call): two crossings
    assert runs([0.0, 0.8, 1.3, 1.3]) == [0, 0, 1, 2]


def test_weak_slow_touch_starts_within_150_ms_only_with_the_pooled_detector() -> None:
    # 60 Pa = 6 pixel sigmas at full force, 0.3 s linear press: one pixel of the 2-frame mean
    # (sigma 10 / sqrt(2) Pa) crosses k_high = 6 sigmas only at 71 % of the ramp (> 210 ms);
    # the pooled image (kernel 2.5 x 5 mm, white noise down ~26x, blob kept ~14 %) at ~20 %
    t, images = sequence(ramp_touch(60.0), 4.0, seed=12)
    spread = 0.005
    early = classify_stream(TouchClassifier(X, Y, contact_spread_m=spread), t, images)
    config = ClassifierConfig(detect_kernel=0)
    late = classify_stream(TouchClassifier(X, Y, config, contact_spread_m=spread), t, images)
    start, _, end = one_touch(early)
    assert LATE_ONSET_S < start.t_s <= LATE_ONSET_S + 0.15
    assert start.n_contacts == 0  # before any pixel crosses k_high
    np.testing.assert_allclose(start.centroid_m, (0.005, -0.005), atol=0.004)
    assert end.label == "push" and end.n_contacts >= 1
    # the 6-sigma contacts alone START it late or, with the bar raised by the noise map's
    # uncertainty (8.5 sigmas at full force against ~7.3), not at all
    assert not late or (late[0].state == "start" and late[0].t_s > LATE_ONSET_S + 0.18)


def test_touch_too_weak_to_segment_ends_after_confirm_s_and_does_not_restart() -> None:
    # 30 Pa held for 1.5 s: the pooled detector sees it; no pixel of the 2-frame mean crosses
    # k_high = 9 sigmas = 64 Pa (it would take 4.8 sigmas of noise on top of the touch)
    t, images = sequence(ramp_touch(30.0, hold_s=1.5), 4.5, seed=13)
    config = ClassifierConfig(confirm_s=0.4, segmentation=SegmentationConfig(k_high=9.0))
    events = classify_stream(TouchClassifier(X, Y, config), t, images)
    start, _, end = one_touch(events)
    assert LATE_ONSET_S < start.t_s <= LATE_ONSET_S + 0.2
    assert end.t_s - start.t_start_s == pytest.approx(0.4, abs=0.021)
    assert end.n_contacts == 0


@pytest.mark.parametrize(("seed", "correlation_px"), [(21, 0.0), (22, 3.0)])
def test_noise_alone_starts_nothing_over_a_minute(seed, correlation_px) -> None:
    # white or spatially correlated noise of the measured sigma, 3000 frames (60 s)
    rng = np.random.default_rng(seed)
    n = 3000
    noise = rng.standard_normal((n, *XX.shape)).astype(np.float32)
    if correlation_px:
        noise = ndimage.gaussian_filter(noise, (0, correlation_px, correlation_px))
        noise /= noise[:, 8:40, 8:40].std()
    images = np.where(INSIDE, SIGMA_PA * noise, np.nan)
    t = np.arange(n) / 50.0
    clf = TouchClassifier(X, Y)
    zmax = 0.0
    for k in range(n):
        assert clf.step(t[k], images[k]) == []
        if clf.detector is not None:
            zmax = max(zmax, float(clf.detector.z.max()))
    assert 3.0 < zmax < clf.config.k_detect  # the detector ran, below its threshold


def test_a_real_devices_noise_wanders_in_time_and_counts_fewer_samples() -> None:
    # data/real/sciospec_adjacent: 20 object-free frames of a real tank, imaged by the node's
    # chain, averaged over 2 frames and pooled as the START detector does: their noise is
    # correlated in time well beyond the running mean's own sharing
    real = Path(__file__).resolve().parents[2] / "data" / "real"
    with np.load(real / "sciospec_adjacent.npz") as data:
        reference, repeated, frames = data["reference"], data["reference_frames"], data["frames"]
    imager = LayerImager.build(
        load_patch(real / "sciospec_adjacent.yaml").layers[0], cache_dir=None
    )
    imager.use_reference(reference, repeated, frames)
    images = imager.images(imager.relative_change(repeated, reference)).astype(np.float64)
    averaged = running_mean(images, 2)
    inside = np.asarray(imager.grid.inside, dtype=bool)
    detector = PooledDetector(inside, kernel_px=4.0, k=5.5, frames_per_sample=2)
    detector.learn_noise(averaged - np.median(averaged, axis=0))
    assert detector.sample_frames > 2.5  # more than the 2 a white device would count
