"""The options several ``eit-skin`` commands share, spelt once: a patch, its layer, a board's link.

A command that names a patch takes ``--patch`` (a shipped name or a YAML path) and, where it
works on one layer, ``--layer`` (default: the patch's first); :func:`chosen_layer` loads both
the same way everywhere. A command that reads a board takes ``--baud`` and ``--wait``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from eit_skin.patch.model import Layer, Patch

PATCH_HELP = "patch: a shipped name (arm, face, elbow) or a YAML path"
LAYER_HELP = "layer name (default: the patch's first layer)"


def add_patch_options(
    parser: argparse.ArgumentParser, default: str | None = None, layer: bool = True
) -> None:
    """``--patch`` (required unless it has a ``default``) and, with ``layer``, ``--layer``."""
    if default is None:
        parser.add_argument("--patch", required=True, help=PATCH_HELP)
    else:
        parser.add_argument("--patch", default=default, help=f"{PATCH_HELP} (default: {default})")
    if layer:
        parser.add_argument("--layer", default="", help=LAYER_HELP)


def chosen_layer(args: argparse.Namespace) -> tuple[Patch, Layer]:
    """The patch ``--patch`` names, loaded and validated, and its ``--layer``.

    Raises:
        PatchError: the file is missing or invalid (the message names the file and field).
        KeyError: the patch has no such layer (the message lists its layers).
    """
    from eit_skin.patch.loading import load_patch
    from eit_skin.resources import config_path

    patch = load_patch(config_path(args.patch))
    return patch, patch.layer(args.layer)


def add_write_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--write``: the command stores ``what`` in the patch file (see :func:`patch_file`)."""
    parser.add_argument(
        "--write", action="store_true", help=f"store {what} in the patch file (a copy's path)"
    )


def patch_file(args: argparse.Namespace) -> Path:
    """The file ``--patch`` names: an existing path as given, else a shipped config.

    Raises:
        ValueError: ``--write`` and the name resolved to a shipped config (never written by
            name: the user writes a copy).
    """
    path = Path(args.patch)
    if path.exists():
        return path
    from eit_skin.resources import config_path

    resolved = config_path(args.patch)
    if getattr(args, "write", False) and resolved != path:
        raise ValueError(
            f"{args.patch}: a shipped config is never written by name; "
            "copy it and give the copy's path"
        )
    return resolved


def add_max_touches_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--max-touches K``: up to K simultaneous touches (default 1: one at a time)."""
    parser.add_argument("--max-touches", type=int, default=1, metavar="K", help=help_text)


def add_board_link_options(parser: argparse.ArgumentParser) -> None:
    """``--baud`` and ``--wait`` of a command that reads a board on a serial port."""
    parser.add_argument("--baud", type=int, default=0, help="bit/s (0: the board profile's)")
    parser.add_argument(
        "--wait",
        type=float,
        default=10.0,
        metavar="S",
        help="give up when no frame came within S seconds (default 10)",
    )
