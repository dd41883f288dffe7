"""Designing a skin: a browser designer and the figures of a design's predicted accuracy.

Modules: ``session`` (one design being edited: patch data in, validated model, mesh and
predicted-accuracy preview out, saved as a patch file with the user's comments kept),
``server`` (the local web server of ``eit-skin design``: aiohttp, plain
HTML/SVG/JS from ``static/``), ``figures`` (PNG maps of ``eit-skin patch --predict``).
The core never imports this subpackage.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "DesignSession": "session",
    "draw_accuracy": "figures",
    "start_server": "server",
}

__all__ = ["DesignSession", "draw_accuracy", "start_server"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

if TYPE_CHECKING:
    from eit_skin.design.figures import draw_accuracy
    from eit_skin.design.server import start_server
    from eit_skin.design.session import DesignSession
