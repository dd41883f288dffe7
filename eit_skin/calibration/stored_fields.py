"""How a calibration model's fields are named in a calibration file (an npz).

Every model of the file (position, depth, several touches, the physics prior inside the
position model) stores its fields under a prefix, ``<prefix>_<field>``, so that one flat npz
holds them all; a model inside another one takes ``<outer prefix>_<its name>`` as its prefix.
Scalars are stored as 0-d arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np


def stored_fields(prefix: str, **fields: object) -> dict[str, np.ndarray]:
    """``fields`` as the file keeps them: ``{"<prefix>_<name>": array}`` (scalars 0-d)."""
    return {f"{prefix}_{name}": np.asarray(value) for name, value in fields.items()}


def stored_dataclass(
    prefix: str, model: object, skip: tuple[str, ...] = ()
) -> dict[str, np.ndarray]:
    """:func:`stored_fields` of every field of the dataclass instance ``model`` but ``skip``."""
    kept = {f.name: getattr(model, f.name) for f in fields(model) if f.name not in skip}
    return stored_fields(prefix, **kept)


@dataclass(frozen=True)
class StoredFields:
    """The fields a model stored under ``prefix`` in a calibration file's ``arrays``.

    ``fields[name]`` is the array (a missing one raises ``KeyError`` naming the file's key),
    ``fields.value(name)`` a scalar as float, ``fields.get(name)`` None when absent.
    """

    arrays: Mapping[str, np.ndarray]
    prefix: str

    def key(self, name: str) -> str:
        return f"{self.prefix}_{name}"

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[self.key(name)]

    def value(self, name: str) -> float:
        return float(self[name])

    def get(self, name: str) -> np.ndarray | None:
        return self.arrays.get(self.key(name))

    def dataclass(self, cls: type, skip: tuple[str, ...] = ()):
        """An instance of the dataclass ``cls`` from its stored fields.

        Fields annotated ``float`` are read as floats; ``skip``: fields left to their defaults.
        """
        kwargs = {
            f.name: self.value(f.name) if f.type in ("float", float) else self[f.name]
            for f in fields(cls)
            if f.name not in skip
        }
        return cls(**kwargs)
