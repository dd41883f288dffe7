"""What every frame source reports: a frame-rate meter and the status for the diagnostics."""

from __future__ import annotations

import time
from dataclasses import dataclass, field


class RateMeter:
    """Frames per second between two queries (O(1) per frame: a counter, monotonic clock).

    ``rate_hz`` reports the rate since the previous query (the first query: since the
    first frame), so with diagnostics every second it is the rate of the last second; a
    query within ``min_window_s`` of the previous one repeats the last value.
    """

    def __init__(self, min_window_s: float = 0.5) -> None:
        self.min_window_ns = int(min_window_s * 1e9)
        self.count = 0
        self._mark: tuple[int, int] | None = None  # (count, monotonic ns) of the last query
        self._rate = 0.0

    def tick(self) -> None:
        if self._mark is None:
            self._mark = (0, time.monotonic_ns())
        self.count += 1

    def rate_hz(self) -> float:
        if self._mark is None:
            return 0.0
        count, then = self._mark
        now = time.monotonic_ns()
        if now - then >= self.min_window_ns:
            self._rate = (self.count - count) / ((now - then) * 1e-9)
            self._mark = (self.count, now)
        return self._rate


@dataclass
class SourceStatus:
    """What a source tells the diagnostics.

    Attributes:
        level: 0 OK, 1 WARN, 2 ERROR (``diagnostic_msgs/DiagnosticStatus`` levels).
        message: one line for humans.
        values: key/value pairs for the diagnostics array.
    """

    level: int
    message: str
    values: dict[str, str] = field(default_factory=dict)
