"""ruff (lint + format) over the whole repository, as the ament linters would."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

RUFF = Path(sys.executable).with_name("ruff")


def test_ruff_check(repo: Path) -> None:
    result = subprocess.run(
        [RUFF, "check", "--no-cache", "."], cwd=repo, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format(repo: Path) -> None:
    result = subprocess.run(
        [RUFF, "format", "--check", "--no-cache", "."], cwd=repo, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stdout + result.stderr
