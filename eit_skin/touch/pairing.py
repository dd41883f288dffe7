"""Pairs a patch's pressure and stretch images by acquisition stamp, boards or not.

On one board both layers' frames carry the same stamp; on two boards (one per layer) each
board's clock is mapped to ROS time on its own, so the stamps of a pressure image and the
stretch image of the same moment differ by up to half a frame period. Like message_filters'
ApproximateTime policy, a pressure image is paired with the stretch image nearest in stamp
within ``slop_ns``; a pressure image still without a partner ``timeout_ns`` after the newest
pressure stamp goes on alone. Stamps: integer nanoseconds.
"""

from __future__ import annotations

from typing import Generic, TypeVar

Item = TypeVar("Item")
Other = TypeVar("Other")

KEEP = 20
"""Unpaired stretch images kept (the oldest go first)."""
MAX_PENDING = 10
"""Pressure images waiting at most; beyond that the oldest goes on alone."""


class StampPairer(Generic[Item, Other]):
    """Pressure items (any payload) paired with the stretch item nearest in stamp.

    Every method returns the pressure items now ready, oldest first, each with its stretch
    partner or None.
    """

    def __init__(self, slop_ns: int, timeout_ns: int) -> None:
        self.slop_ns = int(slop_ns)
        self.timeout_ns = int(timeout_ns)
        self.pending: dict[int, Item] = {}
        self.stretch: dict[int, Other] = {}
        self.unpaired = 0

    def push_pressure(self, stamp: int, item: Item) -> list[tuple[Item, Other | None]]:
        """A pressure item: paired at once when a stretch item is within the slop."""
        match = _nearest(self.stretch, stamp, self.slop_ns)
        if match is not None:
            return [(item, self.stretch.pop(match))]
        self.pending[stamp] = item
        return []

    def push_stretch(self, stamp: int, other: Other) -> list[tuple[Item, Other | None]]:
        """A stretch item: pairs a waiting pressure item within the slop, else is kept."""
        match = _nearest(self.pending, stamp, self.slop_ns)
        if match is not None:
            return [(self.pending.pop(match), other)]
        self.stretch[stamp] = other
        while len(self.stretch) > KEEP:
            self.stretch.pop(min(self.stretch))
        return []

    def flush(self) -> list[tuple[Item, Other | None]]:
        """Pressure items waited on for ``timeout_ns`` (or too many): they go on alone."""
        if not self.pending:
            return []
        newest = max(self.pending)
        ready = []
        for stamp in sorted(self.pending):
            if newest - stamp >= self.timeout_ns or len(self.pending) > MAX_PENDING:
                ready.append((self.pending.pop(stamp), None))
                self.unpaired += 1
        return ready


def _nearest(items: dict[int, object], stamp: int, slop_ns: int) -> int | None:
    """The key of ``items`` nearest to ``stamp`` within ``slop_ns``, or None."""
    best = min(items, key=lambda key: abs(key - stamp), default=None)
    return best if best is not None and abs(best - stamp) <= slop_ns else None
