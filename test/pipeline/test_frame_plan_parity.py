"""The two implementations of "frame -> image" (the numpy reference step and the compiled
kernel, both taking a FramePlan) give the same values, images, contact decisions and
references bit for bit, over every method, prior, channel exclusion and flag case; frames
no plan covers take the same general path in both processors."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eit_skin.fem.forward import ForwardModel
from eit_skin.frames import FLAG_INVALID, FLAG_SATURATED
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import PRIOR_KINDS
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.frame_kernel import compiled_step
from eit_skin.pipeline.frame_plan import FrameChecks, reference_step
from eit_skin.pipeline.processor import LayerProcessor
from test.support.patch_copies import small_disc_patch

pytest.importorskip("numba")  # a declared dependency; without it both are the numpy step

SOLVERS = {
    **{f"one_step-{p}": f"{{method: one_step, prior: {p}, image_pixels: 16}}" for p in PRIOR_KINDS},
    "greit": "{method: greit, image_pixels: 16}",
    "gauss_newton": "{method: gauss_newton, prior: laplace, image_pixels: 16, max_iterations: 2}",
}
CASES = ("clean", "nan", "saturated", "invalid", "out_of_range", "jump", "faulty", "reference")
N_FRAMES = 90


@pytest.fixture(scope="module", params=sorted(SOLVERS))
def setup(request, tmp_path_factory):
    """(name, two imagers, frames ``[90, M]`` V): 20 untouched frames, then presses at two
    places with a slow gain drift and 1e-4 relative noise. Two builds per method, one per
    processor: a Gauss-Newton reconstructor keeps its last solution (warm start)."""
    path = tmp_path_factory.mktemp("parity") / "small.yaml"
    path.write_text(small_disc_patch(SOLVERS[request.param]))
    layer = load_patch(path).layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    model = ForwardModel(imager.mesh, imager.protocol, layer.contact_impedance_ohm_m, 1e-4)
    s0 = layer.material.sheet_conductance_s
    v0 = model.voltages(s0)
    pressed = []
    for centre in ([0.015, 0.01], [-0.02, 0.0]):
        sigma = np.full(imager.mesh.n_triangles, s0)
        sigma[np.linalg.norm(imager.mesh.centroids - centre, axis=1) < 0.008] *= 1.5
        pressed.append(model.voltages(sigma))
    frames = np.array(
        [
            (pressed[(k // 20) % 2] if k >= 20 and k % 20 < 10 else v0) * (1 + 2e-4 * k / 90)
            for k in range(N_FRAMES)
        ]
    )
    rng = np.random.default_rng(4)
    frames += rng.normal(0.0, 1e-4 * np.sqrt(np.mean(v0**2)), frames.shape)
    return request.param, (imager, LayerImager.build(layer, cache_dir=None)), frames


def case_input(case: str, imager: LayerImager, frames: np.ndarray):
    """(imager, frames, flags per frame) of one exclusion or flag case."""
    frames = frames.copy()
    flags: dict[int, np.ndarray] = {}
    m = frames.shape[1]
    if case == "nan":
        frames[30, 7] = np.nan
        frames[45, 3] = np.inf
    elif case in ("saturated", "invalid"):
        for k in range(40, 50):
            flags[k] = np.zeros(m, np.uint8)
            flags[k][11] = FLAG_SATURATED if case == "saturated" else FLAG_INVALID
    elif case == "out_of_range":
        full_scale = 1.5 * float(np.abs(frames).max())
        imager = replace(imager, layer=replace(imager.layer, full_scale_v=full_scale))
        frames[35, 30] = -2.0 * full_scale
    elif case == "jump":
        frames[60, 17] = 1e6
        frames[70:, 40] += np.sqrt(np.mean(frames[:20] ** 2))
    elif case == "faulty":
        frames[25:, imager.protocol.touching([5])] *= 1e-3  # a broken lead
    elif case == "reference":
        frames[:20, 9] = 0.0  # a channel without a reference: left out of every image
    return imager, frames, flags


@pytest.mark.parametrize("case", CASES)
def test_both_implementations_image_every_frame_alike(setup, case):
    name, imagers, frames = setup
    (imager, frames, flags), (other, _, _) = (case_input(case, i, frames) for i in imagers)
    processors = [
        LayerProcessor(i, 20, drift_time_constant_s=1.0, compiled_step=c)
        for i, c in ((imager, True), (other, False))
    ]
    for k, frame in enumerate(frames):
        a, b = (p.step(frame.copy(), 0.02 * k, flags.get(k)) for p in processors)
        assert (a is None) == (b is None), k
        if a is None:
            continue
        assert (a.touching, a.channels_used) == (b.touching, b.channels_used), k
        np.testing.assert_array_equal(a.values, b.values, err_msg=f"frame {k}")
        np.testing.assert_array_equal(a.image, b.image, err_msg=f"frame {k}")
        np.testing.assert_array_equal(*(p.reference() for p in processors), f"frame {k}")
    compiled, numpy_path = processors
    for counter in ("frames_imaged", "drift_updates", "values_out_of_range", "values_jumped"):
        assert getattr(compiled, counter) == getattr(numpy_path, counter), counter
    assert compiled.frames_imaged == N_FRAMES - 20
    assert numpy_path.frames_compiled == 0
    planned = imager.frame_plan is not None  # Gauss-Newton: never planned
    if case == "clean":
        assert compiled.frames_compiled == (N_FRAMES - 20 if planned else 0), name
    elif case == "reference":  # a channel left out of every image: the general path
        assert compiled.frames_compiled == 0
    else:
        assert (compiled.frames_compiled > 0) == planned, name
    if case == "faulty" and planned:  # the frames after the electrode is named: general
        assert compiled.frames_compiled < N_FRAMES - 20 - 40


def test_the_reference_step_and_the_kernel_on_one_plan(setup):
    """Directly on the plan: every output equal, and None alike for an implausible value,
    a jump and a non-finite product; with unknown noise the frame counts as touched."""
    name, (imager, _), frames = setup
    plan = imager.frame_plan
    if plan is None:
        assert name == "gauss_newton"
        return
    reference = frames[:20].mean(axis=0)
    noise = np.full(imager.mesh.n_triangles, 2e-3)
    limit = np.full(frames.shape[1], 1e-3)
    cases = [
        FrameChecks(noise, 5.0, 0.25),
        FrameChecks(None, 5.0, 0.25),
        FrameChecks(noise, 5.0, None, full_scale_v=1e-9),  # every value beyond it
        FrameChecks(noise, 5.0, 0.1, previous_v=frames[19], jump_limit_v=limit * 1e-6),
        FrameChecks(noise, 5.0, 0.1, previous_v=frames[19], jump_limit_v=limit * 1e6),
    ]
    outcomes = set()
    for checks in cases:
        for frame in frames[20::7]:
            a = compiled_step(plan, frame, reference, checks)
            b = reference_step(plan, frame, reference, checks)
            assert (a is None) == (b is None)
            if a is None:
                outcomes.add("none")
                continue
            outcomes.add(a.touching)
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y)
            if checks.element_noise is None:
                assert a.touching and a.reference_v is reference
    assert outcomes == {"none", True, False}
    bad = reference.copy()
    bad[4] = np.nan  # a floor that is not finite
    assert compiled_step(plan, frames[30], bad, cases[0]) is None
    assert reference_step(plan, frames[30], bad, cases[0]) is None
