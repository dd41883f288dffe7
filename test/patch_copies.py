"""Copies of the shipped patches, edited as data and written as YAML (custom-patch tests)."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from eit_skin.resources import config_path

_EXPONENT = re.compile(r"[-+]?\d+(\.\d*)?[eE][-+]?\d+")


def shipped_patch_data(name: str) -> dict:
    """A shipped patch file as data (YAML 1.1 reads ``3.0e4`` as a string: made a number)."""

    def numbers(value):
        if isinstance(value, dict):
            return {k: numbers(v) for k, v in value.items()}
        if isinstance(value, list):
            return [numbers(v) for v in value]
        if isinstance(value, str) and _EXPONENT.fullmatch(value):
            return float(value)
        return value

    return numbers(yaml.safe_load(config_path(name).read_text()))


def write_patch(folder: Path, data: dict, stem: str = "custom") -> Path:
    """``data`` as ``folder/<stem>.yaml``."""
    path = folder / f"{stem}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path
