"""Regression guard on real measurements: the five recordings of ``data/real/``.

eit_skin's shipped defaults (each set's patch file, through ``LayerImager``, the
reconstruction node's chain, with the reference check, measured channel noise and model-error
rule of ``LayerImager.use_reference``) must keep imaging every set about as well as they do
now, never produce a non-finite pixel, and keep their images clean: few blobs of either sign
beyond the targets and little image energy away from them (issue 35). The bounds are the
figures of ``bench/standing/real_data.md`` with a margin, so that method work can improve them
freely
while a broken chain (wrong sign, order, scale, geometry) or a return to noise-dominated
images fails. The figures are deterministic: no noise is drawn here.

The scores come from ``bench/standing/real_data_scoring.py``, the module the benchmark uses, loaded
from its file with ``importlib`` (the benchmark imports it as a sibling; neither side
imports the other's folder as a package and nothing is added to ``sys.path``).
"""

from __future__ import annotations

import functools
import importlib.util
import itertools
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from eit_skin.inverse.hyperparameter import MODEL_ERROR_SHARE
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import SolverSpec
from eit_skin.pipeline.builder import LayerImager

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "data" / "real"


def _load_scoring():
    name = "eit_skin_bench_real_data_scoring"
    if name not in sys.modules:  # dataclasses look their module up in sys.modules
        spec = importlib.util.spec_from_file_location(
            name, REPO / "bench" / "standing" / "real_data_scoring.py"
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


scoring = _load_scoring()

# Position sets: bound on the median position error, metres. Measured (bench/standing/real_data.md,
# run 2026-11-27 16:15): ottawa_ph1 / ottawa_ph3 9.1 / 8.1 mm with the package default
# (one-step NOSER, NF 0.13, model-error share 1/2, equal channel weights) and the tanks' fitted
# depths (pyEIT 16.6 / 15.8 mm); 16.9 / 17.3 mm with the same default on the 2-D sheets, 17.7 /
# 17.1 mm with the default before (share 1/4, measured weights, 2-D) -> 12.0 mm, below 0.8 x
# pyEIT's (13.3 / 12.6 mm: issue 35's goal), which a lost depth fails; the images are
# deterministic, the margin covers BLAS rounding and small method changes. hydrogel_ohmc16:
# 24.8 mm with the package default (21.1 mm with the one before, 39.5 mm with GREIT at NF
# 0.13) -> 0.8 x pyEIT's 36.0 mm = 28.8 mm (issue 35's goal), and it must stay better than
# always answering the centre of the skin (50.9 mm).
MEDIAN_BOUND_M = {"ottawa_ph1": 0.0120, "ottawa_ph3": 0.0120, "hydrogel_ohmc16": 0.0288}
# Track sets: (lowest direction consistency, largest circle-fit residual in metres). Measured:
# iirc_rotate 0.980 / 3.9 mm (previously 0.970, which fails 0.975; the package default 0.980
# / 3.5 mm), sciospec_adjacent 0.778 / 3.7 mm (package default 0.804 / 3.8 mm; its slow phase
# limits it, see the report) -> consistency - 0.1, residual x 1.5.
TRACK_BOUND = {"iirc_rotate": (0.975, 0.0059), "sciospec_adjacent": (0.68, 0.0056)}
SETS = (*MEDIAN_BOUND_M, *TRACK_BOUND)
# Image quality (issue 35): (largest mean spurious blobs per frame, largest median artefact
# energy). Measured with the package default (bench/standing/real_data.md, run 2026-11-27
# 16:15): spurious 0 on the four tanks, 2.74 on hydrogel_ohmc16 (pyEIT 5.50); artefact energy
# ottawa_ph1 0.140, ottawa_ph3 0.155, iirc_rotate 0.097, sciospec_adjacent 0.115,
# hydrogel_ohmc16 0.82 (pyEIT 0.247, 0.278, 0.098, 0.115, 0.88). Bounds: about pyEIT's level
# (the Ottawa tanks: pyEIT's, where the default is well below it; iirc_rotate and
# sciospec_adjacent, where it is at pyEIT's, pyEIT's plus 0.01). Noise-dominated images fail them
# (test_quality_bound_fails_for_noise_dominated_images; the tanks at their depths): the GREIT
# matrix at noise figure 0.13 (measured weights) the patch files shipped before scores
# 1.33 / 0.98, 3.67 / 0.58, 0 / 0.14, 0.01 / 0.16 and 6.47 / 0.92; the noise figure alone (no
# model-error rule) 1.33 / 0.57, 7.33 / 0.64, 0 / 0.06, 0.01 / 0.09 and 6.59 / 0.90. On
# iirc_rotate and sciospec_adjacent (the smallest model misfits) the noise figure alone is as
# clean as the rule, so only the previous GREIT matrix must fail there.
QUALITY_BOUND = {
    "ottawa_ph1": (0.2, 0.25),
    "ottawa_ph3": (0.2, 0.28),
    "iirc_rotate": (0.2, 0.11),
    "sciospec_adjacent": (0.2, 0.12),
    "hydrogel_ohmc16": (5.0, 0.85),
}
#: Noise-dominated solvers: (solver settings, ``model_error_share``), and the sets whose
#: quality bound each must fail.
NOISE_DOMINATED = {
    "previous": (
        (("method", "greit"), ("noise_figure", 0.13), ("channel_weights", "measured")),
        ("ottawa_ph1", "ottawa_ph3", "iirc_rotate", "sciospec_adjacent", "hydrogel_ohmc16"),
    ),
    "noise figure alone": ((), ("ottawa_ph1", "ottawa_ph3", "hydrogel_ohmc16")),
}


@functools.cache
def eit_skin_images(
    name: str, solver: tuple[tuple[str, object], ...] = (), model_error_share: float | None = None
):
    """The set, eit_skin's images ``[T, H, W]`` of it, the image grid and the sheet radius (m).

    ``solver``: ``(key, value)`` pairs replacing the patch file's solver settings;
    ``model_error_share``: ``use_reference``'s (None: the package's).
    """
    layer = load_patch(DATA / f"{name}.yaml").layers[0]
    if solver:
        layer = replace(layer, solver=replace(layer.solver, **dict(solver)))
    data = scoring.load_set(DATA / f"{name}.npz")
    imager = LayerImager.build(layer)  # cached in EIT_SKIN_CACHE (conftest: never ~/.cache)
    with np.load(DATA / f"{name}.npz") as raw:  # the node's rule: reference check, noise
        extra = {} if model_error_share is None else {"model_error_share": model_error_share}
        imager.use_reference(data.reference, raw.get("reference_frames"), data.frames, **extra)
    images = imager.images(imager.relative_change(data.frames, data.reference))
    radius = float(np.linalg.norm(layer.outline, axis=1).max())
    return data, images, imager.grid, radius


def scores(name: str, images: np.ndarray | None = None) -> dict[str, float]:
    data, own, grid, radius = eit_skin_images(name)
    images = own if images is None else images
    return scoring.score(data, images, grid.x, grid.y, grid.inside, radius)


def within_bounds(name: str, s: dict[str, float]) -> bool:
    data = eit_skin_images(name)[0]
    if name in TRACK_BOUND:
        lowest, largest = TRACK_BOUND[name]
        return s["consistency"] >= lowest and s["fit_residual_m"] <= largest
    centre = float(np.median(scoring.centre_errors(data.truth_xy)))
    return s["median_m"] <= min(MEDIAN_BOUND_M[name], centre)


@pytest.mark.parametrize("name", SETS)
def test_real_set_stays_within_its_bound(name: str) -> None:
    s = scores(name)
    assert within_bounds(name, s), f"{name}: {s}"


def within_quality_bound(name: str, s: dict[str, float]) -> bool:
    spurious, energy = QUALITY_BOUND[name]
    return s["spurious"] <= spurious and s["artefact_energy"] <= energy


@pytest.mark.parametrize("name", SETS)
def test_real_set_images_are_clean(name: str) -> None:
    """Few blobs beyond the targets and little energy away from them (issue 35)."""
    s = scores(name)
    assert within_quality_bound(name, s), f"{name}: {s}"


@pytest.mark.parametrize(
    ("solver", "name"),
    [(label, name) for label, (_, names) in NOISE_DOMINATED.items() for name in names],
)
def test_quality_bound_fails_for_noise_dominated_images(solver: str, name: str) -> None:
    """The bound has teeth: the GREIT images the patch files gave before, and the noise
    figure without the model-error rule, fail it."""
    settings, _ = NOISE_DOMINATED[solver]
    data, images, grid, radius = eit_skin_images(name, settings, model_error_share=0.0)
    s = scoring.score(data, images, grid.x, grid.y, grid.inside, radius)
    assert not within_quality_bound(name, s), f"{name}: {s}"


@pytest.mark.parametrize("name", SETS)
def test_real_set_images_are_finite_on_the_sheet(name: str) -> None:
    _, images, grid, _ = eit_skin_images(name)
    assert grid.inside.sum() > 0.7 * grid.inside.size  # a disc fills pi/4 of its square
    assert scoring.nonfinite_pixels(images, grid.inside) == 0
    assert np.isnan(images[:, ~grid.inside]).all()  # off the sheet stays NaN


@pytest.mark.parametrize("name", SETS)
def test_bound_fails_for_a_broken_chain(name: str) -> None:
    """The guard has teeth: images of the wrong sign (position sets) or in a scrambled frame
    order (track sets, as if the frames were mixed up) break the bound."""
    _, images, _, _ = eit_skin_images(name)
    if name in TRACK_BOUND:
        broken = images[np.random.default_rng(0).permutation(len(images))]
    else:
        broken = -images
    assert not within_bounds(name, scores(name, broken))


def test_the_package_default_is_the_one_the_leave_one_set_out_table_chose() -> None:
    """bench/standing/real_data.md chooses the default on five sets for every sixth; what a patch
    without a solver section gets must be the choice on all six sets, and on every set left
    out it must miss no more goals than that fold's own choice (issue 35: a fold may choose
    otherwise only if its choice does no better where it was not chosen), so a default changed
    without rerunning the benchmark, or a benchmark whose choice was not shipped, fails here."""
    method, prior = SolverSpec().method, SolverSpec().prior
    names = {"noser": "NOSER", "laplace": "Laplace", "tikhonov": "Tikhonov"}  # the bench's
    shipped = (
        f"one-step {names[prior]} NF {DEFAULT_NOISE_FIGURE[method]:g}, "
        f"model error 1/{1 / MODEL_ERROR_SHARE:.0f}"
        + (", channels weighted equally" if SolverSpec().channel_weights == "equal" else "")
    )
    report = (REPO / "bench" / "standing" / "real_data.md").read_text().splitlines()
    header = next(i for i, line in enumerate(report) if line.startswith("| set left out |"))
    rows = [line.split("|")[1:-1] for line in report[header + 2 :] if line.startswith("| ")]
    rows = list(itertools.takewhile(lambda cells: len(cells) == 4, rows))
    assert len(rows) == 6, report[header : header + 8]
    assert method == "one_step"
    missed = [[int(cells[k].split(" of ")[0]) for k in (2, 3)] for cells in rows]
    assert all(default <= chosen for chosen, default in missed), rows
    overall = next(line for line in report if line.startswith("Chosen on all six sets: "))
    assert overall.startswith(f"Chosen on all six sets: {shipped} ("), overall


# --- the scoring rules themselves (synthetic images, exact answers) ---------------------------

X = np.linspace(-0.1, 0.1, 41)
Y = np.linspace(-0.1, 0.1, 41)


def dip(centre, depth: float, width: float = 0.01) -> np.ndarray:
    """``[H, W]`` Gaussian dip of ``depth`` at ``centre`` (m) on the X x Y grid."""
    xx, yy = np.meshgrid(X, Y)
    return -depth * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * width**2))


def test_blobs_are_scale_free_and_ranked_by_strength() -> None:
    image = dip((0.05, 0.0), 2.0) + dip((-0.04, 0.03), 1.5) + 0.3 * dip((0.0, -0.06), -1.0)
    image[0, 0] = np.nan  # off the sheet
    xy, weight = scoring.blobs(image, X, Y, sign=-1)
    assert xy.shape == (2, 2)  # the positive bump is not a blob of the expected sign
    np.testing.assert_allclose(xy, [[0.05, 0.0], [-0.04, 0.03]], atol=1e-3)
    assert weight[0] > weight[1]
    xy_scaled, _ = scoring.blobs(1e-4 * image, X, Y, sign=-1)
    np.testing.assert_allclose(xy_scaled, xy, rtol=1e-9, atol=1e-12)
    assert scoring.blobs(-np.abs(image), X, Y, sign=+1)[0].shape == (0, 2)


def test_matching_is_one_to_one_and_merged_targets_both_count() -> None:
    blob_xy = np.array([[0.05, 0.0], [-0.04, 0.03]])
    targets = np.array([[-0.04, 0.02], [0.05, 0.01]])
    np.testing.assert_allclose(scoring.match_errors(blob_xy, targets), [0.01, 0.01])
    np.testing.assert_array_equal(scoring.matched_blobs(blob_xy, targets), blob_xy[::-1])
    np.testing.assert_array_equal(scoring.matched_blobs(blob_xy[:1], targets), blob_xy[[0, 0]])
    one = scoring.match_errors(blob_xy[:1], targets)
    np.testing.assert_allclose(one, [np.hypot(0.09, 0.02), 0.01])
    assert np.isinf(scoring.match_errors(np.empty((0, 2)), targets)).all()
    summary = scoring.error_summary(np.array([0.01, np.inf, 0.02]), radius_m=0.1)
    assert summary["no_blob"] == 1 and summary["median_m"] == 0.02 and summary["p90_m"] > 0.1


def test_position_errors_of_images_with_known_targets() -> None:
    images = np.stack([dip((0.03, 0.04), 1.0), dip((0.0, 0.05), 1.0) + dip((-0.05, 0.0), 0.9)])
    truth = np.array([[[0.03, 0.04], [np.nan, np.nan]], [[0.0, 0.05], [-0.05, 0.0]]])
    errors = scoring.position_errors(images, X, Y, truth, sign=-1)
    assert errors.shape == (3,) and errors.max() < 1e-3
    np.testing.assert_allclose(scoring.centre_errors(truth), [0.05, 0.05, 0.05])


def test_track_direction_and_circle_fit() -> None:
    angle = np.linspace(0.0, 4 * np.pi, 60)
    circle = 0.05 * np.column_stack([np.cos(angle), np.sin(angle)]) + [0.01, -0.02]
    centre, radius, residual = scoring.circle_fit(circle)
    np.testing.assert_allclose(centre, [0.01, -0.02], atol=1e-9)
    assert abs(radius - 0.05) < 1e-9 and residual < 1e-9
    assert scoring.direction_consistency(circle - [0.01, -0.02]) == (1.0, 1)
    assert scoring.direction_consistency(circle[::-1] - [0.01, -0.02]) == (1.0, -1)
    noise = np.random.default_rng(1).normal(0.0, 0.05, (400, 2))
    fraction, _ = scoring.direction_consistency(noise)
    assert 0.5 <= fraction < 0.6
    with_gap = circle.copy()
    with_gap[10] = np.nan  # an image without a blob: both its steps count as inconsistent
    assert scoring.direction_consistency(with_gap - [0.01, -0.02])[0] == pytest.approx(57 / 59)


def test_presence_follows_the_data_not_the_images() -> None:
    reference = np.linspace(1.0, 2.0, 8)
    frames = np.stack([reference * (1 + s) for s in (0.0, 0.001, 0.1, 0.05, 0.01)])
    np.testing.assert_array_equal(
        scoring.present_frames(frames, reference), [False, False, True, True, False]
    )


def test_blob_count_takes_both_signs_and_is_scale_free() -> None:
    image = dip((0.05, 0.0), 2.0) + dip((-0.04, 0.03), 0.5) + dip((0.0, -0.06), -1.5)
    image[0, 0] = np.nan
    assert scoring.blob_count(image) == 2  # the 0.5 dip is below half of the peak 2.0
    assert scoring.blob_count(-1e-3 * image) == 2
    assert scoring.blob_count(image, fraction=0.2) == 3
    assert scoring.blob_count(np.zeros((5, 5))) == 0


def test_artefact_energy_is_the_share_far_from_every_target() -> None:
    image = np.zeros((41, 41))
    image[20, 30] = 3.0  # pixel at (0.05, 0): the target
    image[5, 5] = -4.0  # pixel at (-0.075, -0.075): an artefact
    target = np.array([[0.05, 0.0]])
    assert scoring.artefact_energy(image, X, Y, target, radius_m=0.1) == pytest.approx(16 / 25)
    both = np.array([[0.05, 0.0], [-0.07, -0.07]])
    assert scoring.artefact_energy(image, X, Y, both, radius_m=0.1) == 0.0
    assert scoring.artefact_energy(image, X, Y, np.empty((0, 2)), radius_m=0.1) == 1.0
    q = scoring.image_quality(
        np.stack([image, image]), X, Y, [target, np.empty((0, 2))], radius_m=0.1
    )
    assert q["blobs"] == 2.0 and q["targets"] == 0.5 and q["spurious"] == 1.5
    assert q["artefact_energy"] == pytest.approx(0.5 * (16 / 25 + 1.0))
