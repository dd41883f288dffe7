"""Designing a skin: the figures of a design's predicted accuracy.

Modules: ``figures`` (PNG maps of ``eit-skin patch --predict``). The core never imports this
subpackage.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "draw_accuracy": "figures",
}

__all__ = ["draw_accuracy"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

if TYPE_CHECKING:
    from eit_skin.design.figures import draw_accuracy
