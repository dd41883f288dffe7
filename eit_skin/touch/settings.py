"""Settings declared once: type, default, bounds, unit and description of a config field.

A frozen config dataclass declares each field with :func:`setting` (default, unit, bounds as
the docs show them, description); from that one
declaration come its range check (:func:`check_settings`, called by ``__post_init__``), the
node parameters of ``eit_classifier`` and their table in docs/nodes.md
(:func:`declared_settings`, :meth:`Setting.parameter_text`), and a config from parameter
values (:func:`settings_from`). A field whose type is itself such a dataclass (a nested
config) contributes its settings under their own names.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

_KEY = "eit_skin.setting"


@dataclass(frozen=True)
class Setting:
    """One declared setting.

    Attributes:
        name: field name (also the node parameter's name).
        default: default value; its type (bool, int, float, str) is the setting's type.
        description: what it is and why, one or two sentences (no history: docs/classifier.md).
        unit: SI unit or unit of measure (``"s"``, ``"single-finger spreads"``), or "".
        low, high: bounds, or None.
        low_open, high_open: whether a bound is excluded (``> low`` rather than ``>= low``).
        node: whether the node offers it as a parameter (False: the node cannot honour it).
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    node: bool = True

    @property
    def kind(self) -> type:
        """The setting's type: that of its default."""
        return type(self.default)

    def bounds_text(self) -> str:
        """The allowed range: ``"> 0"``, ``">= 1"``, ``"(0, 1]"``, or "" when unbounded."""
        lo, hi = self.low, self.high
        if lo is not None and hi is not None:
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f"{left}{lo:g}, {hi:g}{right}"
        if lo is not None:
            return f"{'>' if self.low_open else '>='} {lo:g}"
        if hi is not None:
            return f"{'<' if self.high_open else '<='} {hi:g}"
        return ""

    def check(self, value: Any) -> None:
        """Raise ValueError naming the setting when ``value`` is out of its bounds (or NaN)."""
        lo, hi = self.low, self.high
        ok = not (isinstance(value, float) and math.isnan(value))
        if lo is not None:
            ok = ok and (value > lo if self.low_open else value >= lo)
        if hi is not None:
            ok = ok and (value < hi if self.high_open else value <= hi)
        if not ok:
            bounds = self.bounds_text()
            where = f"in {bounds}" if lo is not None and hi is not None else bounds
            raise ValueError(f"{self.name} must be {where}, got {value}")

    def parameter_text(self) -> str:
        """The node parameter's description: meaning, unit and range."""
        return "; ".join(part for part in (self.description, self.unit, self.bounds_text()) if part)


_BOUND = r"(-?[0-9.]+(?:e-?[0-9]+)?)"
_ONE_SIDED = re.compile(rf"^(>=|>|<=|<) {_BOUND}$")
_INTERVAL = re.compile(rf"^([\[(]){_BOUND}, {_BOUND}([\])])$")


def setting(default: Any, unit: str, bounds: str, description: str, *, node: bool = True) -> Any:
    """A dataclass field declaring a :class:`Setting`.

    Args:
        default: default value (its type is the setting's).
        unit: unit of measure, or "".
        bounds: the allowed range as the docs show it: ``"> 0"``, ``">= 1"``, ``"(0, 1]"``.
        description: what it is and why, one or two sentences.
        node: False when the node cannot honour it (no node parameter).

    Raises:
        ValueError: ``bounds`` is not one of those forms.
    """
    low = high = None
    low_open = high_open = False
    if match := _ONE_SIDED.match(bounds):
        op, value = match.group(1), float(match.group(2))
        if op.startswith(">"):
            low, low_open = value, op == ">"
        else:
            high, high_open = value, op == "<"
    elif match := _INTERVAL.match(bounds):
        low, high = float(match.group(2)), float(match.group(3))
        low_open, high_open = match.group(1) == "(", match.group(4) == ")"
    else:
        raise ValueError(f"bounds {bounds!r}: expected '> x', '>= x', '< x', '<= x' or '(a, b]'")
    meta = {
        "default": default,
        "description": description,
        "unit": unit,
        "low": low,
        "high": high,
        "low_open": low_open,
        "high_open": high_open,
        "node": node,
    }
    return dataclasses.field(default=default, metadata={_KEY: meta})


def declared_settings(config: Any) -> list[Setting]:
    """Every setting of a config dataclass (class or instance), nested configs flattened.

    Nested configs come in the place of their field; a field without :func:`setting` is
    left out unless it holds a config.
    """
    cls = config if isinstance(config, type) else type(config)
    found: list[Setting] = []
    for f in dataclasses.fields(cls):
        if _KEY in f.metadata:
            found.append(Setting(f.name, **f.metadata[_KEY]))
        elif f.default_factory is not dataclasses.MISSING:
            nested = f.default_factory()
            if dataclasses.is_dataclass(nested):
                found += declared_settings(nested)
    return found


def check_settings(config: Any) -> None:
    """Check every setting declared directly on ``config`` (nested configs check themselves).

    Raises:
        ValueError: the first value out of its bounds, naming the setting.
    """
    for f in dataclasses.fields(config):
        if _KEY in f.metadata:
            Setting(f.name, **f.metadata[_KEY]).check(getattr(config, f.name))


def settings_from(cls: type, values: Mapping[str, Any]) -> Any:
    """An instance of config dataclass ``cls`` with ``values`` (setting name -> value).

    Values are converted to each setting's type; settings not in ``values`` keep their
    defaults; nested configs are built from the same mapping.

    Raises:
        ValueError: a value out of its bounds (the config's own check).
    """
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if _KEY in f.metadata:
            if f.name in values:
                kwargs[f.name] = type(f.metadata[_KEY]["default"])(values[f.name])
        elif f.default_factory is not dataclasses.MISSING:
            nested = f.default_factory()
            if dataclasses.is_dataclass(nested):
                kwargs[f.name] = settings_from(type(nested), values)
    return cls(**kwargs)


def setting_values(config: Any) -> dict[str, Any]:
    """Setting name -> value of a config instance, nested configs flattened.

    The inverse of :func:`settings_from`.
    """
    values: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            values.update(setting_values(value))
        else:
            values[f.name] = value
    return values
