"""Writing patch files: new ones, and edits that keep the comments the user wrote.

Reading stays with the one reader (:mod:`eit_skin.patch.yaml_reader`); this module only
writes, with ``ruamel.yaml``'s round-trip mode: :func:`updated_text` loads the original
text with its comments and formatting, changes only the values that differ from the new
data (keys removed from the data are removed, new ones appended) and dumps it again, so an
unchanged patch comes back as the same text. :func:`new_text` writes fresh data with short
lists (points, positions) in flow style and a header comment.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any


def _yaml() -> Any:
    from ruamel.yaml import YAML

    yaml = YAML(typ="rt")
    yaml.indent(mapping=2, sequence=4, offset=2)
    yaml.width = 100
    yaml.preserve_quotes = True
    return yaml


def new_text(data: Mapping[str, Any], header: str = "") -> str:
    """YAML text of plain patch ``data`` (dicts, lists, numbers, strings).

    ``header``: comment lines on top.
    """
    from ruamel.yaml.comments import CommentedMap

    document = _commented(data)
    if header and isinstance(document, CommentedMap):
        document.yaml_set_start_comment(header)
    out = io.StringIO()
    _yaml().dump(document, out)
    return out.getvalue()


def updated_text(original: str, data: Mapping[str, Any]) -> str:
    """``original`` YAML text with its values replaced by ``data``'s, comments kept.

    Unchanged data gives back ``original`` itself (ruamel re-wraps long flow lists).
    """
    yaml = _yaml()
    document = yaml.load(original)
    if not isinstance(document, Mapping):
        return new_text(data)
    if _same(document, data):
        return original
    _merge(document, data)
    out = io.StringIO()
    yaml.dump(document, out)
    return out.getvalue()


def _commented(value: Any) -> Any:
    """Plain data -> ruamel nodes; lists of numbers (and of number pairs) in flow style."""
    from ruamel.yaml.comments import CommentedMap, CommentedSeq

    if isinstance(value, Mapping):
        out = CommentedMap()
        for k, v in value.items():
            out[k] = _commented(v)
        short = all(not isinstance(v, (Mapping, list, tuple)) for v in value.values())
        if short and len(value) <= 4:
            out.fa.set_flow_style()
        return out
    if isinstance(value, (list, tuple)):
        seq = CommentedSeq(_commented(v) for v in value)
        if all(_is_number(v) for v in value):
            seq.fa.set_flow_style()
        return seq
    return value


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _same(old: Any, new: Any) -> bool:
    """Equal as data (a ruamel node compared with plain values; 1 and 1.0 are equal)."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        return old.keys() == new.keys() and all(_same(old[k], new[k]) for k in new)
    if _is_sequence(old) and _is_sequence(new):
        return len(old) == len(new) and all(_same(a, b) for a, b in zip(old, new, strict=True))
    if _is_number(old) and _is_number(new):
        return float(old) == float(new)
    return (type(old) is type(new) and old == new) or (_both_str(old, new) and str(old) == str(new))


def _both_str(a: Any, b: Any) -> bool:
    return isinstance(a, str) and isinstance(b, str)


def _is_sequence(value: Any) -> bool:
    return isinstance(value, Sequence) and not isinstance(value, str)


def _merge(node: Any, new: Mapping[str, Any]) -> None:
    """Make the round-trip mapping ``node`` equal ``new`` in place, touching only changes."""
    for key in [k for k in node if k not in new]:
        del node[key]
    for key, value in new.items():
        if key in node and _same(node[key], value):
            continue
        _merge_entry(node, key, node.get(key), value)


def _merge_list(node: Any, new: Sequence[Any]) -> None:
    for i, value in enumerate(new):
        if not _same(node[i], value):
            _merge_entry(node, i, node[i], value)


def _merge_entry(node: Any, slot: str | int, old: Any, value: Any) -> None:
    """Make ``node[slot]`` (now ``old``) equal ``value``: merged into ``old`` where it can be."""
    if isinstance(old, Mapping) and isinstance(value, Mapping):
        _merge(old, value)
    elif _is_sequence(old) and _is_sequence(value) and len(old) == len(value):
        _merge_list(old, value)
    else:
        node[slot] = _styled_like(old, value)


def _styled_like(old: Any, value: Any) -> Any:
    """``value`` as a ruamel node, in flow style where ``old`` was."""
    node = _commented(value)
    flow = getattr(getattr(old, "fa", None), "flow_style", lambda: None)()
    if flow and hasattr(node, "fa"):
        node.fa.set_flow_style()
    return node
