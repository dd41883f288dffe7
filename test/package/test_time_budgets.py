"""Every test has a time budget: a hang fails by name, stretched on a loaded machine only.

A tiny suite with one hanging test runs in a child pytest with this repository's conftest
(``-p test.conftest``) and pytest.ini; the child's output must name the hanging test and
the budget it overran.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

HANG = """
import time

def test_quick():
    pass

def test_that_hangs():
    time.sleep(60)
"""


def run_child(tmp_path: Path, repo: Path, slowdown: str, timeout: str) -> tuple[str, float]:
    (tmp_path / "test_hang.py").write_text(HANG)
    env = dict(os.environ, EIT_SKIN_TEST_SLOWDOWN=slowdown, PYTHONPATH=str(repo))
    args = ["-p", "test.conftest", "-c", str(repo / "pytest.ini"), "--rootdir", str(tmp_path)]
    started = time.monotonic()
    child = subprocess.run(
        [sys.executable, "-m", "pytest", *args, "--timeout", timeout, "-p", "no:cacheprovider"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=50,
    )
    return child.stdout + child.stderr, time.monotonic() - started


def test_the_default_budget_is_a_minute(pytestconfig: pytest.Config) -> None:
    assert float(pytestconfig.getini("timeout")) == 60


def test_a_hang_names_itself_after_its_budget_stretched_by_the_load(tmp_path, repo) -> None:
    output, took_s = run_child(tmp_path, repo, slowdown="2", timeout="1")
    assert "test_hang.py::test_that_hangs - Failed: Timeout (>2.0s)" in output, output[-2000:]
    assert "1 failed, 1 passed" in output
    assert "x 2 for this machine's load" in output  # the header says what it stretched
    assert took_s < 40  # the child's own start-up included; the hang itself would take 60 s
