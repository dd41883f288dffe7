"""A newcomer's way in runs: the examples/ scripts and the entry points' docstring examples."""

from __future__ import annotations

import doctest
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.py"))

#: The public entry points whose docstrings carry examples (load_patch, LayerImager.build,
#: LayerProcessor, TouchClassifier).
DOCTESTED = (
    "eit_skin.patch.loading",
    "eit_skin.pipeline.builder",
    "eit_skin.pipeline.processor",
    "eit_skin.touch.classifier",
)


def test_there_is_an_example() -> None:
    assert [p.name for p in EXAMPLES] == ["patch_to_touch.py"]


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_an_example_runs_as_a_script(script: Path) -> None:
    # as a newcomer runs it: its own process, from the repository root (the shared cache)
    result = subprocess.run(
        [sys.executable, str(script)],
        cwd=script.parents[1],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) <= 60 and len(script.read_text().splitlines()) <= 60
    if script.name == "patch_to_touch.py":  # one push, recognised as one
        states = [(line.split()[2], line.split()[3]) for line in lines]
        assert states[0] == ("start", "push") and states[-1] == ("end", "push"), lines
        assert {s for s, _ in states} <= {"start", "update", "end"}
        assert {label for _, label in states} == {"push"}


@pytest.mark.parametrize("name", DOCTESTED)
def test_docstring_examples_hold(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0, f"{name} has no example"
    assert result.failed == 0
