"""LayerProcessor, the per-frame pipeline of one layer (no ROS), on a small real layer."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from eit_skin.frames import FLAG_INVALID, FLAG_SATURATED
from eit_skin.pipeline.processor import LayerProcessor, fault_check_phase, stamp_to_s
from eit_skin.pipeline.reference import PostureReferences
from test.support.pressed_disc import PRESS_M, pressed_disc

SOLVER = (
    "{method: one_step, prior: laplace, hyperparameter: 0.05, image_pixels: 16, "
    "reference_frames: 4}"
)
PRESS = np.array(PRESS_M)  # m, centre of the pressed disc
NOISE = 1e-4  # relative to the rms frame


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """(imager, no-load frame [M] V, pressed frame [M] V) of a 16-electrode disc."""
    disc = pressed_disc(tmp_path_factory.mktemp("small"), SOLVER, factor=1.5)
    return disc.imager, disc.unloaded_v, disc.pressed_v


def noisy(v: np.ndarray, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return v + rng.normal(0.0, NOISE * np.sqrt(np.mean(v**2)), (n, v.size))


def captured(imager, v0, **kwargs) -> LayerProcessor:
    """A processor whose reference was captured from 20 noisy no-load frames ending at t = 0 s.

    (20 frames, not the layer's 4: the element noise behind the contact decision needs them.)
    """
    processor = LayerProcessor(imager, reference_frames=20, **kwargs)
    for k, frame in enumerate(noisy(v0, 20, 1)):
        assert processor.step(frame, 0.1 * (k - 19)) is None
    assert processor.reference_ready
    return processor


def test_capture_then_images_in_the_layers_unit(small) -> None:
    imager, v0, pressed = small
    processor = LayerProcessor(imager, drift_time_constant_s=0.0)
    assert processor.reference_frames == 4  # the layer's solver.reference_frames
    frames = noisy(v0, 4, 1)
    assert [processor.step(f, 0.1 * k) for k, f in enumerate(frames)] == [None] * 4
    np.testing.assert_allclose(processor.reference(), frames.mean(axis=0), rtol=1e-15)
    assert processor.reference_age_s(1.3) == pytest.approx(1.0)  # from the last capture frame
    out = processor.step(pressed, 0.4)
    grid = imager.grid
    assert out.image.dtype == np.float32 and out.image.shape == grid.shape
    assert out.touching and out.channels_used == imager.n_measurements
    # the pipeline is exactly relative change -> Pa -> pixels
    expected = imager.images(
        imager.physical(imager.relative_change(pressed, processor.reference()))
    )
    np.testing.assert_array_equal(out.image, expected)
    row, col = np.unravel_index(np.nanargmax(out.image), out.image.shape)
    assert np.hypot(grid.x[col] - PRESS[0], grid.y[row] - PRESS[1]) < 0.01
    assert np.nanmax(out.image) > 1000.0  # Pa: x1.5 conductance at 30 kPa per unit change
    assert processor.frames_in == 5 and processor.frames_imaged == 1
    processor.rezero()
    assert not processor.reference_ready and processor.step(pressed, 0.5) is None


def test_drift_follows_untouched_frames_and_freezes_during_a_touch(small) -> None:
    imager, v0, pressed = small
    processor = captured(imager, v0, drift_time_constant_s=1.0)
    start = processor.reference()
    drifted = v0 * (1.0 + 0.5 * NOISE)  # a gain drift well below the contact threshold
    out = processor.step(drifted, 1.0)  # 1 s = one time constant after the capture
    assert not out.touching and processor.drift_updates == 1
    np.testing.assert_allclose(
        processor.reference(), start + (1.0 - np.exp(-1.0)) * (drifted - start), rtol=1e-12
    )
    frozen = processor.reference()
    for k in range(5):  # a long press is never learnt into the baseline
        assert processor.step(pressed, 1.1 + 0.1 * k).touching
    np.testing.assert_array_equal(processor.reference(), frozen)
    assert processor.drift_updates == 1
    assert not processor.step(drifted, 3.0).touching  # released: following again
    moved = np.abs(processor.reference() - drifted)
    assert (moved < np.abs(frozen - drifted)).all() and processor.drift_updates == 2


def test_flagged_channels_are_missing_values_everywhere(small) -> None:
    """A flag and a NaN are the same thing: same image, same reference, same drift."""
    imager, v0, _ = small
    with_flags = captured(imager, v0, drift_time_constant_s=1.0)
    with_nan = captured(imager, v0, drift_time_constant_s=1.0)
    plain = captured(imager, v0, drift_time_constant_s=1.0, jump_k=0.0)  # no jump check
    m = imager.n_measurements
    for k, frame in enumerate(noisy(v0, 3, 2)):
        garbage = frame.copy()
        garbage[[7, 100]] = [5.0, -3.0]  # volts the ADC did not really measure
        flags = np.zeros(m, np.uint8)
        flags[7], flags[100], flags[50] = FLAG_SATURATED, FLAG_INVALID, 16  # not excluding
        holes = frame.copy()
        holes[[7, 100]] = np.nan
        t = 0.1 + 0.1 * k
        a = with_flags.step(garbage, t, flags)
        b = with_nan.step(holes, t)
        assert a.channels_used == b.channels_used == m - 2
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(with_flags.reference(), with_nan.reference())
        c = plain.step(garbage, t)  # the same values unflagged: a wild image, no drift
        assert c.touching and np.nanmax(np.abs(c.image)) > 100 * np.nanmax(np.abs(a.image))
    assert with_flags.drift_updates == 3  # the flagged frames were still followed...
    assert with_flags.reference()[7] == plain.reference()[7]  # ...except where flagged


def test_faults_are_checked_on_frame_time(small) -> None:
    """A dead electrode is left out at the first check due by FRAME time, not before."""
    imager, v0, _ = small
    dt = 0.0625  # 16 Hz, exact in binary
    processor = LayerProcessor(imager, drift_time_constant_s=0.0, fault_check_period_s=1.0)
    dead = imager.protocol.touching([5])
    frames = noisy(v0, 40, 3)
    rng = np.random.default_rng(4)
    frames[4:, dead] = rng.normal(0.0, 0.5, (36, int(dead.sum())))  # floating after the capture
    for k, frame in enumerate(frames):
        out = processor.step(frame, k * dt)
        if k < 4:
            assert out is None
            continue
        # reference ready at frame 3 (0.1875 s): first check due on the grid (phase 0) at
        # 1.0 s = frame 16
        if k < 16:  # not named yet; the one-frame jump check leaves the floating values out
            assert processor.faulty_electrodes.size == 0
            assert dead.size - dead.sum() <= out.channels_used < dead.size
        else:
            assert processor.faulty_electrodes.tolist() == [5]
            assert out.channels_used == dead.size - dead.sum()
    # no check without a period
    never = LayerProcessor(imager, drift_time_constant_s=0.0, fault_check_period_s=0.0)
    never.process(frames, np.arange(40) * dt)
    assert never.faulty_electrodes.size == 0


@pytest.mark.parametrize("phase", [0.0, 0.3, 0.75])
def test_faults_are_checked_on_the_layers_grid_of_frame_times(small, phase, monkeypatch) -> None:
    """After the first, every check falls on the first frame at or after (k + phase) period."""
    imager, v0, _ = small
    dt = 0.0625
    processor = LayerProcessor(
        imager, drift_time_constant_s=0.0, fault_check_period_s=1.0, fault_check_phase=phase
    )
    now = [0.0]
    checked: list[float] = []
    check = processor._check_faults
    monkeypatch.setattr(processor, "_check_faults", lambda *a: checked.append(now[0]) or check(*a))
    for k, frame in enumerate(noisy(v0, 100, 8)):
        now[0] = k * dt
        processor.step(frame, now[0])
    # reference at frame 3 (4 frames: too few to check); the first check is due at the first
    # grid time after it, and waits for 10 imaged frames (frame 13) if that comes sooner
    first_due = phase if phase > 3 * dt else phase + 1.0
    assert checked[0] == max(np.ceil(first_due / dt), 13) * dt
    later = np.array(checked[1:])
    grid = np.arange(10) + phase  # s, period 1 s
    due = np.array([grid[grid <= t].max() for t in later])
    assert len(later) >= 4 and np.all(later - due < dt), (phase, checked)
    assert np.allclose(np.diff(due), 1.0)  # one check per period


def test_the_fault_check_phase_spreads_alike_names_over_the_period() -> None:
    """Patches named arm_0 .. arm_49 check at phases with no gap over 0.25 of the period (a
    CRC of such names clusters), and a process with another hash seed gets the same phase."""
    phases = np.sort([fault_check_phase(f"arm_{i}", "pressure") for i in range(50)])
    assert phases[0] >= 0.0 and phases[-1] < 1.0
    assert np.diff(np.concatenate([phases, [phases[0] + 1.0]])).max() < 0.25, phases
    code = "from eit_skin.pipeline.processor import fault_check_phase as f; print(f('a', 'b'))"
    other = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, "PYTHONHASHSEED": "12345"},
        capture_output=True,
        text=True,
        check=True,
    )
    assert float(other.stdout) == fault_check_phase("a", "b")


def test_a_fault_check_phase_outside_the_period_is_refused(small) -> None:
    with pytest.raises(ValueError, match="fault_check_phase must be in"):
        LayerProcessor(small[0], fault_check_phase=1.0)


def test_an_electrode_dead_from_the_start_is_left_out_of_the_first_image(small) -> None:
    """Checked on the captured frames; the noise that tells touch from drift excludes it."""
    imager, v0, pressed = small
    dead = imager.protocol.touching([5])
    rng = np.random.default_rng(6)
    frames = np.vstack([noisy(v0, 20, 5), pressed[None]])
    frames[:, dead] = rng.normal(0.0, 0.5, (21, int(dead.sum())))  # floating from the start
    processor = LayerProcessor(imager, reference_frames=20, drift_time_constant_s=1.0)
    for k in range(20):
        assert processor.step(frames[k], 0.1 * (k - 19)) is None
    assert processor.faulty_electrodes.tolist() == [5]
    out = processor.step(frames[20], 0.1)
    assert out.channels_used == dead.size - dead.sum()
    assert out.touching and processor.drift_updates == 0  # the press is not learnt


def test_posture_angle_comes_with_the_frame(small) -> None:
    imager, v0, _ = small
    table = PostureReferences("elbow", [0.0, 1.0], np.stack([v0, 1.01 * v0]))
    images = []
    for angle in (0.5, None):  # None: the angle stays at the capture's 0 rad
        processor = LayerProcessor(
            imager, reference_frames=1, drift_time_constant_s=0.0, posture=table
        )
        assert processor.step(1.001 * v0, 0.0, angle_rad=0.0) is None  # this skin: gain 1.001
        images.append(processor.step(1.001 * 1.005 * v0, 0.1, angle_rad=angle).image)
    bent, unbent = (np.nanmax(np.abs(a)) for a in images)
    assert bent < 1e-6 * unbent  # the reference at 0.5 rad is the bent no-load frame
    processor.step(v0, 0.2, angle_rad=float("nan"))  # no angle known: keep the last
    assert processor.angle_rad == 0.0


def test_unusable_frames_and_bad_input(small) -> None:
    imager, v0, _ = small
    processor = captured(imager, v0)
    m = imager.n_measurements
    assert processor.step(np.full(m, np.nan), 0.4) is None
    assert processor.step(v0, 0.5, np.full(m, FLAG_INVALID, np.uint8)) is None
    assert processor.frames_unusable == 2 and processor.frames_imaged == 0
    with pytest.raises(ValueError, match=rf"\[{m}\] volts, got shape \(3,\)"):
        processor.step(np.ones(3), 0.6)
    with pytest.raises(ValueError, match="flags must be"):
        processor.step(v0, 0.6, np.zeros(5, np.uint8))
    with pytest.raises(ValueError, match="frame time must be finite"):
        processor.step(v0, float("nan"))


def test_stamp_to_s_is_the_export_convention() -> None:
    stamps = np.array([1_700_000_000_123_456_789, 1_700_000_000_143_456_789], np.int64)
    assert [stamp_to_s(int(s)) for s in stamps] == (stamps / 1e9).tolist()


def test_images_stay_in_the_materials_range_while_a_dead_electrode_is_not_yet_found(small) -> None:
    """Issue 17: electrode 5 comes loose during a press (its channels float). Until the fault
    check leaves them out, the relative change runs far past what the sheet can do; the image
    stops at the material's bound. A normal press is the plain material conversion, untouched
    by the bound."""
    imager, v0, pressed = small
    material = imager.layer.material
    low, high = material.physical_range
    assert (low, high) == pytest.approx((-0.9 * 3.0e4, 9.0 * 3.0e4))  # [1/10, 10] x sigma0
    # no jump check: it would leave most floating values out before the fault check does
    processor = captured(
        imager, v0, drift_time_constant_s=0.0, fault_check_period_s=1.0, jump_k=0.0
    )
    normal = processor.step(pressed, 0.05)
    unclipped = imager.images(material.to_physical(normal.values).astype(np.float32))
    np.testing.assert_array_equal(normal.image, unclipped)
    touching = imager.protocol.touching([5])
    rng = np.random.default_rng(7)
    out = []
    for k in range(30):
        dead = pressed.copy()
        dead[touching] = rng.normal(0.0, 0.5, int(touching.sum()))  # floating inputs, V
        out.append(processor.step(dead, 0.1 + 0.05 * k))
    before = [o for o in out if o.channels_used == imager.n_measurements]
    after = [o for o in out if o.channels_used < imager.n_measurements]
    assert before and after and processor.faulty_electrodes.tolist() == [5]
    assert max(np.nanmax(o.values) for o in before) > 9.0  # the linear estimate ran away
    for o in out:
        assert low <= np.nanmin(o.image) and np.nanmax(o.image) <= high
    # once left out, the press is imaged from the other channels like a press again
    assert 0.3 * np.nanmax(normal.image) < np.nanmax(after[-1].image) < high
