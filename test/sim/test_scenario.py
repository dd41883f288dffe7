"""Scenarios: built-in scripts, random scripts, the YAML format and its errors."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.random_scenes import random_scenario
from eit_skin.sim.scenario import EDGE_MARGIN_M, ScenarioError, SheetFrame
from eit_skin.sim.scenario_yaml import load_scenario
from eit_skin.sim.scripts import BUILTIN_SCENARIOS, builtin_scenario


@pytest.fixture(scope="module", params=["arm", "face", "elbow"])
def patch(request):
    return load_patch(config_path(request.param))


def test_builtin_scripts_fit_every_patch(patch) -> None:
    frame = SheetFrame.of(patch)
    for name in BUILTIN_SCENARIOS:
        scenario = builtin_scenario(name, patch, seed=1, duration_s=20.0)
        for s in scenario.touches:
            assert frame.fits(s), (name, s)
            assert s.t_start_s >= 0.0 and s.t_end_s + s.settle_s <= scenario.duration_s


def test_demo_is_one_pass_of_the_four_touches(patch) -> None:
    demo = builtin_scenario("demo", patch)
    assert [s.label for s in demo.touches] == ["push", "rub", "pinch", "grab"]
    assert 15.0 <= demo.duration_s <= 20.0
    assert demo.first_touch_s() >= 0.5  # a no-load period for the reference
    truth = demo.truth(50.0)
    assert [t.label for t in truth] == ["push", "rub", "pinch", "grab"]
    assert len(truth[2].contacts) == 2 and 3 <= len(truth[3].contacts) <= 5


def test_random_scenarios_never_overlap_and_stay_inside(patch) -> None:
    frame = SheetFrame.of(patch)
    labels = set()
    for seed in range(3):
        scenario = random_scenario(seed, 60.0, patch)
        touches = scenario.touches
        assert len(touches) >= 10
        for a, b in itertools.pairwise(touches):
            assert b.t_start_s >= a.t_end_s + a.settle_s  # incl. the rub trail relaxing
        for s in touches:
            assert s.t_end_s + s.settle_s <= 60.0
            t = [s.t_start_s + f * s.duration_s for f in (0.0, 0.3, 0.5, 0.8, 1.0)]
            for ti in t:
                clearance = frame.clearance(s.contacts(ti))
                assert (clearance >= s.radius_m + EDGE_MARGIN_M - 1e-12).all()
            labels.add(s.label)
    assert labels == {"push", "rub", "pinch", "grab"}


def test_random_scenarios_are_reproducible_per_seed(patch) -> None:
    a = random_scenario(7, 30.0, patch)
    b = random_scenario(7, 30.0, patch)
    c = random_scenario(8, 30.0, patch)
    assert a.touches == b.touches
    assert a.touches != c.touches


def test_yaml_scenario_loads(tmp_path: Path) -> None:
    arm = load_patch(config_path("arm"))
    path = tmp_path / "s.yaml"
    path.write_text(
        "name: mine\n"
        "touches:\n"
        "  - {at: 1.0, touch: push, position: [0.01, 0.0], duration: 1.0, force_n: 5}\n"
        "  - {at: 3.0, touch: rub, position: [-0.015, 0.0], duration: 1.0, speed: 0.04,"
        " direction_deg: -10}\n"
        "  - {at: 5.0, touch: pinch, position: [0, 0], axis_deg: 90, start_gap: 0.04,"
        " end_gap: 0.015}\n"
        "  - {at: 7.0, touch: grab, positions: [[-0.015, 0], [0.015, 0], [0, 0.015]]}\n"
        "posture:\n"
        "  - {at: 0.0, angle: 0.0}\n"
        "  - {at: 2.0, angle: 1.0}\n"
    )
    scenario = load_scenario(path, arm)
    assert scenario.name == "mine"
    assert [s.label for s in scenario.touches] == ["push", "rub", "pinch", "grab"]
    assert scenario.touches[0].force_n == 5.0
    assert scenario.touches[3].center == pytest.approx([0.0, 0.005])
    assert scenario.posture.angle(2.0) == 1.0
    assert scenario.duration_s == pytest.approx(7.0 + 1.5 + 1.5)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("- {at: 1, touch: poke, position: [0, 0]}", "touches[0].touch"),
        ("- {at: 1, touch: push}", "touches[0].position"),
        ("- {at: 1, touch: push, position: [0.039, 0]}", "touches[0].position"),
        ("- {at: 1, touch: push, position: [0, 0], colour: red}", "touches[0].colour"),
        ("- {at: -1, touch: push, position: [0, 0]}", "touches[0].at"),
        ("- {at: 1, touch: push, position: [0, 0], force_n: '3'}", "touches[0].force_n"),
        (
            "- {at: 1, touch: push, position: [0, 0]}\n- {at: 2, touch: push, position: [0, 0]}",
            "touches[1].at",
        ),
        ("- {at: 1, touch: pinch, position: [0, 0], end_gap: 0.05}", "touches[0].end_gap"),
        ("touches: []\nposture: [{at: 1, angle: 0}, {at: 0.5, angle: 1}]", "posture[1].at"),
        ("touches: []\nspeed: 3", "speed"),
        ("touches: [\n", "line 3, column 1"),
    ],
)
def test_yaml_errors_name_the_file_and_key(tmp_path: Path, text: str, key: str) -> None:
    arm = load_patch(config_path("arm"))
    path = tmp_path / "bad.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, arm)
    assert str(info.value).startswith(f"{path}: {key}: "), str(info.value)


def test_yaml_1_2_exponents_are_numbers(tmp_path: Path) -> None:
    arm = load_patch(config_path("arm"))
    path = tmp_path / "s.yaml"
    path.write_text("- {at: 1, touch: push, position: [5e-3, -4e-3], radius: 5e-3, ramp: 2e-1}\n")
    push = load_scenario(path, arm).touches[0]
    assert push.center == pytest.approx([0.005, -0.004])
    assert push.radius_m == 0.005 and push.ramp_s == 0.2


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "- {at: 1, touch: push, posiiton: [0, 0]}",
            "touches[0].posiiton: unknown key of a push touch; did you mean 'position'?",
        ),
        (
            "- {at: 1, touch: rub, position: [0, 0], sped: 0.05}",
            "touches[0].sped: unknown key of a rub touch; did you mean 'speed'?",
        ),
        ("- {at: 1, tuch: push, position: [0, 0]}", "touches[0].tuch: unknown key of a touch; "),
        ("touchs: []", "touchs: unknown key; did you mean 'touches'?"),
        ("touches: []\nposture: [{at: 0, angel: 1}]", "posture[0].angel: unknown key of a "),
        (
            "touches: []\nname: a\nname: b",
            "name: duplicate key: first on line 2, again on line 3",
        ),
        (
            "- {at: 1, touch: push, position: [0, 0], at: 2}",
            "touches[0].at: duplicate key: first on line 1, again on line 1",
        ),
        ("", "(file): empty file"),
        (" \n\t \n", "(file): empty file"),
        ("# to do\n", "(file): empty file"),
    ],
)
def test_yaml_errors_give_the_reason(tmp_path: Path, text: str, message: str) -> None:
    arm = load_patch(config_path("arm"))
    path = tmp_path / "bad.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, arm)
    assert str(info.value).startswith(f"{path}: {message}"), str(info.value)
