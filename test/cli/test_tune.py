"""``eit-skin tune``: hyperparameter by noise figure, stored in a copy of a shipped patch file."""

from __future__ import annotations

import shutil
from dataclasses import replace

import pytest
import yaml

from eit_skin.cli.main import main
from eit_skin.cli.tune import set_solver_hyperparameter
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path


@pytest.fixture
def arm_copy(tmp_path):
    path = tmp_path / "arm.yaml"
    shutil.copyfile(config_path("arm"), path)
    return path


def _solver_lines(text):
    return [i for i, line in enumerate(text.splitlines()) if line.strip().startswith("solver:")]


def test_write_stores_the_noise_figure_choice_and_keeps_everything_else(arm_copy, capsys):
    from eit_skin.fem.forward import ForwardModel
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.inverse.greit import greit_matrix
    from eit_skin.inverse.hyperparameter import noise_figure
    from eit_skin.inverse.one_step import imaging_jacobian
    from eit_skin.patch.protocol import build_protocol

    before_text = arm_copy.read_text()
    before = load_patch(arm_copy)
    assert before.layer("stretch").solver.hyperparameter is None
    argv = ["tune", "--patch", str(arm_copy), "--layer", "stretch", "--noise-figure", "0.2"]
    assert main([*argv, "--write"]) == 0
    out = capsys.readouterr().out
    after_text = arm_copy.read_text()
    after = load_patch(arm_copy)
    h = after.layer("stretch").solver.hyperparameter
    assert h is not None and f"hyperparameter {h:.4g} " in out and "wrote" in out
    # only the stretch layer's solver line changed; every comment and other line is kept
    old_lines, new_lines = before_text.splitlines(), after_text.splitlines()
    assert len(old_lines) == len(new_lines)
    changed = [i for i, (a, b) in enumerate(zip(old_lines, new_lines, strict=True)) if a != b]
    assert changed == [_solver_lines(before_text)[1]]
    assert new_lines[changed[0]].startswith(old_lines[changed[0]].rstrip("}"))
    # every other key unchanged
    stretch = after.layer("stretch")
    assert replace(stretch.solver, hyperparameter=None) == before.layer("stretch").solver
    assert after.layer("pressure").content_hash == before.layer("pressure").content_hash
    restored = replace(stretch, solver=replace(stretch.solver, hyperparameter=None))
    assert restored.content_hash == before.layer("stretch").content_hash
    # the stored value has the asked-for noise figure (4 significant digits)
    layer = after.layer("stretch")
    fwd = ForwardModel(
        build_mesh(layer),
        build_protocol(layer.protocol, layer.n_electrodes),
        layer.contact_impedance_ohm_m,
        layer.current_a,
    )
    assert layer.solver.method == "greit"
    inverse_mesh = build_mesh(layer, layer.mesh.inverse_max_edge_m)
    jacobian = imaging_jacobian(fwd, layer.material.sheet_conductance_s, inverse_mesh)
    rm = greit_matrix(jacobian, inverse_mesh, hyperparameter=h)
    assert noise_figure(rm) == pytest.approx(0.2, rel=2e-3)
    # tuning again replaces the value in place instead of adding a second key
    assert main([*argv, "--noise-figure", "0.3", "--write"]) == 0
    again = arm_copy.read_text()
    assert again.count("hyperparameter") == after_text.count("hyperparameter")
    assert load_patch(arm_copy).layer("stretch").solver.hyperparameter > h


def test_without_write_nothing_changes_and_shipped_configs_are_never_written(arm_copy, capsys):
    shipped = config_path("arm")
    shipped_text = shipped.read_text()
    text = arm_copy.read_text()
    assert main(["tune", "--patch", str(arm_copy)]) == 0
    assert "not written" in capsys.readouterr().out
    assert arm_copy.read_text() == text
    assert main(["tune", "--patch", "arm", "--write"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "never written by name" in err
    assert shipped.read_text() == shipped_text


def test_unknown_layer_is_one_line_error(arm_copy, capsys):
    assert main(["tune", "--patch", str(arm_copy), "--layer", "nope"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope" in err


BLOCK = """\
# a comment at the top
name: p  # trailing comment
layers:
  - name: a
    solver:
      prior: laplace   # the prior
      noise_figure: 0.3
    mesh: {max_edge: 0.003}
  - name: b
    mesh: {max_edge: 0.003}
  - name: c
    solver: {}
  - name: d
    solver:
      hyperparameter: 0.5  # old value
      prior: tikhonov
# closing comment
"""


@pytest.mark.parametrize(
    ("layer", "expected_solver"),
    [
        ("a", {"prior": "laplace", "noise_figure": 0.3, "hyperparameter": 0.01234}),
        ("b", {"hyperparameter": 0.01234}),
        ("c", {"hyperparameter": 0.01234}),
        ("d", {"hyperparameter": 0.01234, "prior": "tikhonov"}),
    ],
)
def test_text_edit_of_block_flow_missing_and_existing_solver(layer, expected_solver):
    new = set_solver_hyperparameter(BLOCK, layer, 0.012344)
    data, old = yaml.safe_load(new), yaml.safe_load(BLOCK)
    layers = {lay["name"]: lay for lay in data["layers"]}
    assert layers[layer]["solver"] == expected_solver
    for name, lay in {x["name"]: x for x in old["layers"]}.items():
        if name != layer:
            assert layers[name] == lay
        else:
            assert {k: v for k, v in layers[name].items() if k != "solver"} == {
                k: v for k, v in lay.items() if k != "solver"
            }
    for comment in ("# a comment at the top", "# trailing comment", "# the prior", "# closing"):
        assert comment in new
    assert len(new.splitlines()) - len(BLOCK.splitlines()) == (1 if layer in "ab" else 0)


def test_text_edit_rejects_unknown_layer():
    with pytest.raises(ValueError, match="no layer named 'x'"):
        set_solver_hyperparameter(BLOCK, "x", 0.1)
