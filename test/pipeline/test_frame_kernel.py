"""The processor's planned step, compiled and in numpy: the same images, contact decisions
and drifting references, bit for bit, and the general path wherever no plan applies (the
parity over every method, prior and exclusion case: test_frame_plan_parity.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eit_skin.fem.forward import ForwardModel
from eit_skin.frames import FLAG_SATURATED
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.frame_kernel import compiled_step, compiled_step_status, frame_step
from eit_skin.pipeline.frame_plan import FrameChecks, reference_step
from eit_skin.pipeline.processor import LayerProcessor
from test.support.patch_copies import small_disc_patch

pytest.importorskip("numba")  # a declared dependency; without it the numpy path is all

SOLVER = "{method: one_step, prior: laplace, hyperparameter: 0.05, image_pixels: 16}"
PRESSES = ([0.015, 0.01], [-0.02, 0.0], [0.0, -0.025])  # m, pressed disc centres


def layer_of(folder, protocol: str = "", material: str = ""):
    """The small disc's layer; ``protocol``: extra protocol keys (flow mapping entries),
    ``material``: a replacement material (flow mapping)."""
    text = small_disc_patch(SOLVER)
    if protocol:
        text = text.replace("measure: adjacent}", f"measure: adjacent, {protocol}}}")
    if material:
        start = text.index("material: {")
        text = text[:start] + f"material: {material}" + text[text.index("\n", start) :]
    path = folder / "small.yaml"
    path.write_text(text)
    return load_patch(path).layers[0]


def stream(imager: LayerImager, layer, seed: int = 3) -> np.ndarray:
    """``[220, M]`` V: 20 no-load frames, then a slow gain drift (0.02 % over the stream) with
    presses at three places, each 30 frames on, 30 off; 1e-4 relative noise."""
    model = ForwardModel(
        imager.mesh, imager.protocol, layer.contact_impedance_ohm_m, layer.current_a
    )
    s0 = layer.material.sheet_conductance_s
    v0 = model.voltages(s0)
    pressed = []
    for centre in PRESSES:
        sigma = np.full(imager.mesh.n_triangles, s0)
        sigma[np.linalg.norm(imager.mesh.centroids - centre, axis=1) < 0.008] *= 1.5
        pressed.append(model.voltages(sigma))
    frames = []
    for k in range(220):
        touch = k >= 20 and (k - 20) % 60 < 30
        v = pressed[(k - 20) // 60 % 3] if touch else v0
        frames.append(v * (1.0 + 2e-4 * k / 220))
    rng = np.random.default_rng(seed)
    frames = np.array(frames)
    return frames + rng.normal(0.0, 1e-4 * np.sqrt(np.mean(v0**2)), frames.shape)


def run_both(imager: LayerImager, frames: np.ndarray, flags: dict | None = None):
    """Both processors over ``frames`` at 50 Hz; asserts every output is the same.

    The compiled one gets each frame in one reused buffer, as a driver refilling its array
    would hand them: what it keeps of a frame (the fault window) must be its own copy.
    """
    compiled = LayerProcessor(imager, 20, drift_time_constant_s=1.0, compiled_step=True)
    numpy_path = LayerProcessor(imager, 20, drift_time_constant_s=1.0, compiled_step=False)
    touching = 0
    buffer = np.empty(frames.shape[1])
    for k, frame in enumerate(frames):
        f = (flags or {}).get(k)
        buffer[:] = frame
        a, b = compiled.step(buffer, 0.02 * k, f), numpy_path.step(frame, 0.02 * k, f)
        np.testing.assert_array_equal(compiled.faulty_electrodes, numpy_path.faulty_electrodes)
        assert (a is None) == (b is None), k
        if a is None:
            continue
        assert a.touching == b.touching, k
        np.testing.assert_array_equal(a.values, b.values, err_msg=f"frame {k}")
        np.testing.assert_array_equal(a.image, b.image, err_msg=f"frame {k}")
        np.testing.assert_array_equal(compiled.reference(), numpy_path.reference(), f"frame {k}")
        touching += a.touching
    assert compiled.drift_updates == numpy_path.drift_updates
    assert compiled.frames_in == numpy_path.frames_in == len(frames)
    assert compiled.frames_unusable == numpy_path.frames_unusable
    return compiled, numpy_path, touching


def test_compiled_step_images_touches_and_drift_exactly_as_the_numpy_step(tmp_path):
    layer = layer_of(tmp_path)
    imager = LayerImager.build(layer, cache_dir=None)
    compiled, numpy_path, touching = run_both(imager, stream(imager, layer))
    assert compiled.frames_imaged == 200
    assert compiled.frames_compiled == 200 and numpy_path.frames_compiled == 0
    assert 100 <= touching <= 120  # the 110 pressed frames and a few noisy ones
    assert compiled.drift_updates == 200 - touching  # every untouched frame moved it
    assert "compiled (numba" in compiled_step_status()


def test_magnitude_device_frames_take_the_compiled_step_with_the_models_signs(tmp_path):
    layer = layer_of(tmp_path, protocol="values: magnitude")
    imager = LayerImager.build(layer, cache_dir=None)
    frames = np.abs(stream(imager, layer))
    compiled, _, touching = run_both(imager, frames)
    assert compiled.frames_compiled == 200 and touching >= 100


def test_frames_the_kernel_does_not_cover_take_the_numpy_path_with_the_same_result(tmp_path):
    layer = layer_of(tmp_path)
    imager = LayerImager.build(layer, cache_dir=None)
    frames = stream(imager, layer)
    frames[50, 7] = np.nan  # a missing value
    frames[120, 3] = np.inf
    saturated = np.zeros(frames.shape[1], np.uint8)
    saturated[11] = FLAG_SATURATED
    compiled, _, _ = run_both(imager, frames, {80: saturated})
    assert compiled.frames_imaged == 200
    assert compiled.frames_compiled == 197  # all but the three frames above


def test_an_electrode_that_dies_is_found_at_the_same_frame_on_both_paths(tmp_path):
    """The fault checks see the same frames whichever path imaged them: an electrode whose
    channels lose their signal at frame 100 is named at the same check, and both image
    without it from then on (the numpy path's frames, as the kernel needs every channel)."""
    layer = layer_of(tmp_path)
    imager = LayerImager.build(layer, cache_dir=None)
    frames = stream(imager, layer)
    dead = imager.protocol.touching([5])
    frames[100:, dead] *= 1e-3  # a broken lead: the channels through electrode 5 collapse
    compiled, _, _ = run_both(imager, frames)  # asserts both name it at the same frame
    np.testing.assert_array_equal(compiled.faulty_electrodes, [5])
    # frames before the first check after frame 100 took the kernel; none after it
    assert 80 <= compiled.frames_compiled < 150


def test_a_reference_channel_under_the_floor_is_normalised_by_it_as_in_numpy(tmp_path):
    """The kernel's quotient floors ``|v_ref|`` at 1 % of its RMS exactly like the matrix's
    numpy path (the reference check leaves such channels out, so only drift gets there)."""
    layer = layer_of(tmp_path)
    imager = LayerImager.build(layer, cache_dir=None)
    frames = stream(imager, layer)
    reference = frames[:20].mean(axis=0)
    reference[5] = 1e-4 * np.sqrt(np.mean(reference**2))  # far below the floor
    plan = imager.frame_plan
    assert plan is not None
    noise = np.full(imager.mesh.n_triangles, 1e-3)
    for frame in frames[20::40]:
        checks = FrameChecks(noise, 5.0, 0.25)
        values, image, base, touching = compiled_step(plan, frame, reference, checks)
        numpy_step = reference_step(plan, frame, reference, checks)
        for a, b in zip(numpy_step, (values, image, base, touching), strict=True):
            np.testing.assert_array_equal(a, b)
        expected = imager.relative_change(frame, reference)
        np.testing.assert_array_equal(values, expected)
        np.testing.assert_array_equal(image, imager.physical_image(expected))
        score = np.abs(expected.astype(np.float64)) / noise
        assert touching == bool(score.max() > 5.0)
        moved = reference + 0.25 * (frame - reference)
        np.testing.assert_array_equal(base, reference if touching else moved)


def test_a_stretch_layer_has_no_plan_and_a_disabled_kernel_is_the_numpy_step(tmp_path):
    stretch = layer_of(
        tmp_path,
        material="{quantity: stretch, volume_resistivity: 7.6, thickness: 0.0005, "
        "gauge_factor: 5.0}",
    )
    assert LayerImager.build(stretch, cache_dir=None).frame_plan is None
    pressure = LayerImager.build(layer_of(tmp_path), cache_dir=None)
    assert pressure.frame_plan is not None
    assert frame_step(compiled=False) is reference_step
    assert frame_step() is compiled_step


def test_the_environment_switch_keeps_a_process_on_the_numpy_path():
    code = "from eit_skin.pipeline.frame_kernel import compiled_step_status as s; print(s())"
    env = dict(os.environ, EIT_SKIN_JIT="0")
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "numpy (EIT_SKIN_JIT=0)"


def test_the_compiled_kernel_is_kept_on_disk_only_when_asked(tmp_path):
    """``EIT_SKIN_JIT_CACHE=1`` (this run's processes, test/conftest.py) keeps the kernel in
    ``NUMBA_CACHE_DIR``, where every node of the run loads it; without it a process that
    compiles the kernel writes nothing there (the default: numba issue #4807)."""
    assert os.environ["EIT_SKIN_JIT_CACHE"] == "1"
    assert list(Path(os.environ["NUMBA_CACHE_DIR"]).rglob("frame_kernel._kernel-*.nbi"))
    code = "from eit_skin.pipeline.frame_kernel import compiled_step_status as s; print(s())"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), EIT_SKIN_JIT_CACHE="0")
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.startswith("compiled (numba"), out.stdout
    assert list(tmp_path.iterdir()) == []


def test_values_no_sheet_can_give_are_left_out_alike_on_both_paths(tmp_path):
    """A 1e6 V spike, a value beyond the layer's full scale and a step that stays: both
    paths flag the same values, image the same, and a flagged value never reaches an image."""
    from dataclasses import replace

    layer = layer_of(tmp_path)
    plain = LayerImager.build(layer, cache_dir=None)
    frames = stream(plain, layer)
    full_scale = 1.5 * float(np.abs(frames).max())
    imager = replace(plain, layer=replace(layer, full_scale_v=full_scale))
    frames[60, 17] = 1e6  # one channel reading 1e6 V, untouched frame
    frames[70, 30] = -2.0 * full_scale  # beyond the full scale, and a jump
    frames[130:, 40] += np.sqrt(np.mean(frames[:20] ** 2))  # a step that stays: 1e4 noise
    compiled, numpy_path, _ = run_both(imager, frames)
    for processor in (compiled, numpy_path):
        assert processor.values_out_of_range == 2  # 1e6 V is beyond it too
        assert processor.values_jumped == 3  # the spike, the railed value, the step's start
    assert compiled.frames_imaged == 200
    assert 190 <= compiled.frames_compiled <= 197  # the flagged frames took the numpy path
