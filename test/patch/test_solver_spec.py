"""solver.method and solver.prior: GREIT is a method; the old `prior: greit` still loads."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from eit_skin.patch import PatchError, load_patch

ARM = Path(__file__).resolve().parents[2] / "config" / "arm.yaml"


def arm_with_solver(tmp_path: Path, solver: str) -> Path:
    text = re.sub(r"solver: \{[^}]*\}", f"solver: {{{solver}}}", ARM.read_text())
    path = tmp_path / "arm.yaml"
    path.write_text(text)
    return path


def test_old_spelling_loads_as_method_greit_with_the_same_hash(tmp_path):
    new = load_patch(arm_with_solver(tmp_path, "method: greit, noise_figure: 0.13"))
    old = load_patch(
        arm_with_solver(tmp_path, "method: one_step, prior: greit, noise_figure: 0.13")
    )
    assert [ly.solver.method for ly in old.layers] == ["greit", "greit"]
    assert [ly.content_hash for ly in old.layers] == [ly.content_hash for ly in new.layers]


def test_greit_as_the_prior_of_gauss_newton_is_refused_naming_the_key(tmp_path):
    path = arm_with_solver(tmp_path, "method: gauss_newton, prior: greit")
    with pytest.raises(PatchError, match=r"solver\.prior.*'greit' is a one-step method"):
        load_patch(path)


def test_unknown_method_is_refused_with_the_choices(tmp_path):
    with pytest.raises(PatchError, match=r"solver\.method.*one_step.*greit.*gauss_newton"):
        load_patch(arm_with_solver(tmp_path, "method: newton"))


def test_a_solver_without_noise_figure_gets_its_method_default(tmp_path):
    from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
    from eit_skin.pipeline.builder import LayerImager

    layer = load_patch(arm_with_solver(tmp_path, "method: greit")).layers[0]
    assert layer.solver.noise_figure is None
    imager = LayerImager.build(layer, cache_dir=None)
    nf = DEFAULT_NOISE_FIGURE["greit"]
    explicit = load_patch(arm_with_solver(tmp_path, f"method: greit, noise_figure: {nf}"))
    assert imager.matrix.hyperparameter == pytest.approx(
        LayerImager.build(explicit.layers[0], cache_dir=None).matrix.hyperparameter
    )


def test_channel_weights_round_trip_and_a_bad_value_is_refused_naming_the_key(tmp_path):
    from eit_skin.patch.model import DEFAULT_CHANNEL_WEIGHTS

    layers = load_patch(arm_with_solver(tmp_path, "method: greit")).layers
    assert [ly.solver.channel_weights for ly in layers] == [DEFAULT_CHANNEL_WEIGHTS] * 2
    for weights in ("measured", "equal"):
        path = arm_with_solver(tmp_path, f"method: greit, channel_weights: {weights}")
        assert [ly.solver.channel_weights for ly in load_patch(path).layers] == [weights] * 2
    # the key changes no build: a patch at the default keeps the hash it had without the key
    default = arm_with_solver(
        tmp_path, f"method: greit, channel_weights: {DEFAULT_CHANNEL_WEIGHTS}"
    )
    assert [ly.content_hash for ly in load_patch(default).layers] == [
        ly.content_hash for ly in layers
    ]
    with pytest.raises(PatchError, match=r"solver\.channel_weights.*'equals'.*measured, equal"):
        load_patch(arm_with_solver(tmp_path, "method: greit, channel_weights: equals"))
