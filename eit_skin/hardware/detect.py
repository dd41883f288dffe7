"""Which board profile a port's bytes belong to (``eit-skin detect``): "connected, but no image".

:func:`recognise` reads bytes a board sent unasked and names the profile whose format they
follow: eit_skin's wire frames (a CRC-valid frame), OpenEIT (``magnitudes:`` lines) or a
line-printing board (lines of numbers), with the numbers per frame and frames per second.
A Sciospec sends nothing until the host starts it: :data:`SCIOSPEC_PROBE` (a stop command,
harmless to a stopped or running device) is answered by an acknowledgement message, which
:func:`is_sciospec_answer` recognises. Which patch fits and how one frame compares with its
model is the command's (``eit_skin.cli.detect``).
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass

import numpy as np

from eit_skin.hardware.boards import LINE_LABEL
from eit_skin.hardware.sciospec import STOP, SYSTEM_TAG
from eit_skin.hardware.wire import FrameParser
from eit_skin.patch.device import OPENEIT_ELECTRODES

SCIOSPEC_PROBE = STOP
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^nan$|^[-+]?inf$", re.I)
_SEPARATORS = re.compile(r"[,; \t]+")


@dataclass(frozen=True)
class Recognised:
    """What a port sent.

    Attributes:
        profile: the board profile (``eit_skin``, ``openeit``, ``lines``).
        values_per_frame: numbers in one frame.
        frames: complete frames seen.
        frames_per_s: frames per second over the listening time.
        detail: e.g. the separators and label of a line-printing board, the header of a
            wire frame.
        last_frame: ``[values_per_frame]`` the last frame's numbers.
    """

    profile: str
    values_per_frame: int
    frames: int
    frames_per_s: float
    detail: str
    last_frame: np.ndarray


def recognise(data: bytes, seconds: float) -> Recognised | None:
    """The profile whose frames make up ``data`` (read over ``seconds``), or None."""
    parser = FrameParser()
    frames = parser.feed(data)
    if frames:
        last = frames[-1]
        return Recognised(
            "eit_skin",
            last.n_values,
            len(frames),
            len(frames) / seconds,
            f"{last.n_electrodes} electrodes, pattern {last.pattern_id.name.lower()}",
            last.voltages_v,
        )
    lines = [line.strip() for line in re.split(rb"\r\n|\r|\n", data)[1:-1]]  # whole lines
    magnitudes = [line for line in lines if line.startswith(b"magnitudes:")]
    if magnitudes:
        values = [_numbers(line.split(b":", 1)[1].decode("latin-1")) for line in magnitudes]
        counts = Counter(len(v) for v in values if v is not None)
        if counts:
            count = counts.most_common(1)[0][0]
            last = next(v for v in reversed(values) if v is not None and len(v) == count)
            n = {k * (k - 4): k for k in OPENEIT_ELECTRODES}.get(count)
            mode = f"{n}-electrode imaging" if n else "an unknown mode"
            return Recognised(
                "openeit", count, counts[count], counts[count] / seconds, mode, np.array(last)
            )
    numeric = []
    for line in lines:
        text = line.decode("latin-1")
        label = LINE_LABEL.match(text)
        values = _numbers(text[label.end() :] if label else text)
        if values is not None and len(values) > 1:
            numeric.append((values, label.group(0) if label else "", text))
    if numeric:
        counts = Counter(len(v) for v, _, _ in numeric)
        count = counts.most_common(1)[0][0]
        values, label, text = next(item for item in reversed(numeric) if len(item[0]) == count)
        separators = "".join(sorted(set(_SEPARATORS.findall(text)[0]))) if count > 1 else ","
        zeros = int(np.sum(np.array(values) == 0))
        detail = f"separators {separators!r}" + (f", label {label!r}" if label else "")
        detail += f", {zeros} zeros per frame" if zeros else ""
        return Recognised(
            "lines", count, counts[count], counts[count] / seconds, detail, np.array(values)
        )
    return None


def _numbers(text: str) -> list[float] | None:
    tokens = [t for t in _SEPARATORS.split(text.strip(" ,;\t")) if t]
    if not tokens or not all(_NUMBER.match(t) for t in tokens):
        return None
    return [float(t) for t in tokens]


def is_sciospec_answer(data: bytes) -> bool:
    """Whether ``data`` holds a Sciospec system message (``18 01 xx 18``)."""
    return any(
        data[i] == SYSTEM_TAG and data[i + 1] == 1 and data[i + 3] == SYSTEM_TAG
        for i in range(len(data) - 3)
    )
