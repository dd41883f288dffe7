"""Copies of the shipped patches, edited as data and written as YAML (custom-patch tests)."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from eit_skin.resources import config_path

_EXPONENT = re.compile(r"[-+]?\d+(\.\d*)?[eE][-+]?\d+")

_SMALL_DISC = """\
name: small
frame_id: small_link
layers:
  - name: pressure
    outline: {type: circle, radius: 0.040, center: [0.0, 0.0]}
    electrodes: {count: 16, layout: even, width: 0.004, contact_impedance: 4.0}
    current: 1.0e-4
    material: {quantity: pressure, sheet_conductance: 6.92e-5, pressure_scale: 3.0e4}
    protocol: {drive: adjacent, measure: adjacent}
    mesh: {max_edge: 0.008, electrode_edge: 0.002}
"""


def small_disc_patch(solver: str = "") -> str:
    """A one-layer 40 mm pressure disc (fast meshes) as patch YAML, with ``solver`` a flow
    mapping such as ``"{method: one_step, prior: laplace}"`` (empty: the default solver)."""
    return _SMALL_DISC + (f"    solver: {solver}\n" if solver else "")


def small_disc_data() -> dict:
    """:func:`small_disc_patch` (default solver) as data, to edit before loading."""
    return _numbers(yaml.safe_load(small_disc_patch()))


def shipped_patch_data(name: str) -> dict:
    """A shipped patch file as data (YAML 1.1 reads ``3.0e4`` as a string: made a number)."""
    return _numbers(yaml.safe_load(config_path(name).read_text()))


def _numbers(value):
    """``value`` with exponent strings (``3.0e4``, a string in YAML 1.1) made numbers."""
    if isinstance(value, dict):
        return {k: _numbers(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_numbers(v) for v in value]
    if isinstance(value, str) and _EXPONENT.fullmatch(value):
        return float(value)
    return value


def write_patch(folder: Path, data: dict, stem: str = "custom") -> Path:
    """``data`` as ``folder/<stem>.yaml``."""
    path = folder / f"{stem}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path
