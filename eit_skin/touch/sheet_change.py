"""After a withdrawn touch (a changed sheet): is the sheet still again?

A "touch" that goes on for longer than ``sheet_change_taus`` baseline time constants is the
sheet changing, not a touch (:class:`~eit_skin.touch.classifier.TouchClassifier` withdraws
it; why: docs/classifier.md, "Changed sheet"). The classifier then starts no touch until the
sheet has stayed still over a whole window, and calibrates again after it. Still: the change
from the window's first to its last averaged image holds no contact standing out against the
noise the sheet had at rest before it changed. A window the sheet moved in is followed by one
as long as the sheet has been changing so far (a long hold needs one window; a sheet that
keeps changing, ever longer ones). Only the window's first and latest images are kept.
"""

from __future__ import annotations

import numpy as np

from eit_skin.touch.background import Background


class StillnessWindow:
    """Windows of frames after a sheet change, until the sheet stayed still over one.

    Args:
        at_rest: the background the classifier had before the sheet changed (its noise map
            and START bar judge a window).
        changed_s: when the sheet began to change (the withdrawn touch's START), s.
        window_s: length of the first window, s (the withdrawal's bound).
        average_frames: frames per averaged image (``average_frames``).
    """

    def __init__(
        self, at_rest: Background, changed_s: float, window_s: float, average_frames: int
    ) -> None:
        self.at_rest = at_rest
        self.changed_s = changed_s
        self.window_s = window_s
        self.average_frames = max(int(average_frames), 1)
        self._start_s: float | None = None
        self._first: list[np.ndarray] = []  # the window's first average_frames images
        self._latest: list[np.ndarray] = []  # its latest average_frames images

    def still(self, t_s: float, pressure: np.ndarray) -> bool:
        """Add the image ``pressure`` ``[H, W]`` Pa at ``t_s``; True once a window was still."""
        if self._start_s is None:
            self._start_s, self._first, self._latest = t_s, [], []
        if len(self._first) < self.average_frames:
            self._first.append(pressure)
        self._latest = [*self._latest[-(self.average_frames - 1) :], pressure]
        if self.average_frames == 1:
            self._latest = [pressure]
        if t_s - self._start_s + 1e-9 < self.window_s:
            return False
        change = np.mean(self._latest, axis=0) - np.mean(self._first, axis=0)
        at_rest = self.at_rest
        contacts, parts = at_rest.segmenter.segment_with_labels(change - at_rest.offset(change))
        if contacts and at_rest.stands_out(change, parts > 0):  # moved: a longer window
            self.window_s = max(t_s - self.changed_s, self.window_s)
            self._start_s = None
            return False
        return True
