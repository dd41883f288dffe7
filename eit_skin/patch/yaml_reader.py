"""The one YAML reader of the package's input files (patches, scenarios) and its validator.

:func:`read_yaml` parses a file with the YAML 1.2 core schema (``5e-3`` is a float, ``010``
is ten, only ``true``/``false`` are booleans, no dates) and refuses an empty file and a key
written twice in one mapping. :class:`Reader` gives typed access to the parsed data; every
problem becomes a :class:`ConfigError` ``"<file>: <key.path[3].x>: <reason>"`` of the
caller's subclass (``PatchError``, ``ScenarioError``). An unknown key is named together with
the closest known one (a typo does not pass silently, nor hide behind "missing key").
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml


class ConfigError(ValueError):
    """An input file is invalid: ``"<file>: <key path>: <reason>"``.

    Attributes:
        source: the file (or ``"<dict>"`` for in-memory data).
        key_path: where in it, e.g. ``layers[0].electrodes.width``; ``(root)`` for the whole
            document, ``(file)`` for the file itself, ``line L, column C`` for YAML syntax.
        reason: what is wrong.
    """

    def __init__(self, source: str, key_path: str, reason: str) -> None:
        self.source = source
        self.key_path = key_path or "(root)"
        self.reason = reason
        super().__init__(f"{source}: {self.key_path}: {reason}")


# --------------------------------------------------------------------------- parsing


class Yaml12Loader(yaml.SafeLoader):
    """Safe loader with the YAML 1.2 core schema's plain scalars (null, bool, int, float)."""

    def construct_core_int(self, node: yaml.ScalarNode) -> int:
        text = self.construct_scalar(node)
        sign, digits = (-1, text[1:]) if text[0] == "-" else (1, text.lstrip("+"))
        if digits.startswith("0o"):
            return sign * int(digits[2:], 8)
        if digits.startswith("0x"):
            return sign * int(digits[2:], 16)
        return sign * int(digits, 10)  # leading zeros are decimal in YAML 1.2


#: Plain-scalar resolution of the YAML 1.2 core schema (plus merge keys ``<<``):
#: ``(tag, regular expression, possible first characters)``.
_CORE_SCHEMA = (
    ("null", r"~|null|Null|NULL|", ["~", "n", "N", ""]),
    ("bool", r"true|True|TRUE|false|False|FALSE", list("tTfF")),
    ("int", r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+", list("-+0123456789")),
    (
        "float",
        r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)",
        list("-+.0123456789"),
    ),
    ("merge", r"<<", ["<"]),
)


def _install_core_schema(loader: type[yaml.SafeLoader]) -> None:
    loader.yaml_implicit_resolvers = {}  # drop YAML 1.1's (yes/no, 1_000, 1:30, dates, ...)
    for tag, pattern, first in _CORE_SCHEMA:
        loader.add_implicit_resolver(
            f"tag:yaml.org,2002:{tag}", re.compile(f"^(?:{pattern})$"), first
        )
    loader.add_constructor("tag:yaml.org,2002:int", Yaml12Loader.construct_core_int)


_install_core_schema(Yaml12Loader)


def read_yaml(path: str | Path, error: type[ConfigError], list_key: str = "") -> Any:
    """Parse a YAML file (YAML 1.2 core schema); problems raise ``error``.

    Refused: an unreadable or non-UTF-8 file (key path ``(file)``, with the byte offset),
    an empty file (only whitespace or comments), invalid YAML (``line L, column C``) and a
    key repeated in one mapping (its key path, with both lines). ``list_key`` is the key
    path of a document that is a plain list (scenario files: the touches).
    """
    source = str(path)
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except OSError as exc:
        raise error(source, "(file)", exc.strerror or str(exc)) from None
    except UnicodeDecodeError as exc:
        raise error(source, "(file)", f"not UTF-8 text: bad byte at offset {exc.start}") from None
    return read_yaml_text(text, source, error, list_key)


def read_yaml_text(text: str, source: str, error: type[ConfigError], list_key: str = "") -> Any:
    """Parse YAML ``text`` as :func:`read_yaml` parses a file; errors name ``source``."""
    if not text.strip():  # YAML itself would choke on a tab here
        raise error(source, "(file)", "empty file")
    loader = Yaml12Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:  # only comments (or document markers)
            raise error(source, "(file)", "empty file")
        root = list_key if isinstance(node, yaml.SequenceNode) else ""
        _refuse_duplicate_keys(node, root, source, error)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "(yaml)"
        problem = getattr(exc, "problem", None) or str(exc)
        context = getattr(exc, "context", None)
        if context and problem.startswith("but "):  # "expected a single document ..."
            problem = f"{context}, {problem}"
        raise error(source, where, f"invalid YAML: {problem}") from None
    finally:
        loader.dispose()


def _refuse_duplicate_keys(
    root: yaml.Node, path: str, source: str, error: type[ConfigError]
) -> None:
    """Raise ``error`` naming the key path and both lines of the first repeated mapping key."""
    stack, seen_nodes = [(root, path)], set()
    while stack:
        node, where = stack.pop()
        if id(node) in seen_nodes:  # aliases may share (and even contain) nodes
            continue
        seen_nodes.add(id(node))
        children = []
        if isinstance(node, yaml.MappingNode):
            first_line: dict[tuple[str, str], int] = {}
            for key, value in node.value:
                name = key.value if isinstance(key, yaml.ScalarNode) else None
                child = Reader.join(where, name if name is not None else "?")
                if name is not None and name != "<<":
                    line = key.start_mark.line + 1
                    if (key.tag, name) in first_line:
                        raise error(
                            source,
                            child,
                            f"duplicate key: first on line {first_line[key.tag, name]}, "
                            f"again on line {line}",
                        )
                    first_line[key.tag, name] = line
                children.append((value, child))
        elif isinstance(node, yaml.SequenceNode):
            children = [(item, Reader.join(where, i)) for i, item in enumerate(node.value)]
        stack.extend(reversed(children))  # depth first, in document order


# --------------------------------------------------------------------------- validation


_MISSING = object()


def describe(value: Any) -> str:
    """Short description of a parsed YAML value for error messages, e.g. ``a string ('x')``."""
    if value is None:
        return "nothing (null)"
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    for t, name in names.items():
        if type(value) is t:
            return f"{name} ({value!r})"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    return type(value).__name__


class Reader:
    """Typed access to parsed YAML data; errors name the file and the key path.

    Args:
        source: the file the data came from (first part of every message).
        error: the :class:`ConfigError` subclass to raise.
    """

    def __init__(self, source: str, error: type[ConfigError]) -> None:
        self.source = source
        self._error = error

    def error(self, path: str, reason: str) -> ConfigError:
        return self._error(self.source, path, reason)

    @staticmethod
    def join(path: str, key: str | int) -> str:
        if isinstance(key, int):
            return f"{path}[{key}]"
        return f"{path}.{key}" if path else key

    def mapping(
        self,
        value: Any,
        path: str,
        required: tuple[str, ...] = (),
        optional: tuple[str, ...] = (),
        what: str = "",
    ) -> Mapping:
        """``value`` as a mapping with string keys, only the allowed ones, the required present.

        An unknown key is reported first (with the closest allowed key: a misspelt required
        key is a typo, not a missing key). ``what`` (e.g. ``"circle outline"``) names the
        kind of mapping in that message.
        """
        d = self.any_mapping(value, path)
        allowed = (*required, *optional)
        for key in d:
            if key not in allowed:
                raise self.error(self.join(path, key), self._unknown(key, allowed, what))
        for key in required:
            if key not in d:
                raise self.error(self.join(path, key), "missing required key")
        return d

    def any_mapping(self, value: Any, path: str) -> Mapping:
        """``value`` as a mapping with string keys (any keys)."""
        if not isinstance(value, Mapping):
            raise self.error(path, f"expected a mapping, got {describe(value)}")
        for key in value:
            if not isinstance(key, str):
                raise self.error(path, f"keys must be strings, got {key!r}")
        return value

    def variant(
        self,
        value: Any,
        path: str,
        kinds: Mapping[str, tuple[str, ...]],
        what: str,
        key: str = "type",
    ) -> tuple[str, Mapping]:
        """A mapping whose ``key`` (e.g. ``type``) selects its allowed keys ``kinds[kind]``.

        Returns ``(kind, mapping)``; other keys are refused naming the kind (``"circle
        hole"``). While ``key`` itself is missing, an unknown key is matched against the keys
        of every kind (``tpye`` -> ``type``).
        """
        d = self.any_mapping(value, path)
        if key not in d:
            every = tuple(dict.fromkeys(k for keys in kinds.values() for k in keys))
            self.mapping(d, path, required=(key,), optional=every, what=what)
        kind = self.string(d, key, path, choices=tuple(kinds))
        self.mapping(d, path, required=(key,), optional=kinds[kind], what=f"{kind} {what}")
        return kind, d

    @staticmethod
    def _unknown(key: str, allowed: tuple[str, ...], what: str) -> str:
        article = "an" if what[:1] in ("a", "e", "i", "o", "u") else "a"
        head = f"unknown key of {article} {what}" if what else "unknown key"
        close = difflib.get_close_matches(key, allowed, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ";"
        return f"{head}{hint} allowed: {', '.join(sorted(allowed))}"

    def sequence(self, value: Any, path: str, min_len: int = 0) -> list:
        if not isinstance(value, (list, tuple)):
            raise self.error(path, f"expected a list, got {describe(value)}")
        if len(value) < min_len:
            raise self.error(path, f"expected at least {min_len} entries, got {len(value)}")
        return list(value)

    def entry(self, data: Mapping, key: str, path: str, default: Any) -> tuple[str, Any, bool]:
        """``(where, value, present)``: ``data[key]``, else ``default`` (an error without one)."""
        where = self.join(path, key)
        if key not in data:
            if default is _MISSING:
                raise self.error(where, "missing required key")
            return where, default, False
        return where, data[key], True

    def number(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        minimum: float | None = None,
        positive: bool = False,
        allow_none: bool = False,
    ) -> Any:
        """``data[key]`` as a finite float (``default`` if absent; required without one)."""
        where, value, present = self.entry(data, key, path, default)
        if not present:
            return value
        if value is None and allow_none:
            return None
        number = self.as_float(value, where)
        if positive and not number > 0:
            raise self.error(where, f"must be > 0, got {number:g}")
        if minimum is not None and number < minimum:
            raise self.error(where, f"must be >= {minimum:g}, got {number:g}")
        return number

    def as_float(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(where, f"expected a number, got {describe(value)}")
        if not math.isfinite(value):
            raise self.error(where, f"expected a finite number, got {value}")
        return float(value)

    def integer(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        minimum: int | None = None,
    ) -> int:
        where, value, present = self.entry(data, key, path, default)
        if not present:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(where, f"expected an integer, got {describe(value)}")
        if minimum is not None and value < minimum:
            raise self.error(where, f"must be >= {minimum}, got {value}")
        return int(value)

    def string(
        self,
        data: Mapping,
        key: str,
        path: str,
        default: Any = _MISSING,
        choices: tuple[str, ...] | None = None,
    ) -> str:
        where, value, present = self.entry(data, key, path, default)
        if not present:
            return value
        if not isinstance(value, str) or not value:
            raise self.error(where, f"expected a non-empty string, got {describe(value)}")
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, choices, n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise self.error(
                where, f"unknown value {value!r}{hint}; expected one of {', '.join(choices)}"
            )
        return value

    def vector(self, value: Any, where: str, size: int) -> np.ndarray:
        """``[size]`` float array from a list of ``size`` numbers."""
        items = self.sequence(value, where)
        if len(items) != size:
            raise self.error(where, f"expected {size} numbers, got {len(items)}")
        return np.array([self.as_float(v, self.join(where, i)) for i, v in enumerate(items)])

    def points(self, value: Any, where: str, min_len: int) -> np.ndarray:
        """``[n, 2]`` float array from a list of at least ``min_len`` ``[x, y]`` pairs."""
        items = self.sequence(value, where, min_len=min_len)
        return np.array([self.vector(p, self.join(where, i), 2) for i, p in enumerate(items)])
