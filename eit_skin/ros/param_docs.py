"""The parameter tables of docs/nodes.md, written from the nodes' parameter descriptors.

``python -m eit_skin.ros.param_docs`` rewrites, in docs/nodes.md, the text between
``<!-- parameters: <executable> -->`` and ``<!-- end parameters -->`` with a table made from
:data:`eit_skin.ros.parameters.NODE_PARAMETERS` (the descriptors the nodes declare);
``--check`` only says whether the page is up to date (exit 1 when it is not).
No rclpy needed.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from eit_skin.ros.parameters import NODE_PARAMETERS, WRITABLE, format_default

DOCS_PAGE = Path(__file__).resolve().parents[2] / "docs" / "nodes.md"
"""docs/nodes.md of the checkout."""

_BLOCK = re.compile(r"(<!-- parameters: (\w+) -->\n)(.*?)(<!-- end parameters -->)", re.DOTALL)


def parameter_table(executable: str) -> str:
    """A Markdown table of a node's parameters, one row per descriptor.

    Columns: name, type, default, live (writable while running with its bounds, or
    read-only), meaning.
    """
    writable = WRITABLE[executable]
    rows = ["| parameter | type | default | live | meaning |", "|---|---|---|---|---|"]
    for name, default, description in NODE_PARAMETERS[executable]:
        kind = "double[]" if isinstance(default, (list, tuple)) else type(default).__name__
        meaning = description.replace("|", "\\|")
        live = f"writable {writable[name].bounds_text()}" if name in writable else "read-only"
        rows.append(f"| `{name}` | {kind} | `{format_default(default)}` | {live} | {meaning} |")
    return "\n".join(rows) + "\n"


def render(text: str) -> str:
    """``text`` (docs/nodes.md) with every parameter block regenerated.

    Raises:
        ValueError: a block names an unknown executable, or a node has no block.
    """
    seen: set[str] = set()

    def block(match: re.Match) -> str:
        executable = match.group(2)
        if executable not in NODE_PARAMETERS:
            raise ValueError(f"docs/nodes.md: no node {executable!r} (known: {NODE_PARAMETERS})")
        seen.add(executable)
        return match.group(1) + parameter_table(executable) + match.group(4)

    rendered = _BLOCK.sub(block, text)
    missing = sorted(set(NODE_PARAMETERS) - seen)
    if missing:
        raise ValueError(f"docs/nodes.md: no '<!-- parameters: NAME -->' block for {missing}")
    return rendered


def main(argv: list[str] | None = None) -> int:
    """Rewrite the page (exit 0), or with ``--check`` exit 1 when it is out of date."""
    parser = argparse.ArgumentParser(prog="python -m eit_skin.ros.param_docs")
    parser.add_argument("--check", action="store_true", help="only check, write nothing")
    parser.add_argument("--page", type=Path, default=DOCS_PAGE, help="the page (docs/nodes.md)")
    args = parser.parse_args(argv)
    text = args.page.read_text()
    rendered = render(text)
    if args.check:
        if rendered != text:
            print(f"{args.page} is out of date: run python -m eit_skin.ros.param_docs")
            return 1
        return 0
    args.page.write_text(rendered)
    return 0


if __name__ == "__main__":
    sys.exit(main())
