"""Emulated EIT boards that people own, byte for byte on a pseudo-terminal.

Written from each board's own open code (never from eit_skin's host side), so the host's
parsers are tested end to end against an independent implementation:

* :class:`OpenEITEmulator`: the OpenEIT / Mindseye Spectra firmware
  (``OpenEIT/EIT_Firmware`` ``OpenEIT.c``: boot banner and mode switching in ``main``, the
  frame line in ``multiplex_adg732``, the 28.4 fixed-point text of ``sprintf_fixed32``).
* :class:`LinesEmulator`: line-printing Arduino boards (``lorcan2440/EIT_Touch_Sensor``
  ``eit_controller/src/main.cpp``: ``Serial.print(v, 4); Serial.print(", ");`` per value,
  then a line feed), with the separators, prefix, line endings and dropped zeros of other
  DIY boards.
* :class:`~eit_skin.hardware.sciospec_emulator.SciospecEmulator` (its own module): Sciospec
  EIT16/32/64 over USB serial.

Each takes a frame source (frame index -> the layer's ``M`` measurements in protocol order),
the layer's :class:`~eit_skin.patch.protocol.Protocol` and a rate, and shares the pty
handling of :class:`~eit_skin.hardware.fake_device.PtyBoard` (plug, unplug, symlink,
``write_raw`` to inject garbage, ``cut_next_frame``). What none of them emulate is listed in
docs/boards.md (*Emulated boards*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eit_skin.hardware.fake_device import FrameSource, PtyBoard
from eit_skin.patch.protocol import Protocol

# ---------------------------------------------------------------------------------- OpenEIT

OPENEIT_BANNER = b"OpenEIT\n"
"""What the firmware prints at power-on (``main``, before the loop)."""

OPENEIT_IMAGING_MODES: dict[bytes, tuple[int, int, bytes]] = {
    b"c\n": (3, 8, b"mode 3: 8 electrode imaging\n"),
    b"d\n": (4, 16, b"mode 4: 16 electrode imaging\n"),
    b"e\n": (5, 32, b"mode 3: 32 electrode imaging\n"),  # sic: the firmware's own text
}
"""Host command -> (firmware mode, electrodes, the line the firmware prints on switching)."""

OPENEIT_OTHER_MODES = (b"a\n", b"b\n", b"f\n", b"g\n")
"""Time series, spectroscopy and bipolar modes: recognised, not emulated (see the docs)."""

OPENEIT_VALUES_PER_FRAME = {8: 32, 16: 192, 32: 896}
"""Electrodes -> magnitudes per frame line (``numberofmeasures`` in ``multiplex_adg732``)."""

OPENEIT_FIXED32_MAX = 0x7FFFFFFF
"""Saturated 28.4 fixed-point magnitude (``calculate_magnitude``)."""


def openeit_fixed32(magnitudes: np.ndarray) -> np.ndarray:
    """28.4 fixed-point magnitudes (int64 ``[N]``, 16ths) of board-unit values ``[N]``.

    Nearest 1/16 (ties up), saturated at 0x7FFFFFFF, NaN as 0 (an open circuit).
    """
    v = np.abs(np.asarray(magnitudes, dtype=np.float64))
    v = np.where(np.isnan(v), 0.0, v)
    return np.clip(np.floor(v * 16.0 + 0.5), 0, OPENEIT_FIXED32_MAX).astype(np.int64)


def openeit_frame_line(magnitudes: np.ndarray) -> bytes:
    """One OpenEIT frame line from magnitudes in board units ``[N]``.

    ``magnitudes: `` then, per value, the 28.4 fixed-point number (rounded to the nearest
    1/16, saturated at 0x7FFFFFFF / 16, NaN as 0 like an open circuit) as ``%8d.%04d``
    (fraction = 16ths x 625) followed by ``,``; then ``CR LF``.
    """
    full = openeit_fixed32(magnitudes)
    ipart = np.char.rjust((full >> 4).astype(str), 8)
    fpart = np.char.zfill(((full & 0x0F) * 625).astype(str), 4)
    text = "".join(np.char.add(np.char.add(ipart, "."), np.char.add(fpart, ",")).tolist())
    return b"magnitudes: " + text.encode("ascii") + b"\r\n"


class OpenEITEmulator(PtyBoard):
    """An OpenEIT board: banner at power-on, then one magnitude line per frame, forever.

    Between two frames it looks at what the host wrote since the last look: only when more
    than 2 bytes are waiting it takes the first 2 as the command (kept, like the firmware's
    ``RxBuffer``), then drops everything else. ``c``, ``d``, ``e`` + line feed switch to 8 /
    16 / 32-electrode imaging (printing the firmware's mode line) unless already there. A
    mode whose value count is not the protocol's frame size sends lines of zeros.

    Args:
        frame_source: frame index -> the layer's measurements ``[M]`` in protocol order.
        protocol: the layer's protocol (``device_frame`` gives the board's numbers).
        rate_hz: frames per second.
        scale: board units per frame-source unit (1 for recordings of the board's numbers;
            ``1 / current_a`` turns volts into the firmware's transfer impedance, ohms).
    """

    def __init__(
        self,
        frame_source: FrameSource,
        protocol: Protocol,
        rate_hz: float = 10.0,
        *,
        scale: float = 1.0,
        max_pending_bytes: int = 1 << 20,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=max_pending_bytes)
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"scale must be a positive number, got {scale}")
        self.frame_source = frame_source
        self.protocol = protocol
        self.scale = float(scale)
        self.mode = 4
        self.n_electrodes = 16
        self.unemulated_commands: list[bytes] = []
        self._rx = bytearray()
        self._rx_buffer = b"\x00\x00"
        self._restart_cut: int | None = None

    def on_power_up(self) -> None:
        """Boot: mode 4 (16 electrodes) and the banner, as at the top of ``main``."""
        self.mode, self.n_electrodes = 4, 16
        self._rx.clear()
        self._rx_buffer = b"\x00\x00"
        self.write_raw(OPENEIT_BANNER)

    def on_host_bytes(self, data: bytes) -> None:
        """Collect host bytes; the firmware looks at them only between frames."""
        self._rx += data

    def restart(self, cut_at: int | None = None) -> None:
        """Reboot during the next frame.

        Its line stops after ``cut_at`` bytes (default: half of it), the banner follows, and
        streaming goes on in mode 4.
        """
        self._restart_cut = -1 if cut_at is None else int(cut_at)

    def board_numbers(self, index: int) -> np.ndarray:
        """Frame ``index`` of the current mode in board units ``[N]``, before printing."""
        n_values = OPENEIT_VALUES_PER_FRAME[self.n_electrodes]
        if self.protocol.frame_size != n_values:
            return np.zeros(n_values)
        return self.protocol.device_frame(self.frame_source(index)) * self.scale

    def frame_line(self, index: int) -> bytes:
        """Frame ``index`` of the current mode as the board prints it."""
        return openeit_frame_line(self.board_numbers(index))

    def expected_measurements(self, index: int) -> np.ndarray:
        """``[M]`` what a correct host decodes from frame ``index``, board units.

        Protocol order, magnitudes; the current mode must be the protocol's.
        """
        return self.protocol.select(openeit_fixed32(self.board_numbers(index)) / 16.0)

    def _look_at_input(self) -> None:
        """The top of the firmware's main loop: command check, mode switch, flush."""
        taken = len(self._rx) > 2
        if taken:
            self._rx_buffer = bytes(self._rx[:2])
        self._rx.clear()
        command = OPENEIT_IMAGING_MODES.get(self._rx_buffer)
        if command is not None and command[0] != self.mode:
            self.mode, self.n_electrodes, line = command
            self.write_raw(line)
        elif taken and self._rx_buffer in OPENEIT_OTHER_MODES:
            self.unemulated_commands.append(self._rx_buffer)

    def emit_frame(self, index: int, device_time_us: int) -> None:
        """Look at the host's bytes, then print one frame line of the current mode."""
        self._look_at_input()
        line = self.frame_line(index)
        if self._restart_cut is not None:
            cut = len(line) // 2 if self._restart_cut < 0 else self._restart_cut
            self._restart_cut = None
            self.write_raw(line[:cut])
            self.on_power_up()
            return
        self.write_frame(line)


# ------------------------------------------------------------------------------ lines boards

LINE_SEPARATORS = (", ", ";", " ", ",", "\t")
"""Separators a line-printing board may put after every value."""

LINE_ENDINGS = ("\n", "\r\n")


def arduino_print_float(values: np.ndarray, digits: int = 4) -> np.ndarray:
    """``Serial.print(v, digits)`` of every value, as Arduino's ``Print::printFloat`` does.

    ``nan``, ``inf`` (either sign), ``ovf`` beyond +-4294967040; else an optional ``-``
    (any negative number, so ``-0.00001`` prints ``-0.0000``), the value plus half a unit
    of the last digit, its integer part, ``.`` and ``digits`` digits taken one at a time.

    Args:
        values: numbers ``[N]``.
        digits: decimals.

    Returns:
        ``[N]`` str array.
    """
    v = np.asarray(values, dtype=np.float64)
    rounding = 0.5
    for _ in range(digits):
        rounding /= 10.0
    number = np.abs(v) + rounding
    finite = np.isfinite(number) & (number < 4294967040.0 + 1.0)
    number = np.where(finite, number, 0.0)
    int_part = np.floor(number)
    remainder = number - int_part
    out = np.char.add(np.where(v < 0, "-", ""), int_part.astype(np.int64).astype(str))
    if digits > 0:
        out = np.char.add(out, ".")
        for _ in range(digits):
            remainder = remainder * 10.0
            digit = np.floor(remainder)
            remainder = remainder - digit
            out = np.char.add(out, digit.astype(np.int64).astype(str))
    out = np.where(np.abs(v) > 4294967040.0, "ovf", out)
    out = np.where(np.isinf(v), "inf", out)
    return np.where(np.isnan(v), "nan", out)


@dataclass(frozen=True)
class LineFormat:
    """How a line-printing board writes a frame.

    The line is ``label: `` (when given), then every number as ``Serial.print(v, digits)``
    times ``scale`` followed by ``separator``, then ``line_ending``.

    Attributes:
        separator: one of :data:`LINE_SEPARATORS`.
        label: prefix word ('' for none).
        line_ending: LF or CR LF.
        drop_zeros: print only the protocol's entries of a full layout (boards that skip
            the pairs on drive electrodes).
        scale: board units per frame-source unit.
        digits: decimals of every number.
    """

    separator: str = ", "
    label: str = ""
    line_ending: str = "\n"
    drop_zeros: bool = False
    scale: float = 1.0
    digits: int = 4

    def __post_init__(self) -> None:
        if self.separator not in LINE_SEPARATORS:
            raise ValueError(f"separator: {self.separator!r} is not one of {LINE_SEPARATORS}")
        if self.line_ending not in LINE_ENDINGS:
            raise ValueError(f"line_ending: {self.line_ending!r} is not one of {LINE_ENDINGS}")
        if self.label and not self.label.replace("_", "").isalnum():
            raise ValueError(f"label: {self.label!r} must be letters, digits or '_'")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a positive number, got {self.scale}")
        if not 0 <= self.digits <= 15:
            raise ValueError(f"digits must be in 0..15, got {self.digits}")


class LinesEmulator(PtyBoard):
    """A line-printing board: one text line of numbers per frame, no host commands.

    Args:
        frame_source: frame index -> the layer's measurements ``[M]`` in protocol order.
        protocol: the layer's protocol: the full layout gives the N x N numbers of
            ``read_frame`` (zeros on pairs touching a drive electrode).
        rate_hz: frames per second.
        line_format: how the line is written (``drop_zeros`` is refused for a compact
            layout).
        max_pending_bytes: bytes queued while nobody reads before frames are dropped.
    """

    def __init__(
        self,
        frame_source: FrameSource,
        protocol: Protocol,
        rate_hz: float = 10.0,
        line_format: LineFormat = LineFormat(),
        max_pending_bytes: int = 1 << 20,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=max_pending_bytes)
        if line_format.drop_zeros and protocol.frame_index is None:
            raise ValueError(
                "drop_zeros: the protocol's layout is compact (no zeros to drop); use layout: full"
            )
        self.frame_source = frame_source
        self.protocol = protocol
        self.line_format = line_format
        self.separator = line_format.separator
        self.label = line_format.label
        self.line_ending = line_format.line_ending
        self.drop_zeros = line_format.drop_zeros
        self.scale = float(line_format.scale)
        self.digits = int(line_format.digits)
        self._kept = None if protocol.frame_index is None else np.sort(protocol.frame_index)

    def printed_numbers(self, index: int) -> np.ndarray:
        """The numbers of frame ``index``'s line as text ``[N]`` (str array)."""
        values = self.protocol.device_frame(self.frame_source(index))
        if self.drop_zeros:
            values = values[self._kept]
        return arduino_print_float(values * self.scale, self.digits)

    def expected_measurements(self, index: int) -> np.ndarray:
        """``[M]`` what a correct host decodes from frame ``index``, protocol order.

        ``ovf`` decodes as NaN.
        """
        printed = np.char.replace(self.printed_numbers(index), "ovf", "nan").astype(np.float64)
        if not self.drop_zeros:
            return self.protocol.select(printed)
        full = np.zeros(self.protocol.frame_size)
        full[self._kept] = printed
        return self.protocol.select(full)

    def frame_line(self, index: int) -> bytes:
        """Frame ``index`` as the board prints it."""
        text = self.printed_numbers(index)
        body = "".join(np.char.add(text, self.separator).tolist())
        prefix = f"{self.label}: " if self.label else ""
        return (prefix + body + self.line_ending).encode("ascii")

    def emit_frame(self, index: int, device_time_us: int) -> None:
        """Print frame ``index``."""
        self.write_frame(self.frame_line(index))
