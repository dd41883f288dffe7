"""Board profiles: a real board's bytes -> the layer's frames, and the host's commands to it.

One reader per byte format, all with one shape (:class:`BoardReader`): ``feed(bytes)`` returns
the :class:`BoardFrame` s its bytes completed (the board's numbers in the layer's device-frame
layout, for :meth:`~eit_skin.patch.protocol.Protocol.select`), ``commands(now)`` the bytes the
host must write now (a mode line or a setup on every connect, again after ``ack_timeout_s``
without an answer), ``farewell()`` the bytes that stop the board. A frame the reader cannot
use is counted under one reason (:attr:`BoardReader.refused`) and never returned; the one line
naming the last one (with the stream's byte offset) goes to the diagnostics.

The profile names and options are the patch schema's (:mod:`eit_skin.patch.device`); the
measurement order is the layer's protocol's (:mod:`eit_skin.patch.protocol`): no reader keeps
a copy of it. docs/boards.md describes each board and cites the code each format was read from.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from eit_skin.frames import FLAG_INVALID
from eit_skin.hardware.wire import DeviceFrame, FrameParser
from eit_skin.patch.device import OPENEIT_ELECTRODES, DeviceSpec
from eit_skin.patch.protocol import Protocol


@dataclass(frozen=True, eq=False)
class BoardFrame:
    """One drive cycle as a board sent it.

    Attributes:
        values: ``[W]`` float64 or complex128: the board's numbers in the layer's device frame
            layout (``W`` = ``protocol.frame_size``, or ``M`` in protocol order), volts.
        flags: ``[W]`` uint8 FLAG_* bits (FLAG_INVALID where a value is not finite).
        device_time_us: the board's clock at acquisition, microseconds; None: the board sends
            no clock and the frame is stamped with its arrival time on the host.
        sequence: the board's frame counter, or None (the host counts).
        current_a: the injected current the board reports, or None (the layer's).
    """

    values: np.ndarray
    flags: np.ndarray
    device_time_us: int | None = None
    sequence: int | None = None
    current_a: float | None = None


def invalid_flags(values: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(values), 0, FLAG_INVALID).astype(np.uint8)


@dataclass
class ReaderStats:
    """Counters of a reader: every byte fed is a frame's, discarded, or still buffered.

    Attributes:
        bytes: bytes fed.
        frames: frames returned.
        discarded_bytes: bytes of refused frames and of input that forms no frame.
        refused: frames refused, per reason.
        messages: board messages that are not frames (banners, mode lines, acknowledgements).
        restarts: times the board was seen to start again (banner, clock running back).
    """

    bytes: int = 0
    frames: int = 0
    discarded_bytes: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    messages: int = 0
    restarts: int = 0

    @property
    def errors(self) -> int:
        """Frames refused, all reasons."""
        return sum(self.refused.values())


class BoardReader:
    """Base of every profile's reader (see the module docstring).

    Args:
        protocol: the layer's protocol (value counts, layouts, electrode numbering).
        device: the layer's ``device`` section.
        layer: the layer's name, for messages.
    """

    profile = ""
    REASONS: tuple[str, ...] = ()
    #: what a working board sends, for the ERROR diagnostic when it does not
    EXPECTING = "frames"

    def __init__(self, protocol: Protocol, device: DeviceSpec, layer: str) -> None:
        self.protocol = protocol
        self.device = device
        self.layer = layer
        self.stats = ReaderStats(refused=dict.fromkeys(self.REASONS, 0))
        self.last_refusal = ""
        self.acknowledged = False
        self.attempts = 0
        self._sent_at: float | None = None
        self._recent = b""

    @property
    def ack_timeout_s(self) -> float:
        try:
            return float(self.device.get("ack_timeout_s"))
        except KeyError:
            return 0.0

    def reset(self) -> None:
        """A (re)connect: drop partial input; the host's commands are due again.

        The board has not answered yet (a good frame or an acknowledgement answers).
        """
        self._sent_at = None
        self.attempts = 0
        self.acknowledged = False

    def feed(self, data: bytes) -> list[BoardFrame]:
        raise NotImplementedError

    def greeting(self) -> bytes:
        """What the host writes on connect (b'' for a board that just streams)."""
        return b""

    def farewell(self) -> bytes:
        """What the host writes before it closes the port (b'': nothing)."""
        return b""

    def commands(self, now_s: float) -> bytes:
        """Bytes to write now: the greeting on connect, again each ``ack_timeout_s`` unanswered."""
        if self.acknowledged or self.ack_timeout_s <= 0:
            return b""
        if self._sent_at is not None and now_s - self._sent_at < self.ack_timeout_s:
            return b""
        self._sent_at = now_s
        self.attempts += 1
        return self.greeting()

    def unanswered(self, now_s: float) -> str:
        """One line for an ERROR diagnostic: the board has not answered the host, else ''.

        Said once ``ack_timeout_s`` has passed since the host's commands without an answer.
        """
        if self.acknowledged or self._sent_at is None or self.attempts < 2:
            return ""  # answered, or the first ack_timeout_s has not passed
        seen = repr(self._recent) if self._recent else "nothing"
        refusal = f"; last refused: {self.last_refusal}" if self.last_refusal else ""
        return (
            f"profile {self.profile}: no answer ({self.EXPECTING}) after {self.attempts} "
            f"tries of {self.ack_timeout_s:g} s; saw {seen}{refusal}"
        )

    def _seen(self, data: bytes, start: bool = True) -> None:
        """Keep the first 80 bytes of the latest input that formed no frame (diagnostics).

        ``start``: a new run of such input begins with ``data``.
        """
        self._recent = (data if start else self._recent + data)[:80]

    def _refuse(self, reason: str, message: str, n_bytes: int) -> None:
        self.stats.refused[reason] += 1
        self.stats.discarded_bytes += n_bytes
        self.last_refusal = message


class WireReader(BoardReader):
    """eit_skin's own binary wire protocol (docs/wire-protocol.md).

    ``check(frame)`` (:meth:`~eit_skin.hardware.sources.LayerFrameFactory.reject`) names why a
    decoded frame is not the layer's: ``(reason, line)`` or None.
    """

    profile = "eit_skin"
    REASONS = ("values", "electrodes", "pattern", "current")

    def __init__(
        self,
        protocol: Protocol,
        device: DeviceSpec,
        layer: str,
        check: Callable[[DeviceFrame], tuple[str, str] | None],
    ) -> None:
        super().__init__(protocol, device, layer)
        self.parser = FrameParser()
        self.check = check

    def reset(self) -> None:
        super().reset()
        self.parser.reset()

    def feed(self, data: bytes) -> list[BoardFrame]:
        self.stats.bytes += len(data)
        out = []
        for frame in self.parser.feed(data):
            rejection = self.check(frame)
            if rejection is not None:
                self.stats.refused[rejection[0]] += 1
                self.last_refusal = rejection[1]
                continue
            out.append(
                BoardFrame(
                    frame.voltages_v,
                    frame.flags,
                    frame.device_time_us,
                    frame.sequence,
                    frame.current_a,
                )
            )
        self.acknowledged = self.acknowledged or bool(out)
        parser = self.parser.stats
        self.stats.frames += len(out)
        self.stats.discarded_bytes = parser.discarded_bytes
        return out


_LINE_END = re.compile(rb"\r\n|\r|\n")
LINE_LABEL = re.compile(r"^\s*[A-Za-z_][\w .-]*:")
"""A ``label:`` before a line's numbers (a word, then a colon)."""


@dataclass(frozen=True)
class TextLines:
    """What a good frame line of a text board holds.

    Attributes:
        expected: numbers per line.
        separators: characters between numbers (besides whitespace).
        prefix: the word before the numbers ('' for none).
        volts_per_unit: volts per printed unit.
        start_command: the line the host sends on connect ('' for none).
    """

    expected: int
    separators: str
    prefix: str
    volts_per_unit: float
    start_command: str = ""


class TextLineReader(BoardReader):
    """One frame per text line: ``[label:] v1 <sep> v2 <sep> ... vN [<sep>]`` + CR, LF or CRLF.

    Separators are any mix of the given characters and whitespace (runs count as one).
    The first line after a (re)connect may be the tail of a line the board was writing: if it
    is not a good frame it is counted as ``partial_line``, not as an error of the board.
    A value that is not finite (``nan``, ``inf``) keeps its frame, flagged FLAG_INVALID on
    that channel (as the wire protocol does); words that are not numbers refuse the frame.
    ``lines`` says what a good line holds.
    """

    profile = "lines"
    REASONS = ("partial_line", "too_long", "not_a_frame", "prefix", "values", "not_a_number")

    def __init__(
        self,
        protocol: Protocol,
        device: DeviceSpec,
        layer: str,
        lines: TextLines,
    ) -> None:
        super().__init__(protocol, device, layer)
        self.start_command = lines.start_command
        self.expected = int(lines.expected)
        self.prefix = lines.prefix
        self.volts_per_unit = float(lines.volts_per_unit)
        self.separators = lines.separators
        self._to_spaces = str.maketrans(dict.fromkeys(lines.separators, " "))
        self.max_line = 64 * self.expected + 256
        self._buf = bytearray()
        self._offset = 0  # stream offset of self._buf[0]
        self._fresh = True
        self._skipping = False
        self.EXPECTING = f"lines of {self.expected} numbers"

    def greeting(self) -> bytes:
        """The board's start line (``start_command`` + newline), or nothing."""
        return (self.start_command + "\n").encode() if self.start_command else b""

    def reset(self) -> None:
        super().reset()
        self.stats.discarded_bytes += len(self._buf)
        self._offset += len(self._buf)
        self._buf.clear()
        self._fresh = True
        self._skipping = False

    def feed(self, data: bytes) -> list[BoardFrame]:
        self.stats.bytes += len(data)
        buf = self._buf
        buf += data
        frames: list[BoardFrame] = []
        start = 0
        for end in _LINE_END.finditer(buf):
            line = bytes(buf[start : end.start()])
            size = end.end() - start
            if self._skipping:
                self._skipping = False
                self.stats.discarded_bytes += size
            elif line.strip():
                frame = self._line(line, self._offset + start, size)
                if frame is not None:
                    frames.append(frame)
            else:
                self.stats.discarded_bytes += size  # an empty line, or CR and LF apart
            self._fresh = False
            start = end.end()
        del buf[:start]
        self._offset += start
        if len(buf) > self.max_line:
            self._refuse(
                "too_long",
                f"byte {self._offset}: no line end within {self.max_line} bytes",
                len(buf),
            )
            self._seen(bytes(buf[:80]))
            self._offset += len(buf)
            buf.clear()
            self._skipping = True
        self.stats.frames += len(frames)
        return frames

    def _line(self, line: bytes, offset: int, size: int) -> BoardFrame | None:
        text = line.decode("latin-1").strip()
        body = self._body(text, offset, size)
        if body is None:
            return None
        text = body.translate(self._to_spaces)
        try:
            values = np.fromstring(text, sep=" ")  # C parsing; numpy >= 2.4 raises on a word
        except ValueError:
            values = None
        if values is None or len(values) != self.expected:
            tokens = text.split()
            if len(tokens) != self.expected:
                return self._bad(
                    "values",
                    f"byte {offset}: {len(tokens)} values, layer {self.layer!r} expects "
                    f"{self.expected}",
                    line,
                    size,
                )
            word = next((t for t in tokens if not _is_number(t)), None)
            if word is not None:
                return self._bad(
                    "not_a_number", f"byte {offset}: {word[:20]!r} is not a number", line, size
                )
            values = np.array(list(map(float, tokens)))  # numbers numpy's parser declines
        if self.volts_per_unit != 1.0:
            values *= self.volts_per_unit
        self.acknowledged = True
        return BoardFrame(values, invalid_flags(values))

    def _body(self, text: str, offset: int, size: int) -> str | None:
        """The values part of a line, or None (counted) for a line that is no frame."""
        if self.prefix:
            if not text.startswith(self.prefix):
                self._bad(
                    "prefix",
                    f"byte {offset}: line does not start with {self.prefix!r}",
                    text.encode("latin-1"),
                    size,
                )
                return None
            return text[len(self.prefix) :]
        label = LINE_LABEL.match(text)
        return text[label.end() :] if label else text

    def _bad(self, reason: str, message: str, line: bytes, size: int) -> None:
        self._seen(line[:80])
        if self._fresh:
            reason, message = "partial_line", f"{message} (first line after connecting)"
        self._refuse(reason, message, size)
        return None


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


class OpenEITReader(TextLineReader):
    r"""OpenEIT / Mindseye Spectra imaging lines (docs/boards.md, firmware ``OpenEIT.c``).

    A frame is ``magnitudes: `` + N x ``%8d.%04d,`` + CRLF. The firmware boots into
    16-electrode imaging and prints ``OpenEIT``; it switches mode when it finds the mode
    letter and a newline among more than two waiting bytes between frames, printing
    ``mode K: ...``. The host writes the layer's mode line twice (``d\nd\n``: four bytes)
    on every connect and after a restart banner, and again after ``ack_timeout_s`` without
    a frame of the mode's size.
    """

    profile = "openeit"

    def __init__(self, protocol: Protocol, device: DeviceSpec, layer: str) -> None:
        n = protocol.n_electrodes
        super().__init__(
            protocol,
            device,
            layer,
            TextLines(n * (n - 4), ",", "magnitudes:", float(device.get("volts_per_unit"))),
        )
        self.mode = OPENEIT_ELECTRODES[n]
        self.EXPECTING = f"'magnitudes:' lines of {self.expected} values (mode {self.mode})"

    def greeting(self) -> bytes:
        return f"{self.mode}\n".encode() * 2

    def _body(self, text: str, offset: int, size: int) -> str | None:
        if "OpenEIT" in text:  # the boot banner: back in its default mode
            self.stats.messages += 1
            self.stats.restarts += 1
            self.acknowledged = False
            self._sent_at = None
            if text.startswith("OpenEIT"):
                self.stats.discarded_bytes += size
            else:  # a reset cut the frame being written
                self._refuse("values", f"byte {offset}: frame cut by a board restart", size)
            return None
        if text.startswith("mode "):
            self.stats.messages += 1
            self.stats.discarded_bytes += size
            self._seen(text.encode("latin-1")[:80])
            return None
        return super()._body(text, offset, size)


def lines_reader(protocol: Protocol, device: DeviceSpec, layer: str) -> TextLineReader:
    """The ``lines`` profile's reader with the patch's options."""
    count = int(device.get("values"))
    if count == 0:
        count = protocol.n_measurements if device.get("drop_zeros") else protocol.frame_size
    lines = TextLines(
        expected=count,
        separators=str(device.get("separators")),
        prefix=str(device.get("prefix")),
        volts_per_unit=float(device.get("volts_per_unit")),
        start_command=str(device.get("start_command")),
    )
    return TextLineReader(protocol, device, layer, lines)
