"""ReferenceTracker, posture tables and joint-angle lookup (no ROS)."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.pipeline.reference import (
    JointAngleHistory,
    PostureReferences,
    ReferenceTracker,
    bin_posture_frames,
)

M = 12


def test_capture_averages_finite_values_per_channel() -> None:
    """Missing values: a channel averages its finite values; an all-missing frame is skipped."""
    tracker = ReferenceTracker(M, n_frames=3, drift_time_constant_s=0.0)
    frames = np.arange(4 * M, dtype=float).reshape(4, M)
    frames[:, 5] = np.nan  # a dead channel: missing in every frame
    bad = frames[0].copy()
    bad[2] = np.inf
    assert not tracker.capture(np.full(M, np.nan), 0.0)  # nothing usable: does not count
    assert not tracker.capture(bad, 0.1)
    assert not tracker.capture(frames[1], 0.2)
    assert tracker.capture(frames[2], 0.3)
    expected = frames[:3].mean(axis=0)
    expected[2] = frames[1:3, 2].mean()  # the inf left out of channel 2 only
    np.testing.assert_allclose(tracker.reference(), expected)  # channel 5 stays NaN
    noise = frames[:3].std(axis=0, ddof=1)
    noise[2] = frames[1:3, 2].std(ddof=1)
    np.testing.assert_allclose(tracker.noise_v, noise)
    assert tracker.age_s(1.3) == pytest.approx(1.0)
    with pytest.raises(ValueError, match=rf"\[{M}\] volts, got shape \(3,\)"):
        tracker.capture(np.ones(3), 1.0)
    tracker.rezero()
    assert not tracker.ready and np.isnan(tracker.age_s(2.0))


def test_drift_follows_untouched_frames_and_freezes_during_contact() -> None:
    tracker = ReferenceTracker(M, n_frames=1, drift_time_constant_s=10.0)
    tracker.capture(np.ones(M), 0.0)
    tracker.set_element_noise(np.full(5, 0.01))
    assert tracker.touching(np.array([0.0, 0.0, 0.06, 0.0, 0.0]))  # 6 x noise > contact_k = 5
    assert not tracker.touching(np.full(5, 0.04))
    tracker.track(np.full(M, 2.0), 10.0, touching=True)
    np.testing.assert_array_equal(tracker.reference(), np.ones(M))
    frame = np.full(M, 2.0)
    frame[3] = np.nan  # missing: channel 3 keeps its reference
    tracker.track(frame, 10.0, touching=False)  # dt = 10 s = one time constant
    expected = np.full(M, 1.0 + (1.0 - np.exp(-1.0)))
    expected[3] = 1.0
    np.testing.assert_allclose(tracker.reference(), expected)
    assert tracker.drift_updates == 1


def test_a_given_reference_counts_as_captured_without_noise() -> None:
    tracker = ReferenceTracker(M, n_frames=20, drift_time_constant_s=1.0)
    tracker.set_reference(np.full(M, 3.0), 5.0)
    assert tracker.ready and tracker.age_s(6.0) == pytest.approx(1.0)
    np.testing.assert_array_equal(tracker.reference(), 3.0)
    assert tracker.touching(np.zeros(5))  # noise unknown: never learnt into the baseline


def test_posture_table_interpolates_and_scales_with_the_captured_gain() -> None:
    table = PostureReferences("elbow", [0.0, 1.0, 2.0], np.array([[1.0] * M, [2.0] * M, [4.0] * M]))
    np.testing.assert_allclose(table.at(0.5), 1.5)
    np.testing.assert_allclose(table.at(1.75), 3.5)
    np.testing.assert_allclose(table.at(-1.0), 1.0)
    np.testing.assert_allclose(table.at(9.0), 4.0)
    tracker = ReferenceTracker(M, n_frames=1, drift_time_constant_s=0.0, posture=table)
    tracker.capture(np.full(M, 1.1), 0.0)  # at angle 0: this skin reads 10 % above the table
    tracker.angle_rad = 1.5
    np.testing.assert_allclose(tracker.reference(), 1.1 * 3.0)


def test_posture_table_saves_and_loads_per_layer(tmp_path) -> None:
    path = tmp_path / "posture.npz"
    a = PostureReferences("elbow", [0.0, 1.0], np.ones((2, M)))
    b = PostureReferences("elbow", [0.5], np.full((1, M), 3.0))
    a.save(path, "pressure")
    b.save(path, "stretch")
    back = PostureReferences.load(path, "pressure")
    np.testing.assert_array_equal(back.references_v, a.references_v)
    assert PostureReferences.load(path, "stretch").angles_rad.tolist() == [0.5]
    with pytest.raises(ValueError, match="missing key"):
        PostureReferences.load(path, "nothing")


def test_bin_posture_frames_averages_per_bin() -> None:
    angles = np.repeat([0.0, 0.5, 1.0], 6) + np.tile(np.linspace(-0.01, 0.01, 6), 3)
    frames = np.repeat([[1.0] * M, [2.0] * M, [3.0] * M], 6, axis=0)
    table = bin_posture_frames("elbow", angles, frames, bin_width_rad=0.2, min_frames=5)
    np.testing.assert_allclose(table.angles_rad, [0.0, 0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(table.references_v[:, 0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="no angle bin"):
        bin_posture_frames("elbow", angles[:3], frames[:3], 0.2, 5)


def test_joint_angle_history_interpolates_at_a_stamp() -> None:
    history = JointAngleHistory(span_ns=10**9)
    assert np.isnan(history.at(0))
    for k in range(5):
        history.add(k * 100_000_000, 0.1 * k)
    history.add(50_000_000, 9.0)  # out of order: ignored
    assert history.at(250_000_000) == pytest.approx(0.25)
    assert history.at(10**10) == pytest.approx(0.4)
    history.add(2_000_000_000, 1.0)  # older than span_ns: the first samples are dropped
    assert history.at(0) == pytest.approx(1.0)
