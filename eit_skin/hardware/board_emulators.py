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
* :class:`SciospecEmulator`: Sciospec EIT16/32/64 over USB serial (``spatialaudio/sciopy``
  ``usb_hs_handling.py`` and ``setup_m.py``): ``[tag][len][payload][tag]`` commands,
  acknowledgements, and one complex float32 data frame per injection and channel group.

Each takes a frame source (frame index -> the layer's ``M`` measurements in protocol order),
the layer's :class:`~eit_skin.patch.protocol.Protocol` and a rate, and shares the pty
handling of :class:`~eit_skin.hardware.fake_device.PtyBoard` (plug, unplug, symlink,
``write_raw`` to inject garbage, ``cut_next_frame``). What none of them emulate is listed in
docs/boards.md (*Emulated boards*).
"""

from __future__ import annotations

import functools
import struct
import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

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


class LinesEmulator(PtyBoard):
    """A line-printing board: one text line of numbers per frame, no host commands.

    The line is ``label: `` (when given), then every number as ``Serial.print(v, 4)``
    followed by ``separator``, then ``line_ending``.

    Args:
        frame_source: frame index -> the layer's measurements ``[M]`` in protocol order.
        protocol: the layer's protocol: the full layout gives the N x N numbers of
            ``read_frame`` (zeros on pairs touching a drive electrode).
        rate_hz: frames per second.
        separator: one of :data:`LINE_SEPARATORS`.
        label: prefix word ('' for none).
        line_ending: LF or CR LF.
        drop_zeros: print only the protocol's entries of a full layout (boards that skip
            the pairs on drive electrodes); refused for a compact layout.
        scale: board units per frame-source unit.
        digits: decimals of every number.
    """

    def __init__(
        self,
        frame_source: FrameSource,
        protocol: Protocol,
        rate_hz: float = 10.0,
        *,
        separator: str = ", ",
        label: str = "",
        line_ending: str = "\n",
        drop_zeros: bool = False,
        scale: float = 1.0,
        digits: int = 4,
        max_pending_bytes: int = 1 << 20,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=max_pending_bytes)
        if separator not in LINE_SEPARATORS:
            raise ValueError(f"separator: {separator!r} is not one of {LINE_SEPARATORS}")
        if line_ending not in LINE_ENDINGS:
            raise ValueError(f"line_ending: {line_ending!r} is not one of {LINE_ENDINGS}")
        if label and not label.replace("_", "").isalnum():
            raise ValueError(f"label: {label!r} must be letters, digits or '_'")
        if drop_zeros and protocol.frame_index is None:
            raise ValueError(
                "drop_zeros: the protocol's layout is compact (no zeros to drop); use layout: full"
            )
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"scale must be a positive number, got {scale}")
        if not 0 <= digits <= 15:
            raise ValueError(f"digits must be in 0..15, got {digits}")
        self.frame_source = frame_source
        self.protocol = protocol
        self.separator = separator
        self.label = label
        self.line_ending = line_ending
        self.drop_zeros = drop_zeros
        self.scale = float(scale)
        self.digits = int(digits)
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


# ---------------------------------------------------------------------------------- Sciospec

SCIOSPEC_ACK = bytes([0x18, 0x01, 0x83, 0x18])
"""Command-Acknowledge: command executed (sciopy ``msg_dict`` 0x83)."""

SCIOSPEC_NACK_UNKNOWN = bytes([0x18, 0x01, 0x82, 0x18])
"""Not-Acknowledge: command could not be recognised (0x82)."""

SCIOSPEC_NACK_NOT_EXECUTED = bytes([0x18, 0x01, 0x81, 0x18])
"""Not-Acknowledge: command has not been executed (0x81): a value out of range."""

SCIOSPEC_TIMEOUT = bytes([0x18, 0x01, 0x02, 0x18])
"""Communication timeout: less data than the length byte announced (0x02)."""

SCIOSPEC_DATA_TAG = 0xB4
SCIOSPEC_CHANNELS_PER_GROUP = 16

#: Setup sub-commands (``B0``) -> payload length including the sub-command byte.
SCIOSPEC_SETUP_LENGTHS = {
    0x01: 1,  # reset setup
    0x02: 3,  # burst count, uint16 BE
    0x03: 5,  # frame rate, float32 BE, Hz
    0x04: 12,  # frequency block: fmin f32, fmax f32, fcount u16, ftype u8
    0x05: 9,  # excitation amplitude, float64 BE, A
    0x06: 3,  # injection pair (ESout, ESin), 1-based channels, appended
    0x08: 3,  # measure mode
    0x09: 3,  # gain
    0x0C: 2,  # excitation switch type
    0x0D: 2,  # ADC range
}

SCIOSPEC_OUTPUTS = {0x01: "excitation", 0x02: "frequency_row", 0x03: "timestamp"}
"""Output configuration (``B2``) sub-commands: optional fields of every data frame."""


@functools.lru_cache(maxsize=8)
def difference_inverse(protocol: Protocol) -> sp.csr_matrix:
    """``[n_inj * n_el, M]`` least-squares inverse of :meth:`Protocol.measure` per injection.

    Per injection, the pseudo-inverse of its measurements' +1/-1 incidence matrix: the
    minimum-norm potentials (zero mean on every set of electrodes the pairs connect, 0 on
    electrodes no pair touches). Made once per protocol (a loop over injections).
    """
    n, meas = protocol.n_electrodes, protocol.measurements
    rows, cols, vals = [], [], []
    for k in range(protocol.n_injections):
        (idx,) = np.nonzero(meas[:, 0] == k)
        if idx.size == 0:
            continue
        incidence = np.zeros((idx.size, n))
        incidence[np.arange(idx.size), meas[idx, 1]] += 1.0
        incidence[np.arange(idx.size), meas[idx, 2]] -= 1.0
        pinv = np.linalg.pinv(incidence)  # [n, m_k]
        r, c = np.nonzero(np.abs(pinv) > 1e-14)
        rows.append(k * n + r)
        cols.append(idx[c])
        vals.append(pinv[r, c])
    shape = (protocol.n_injections * n, protocol.n_measurements)
    return sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape
    )


def potentials_from_differences(protocol: Protocol, differences: np.ndarray) -> np.ndarray:
    """Single-ended electrode potentials per injection that reproduce a frame of differences.

    Least squares per injection (a constant per injection is free: the minimum-norm one is
    taken). When each injection's measurement pairs form no loop (adjacent pairs skipping
    the drive electrodes, for instance) ``protocol.measure(result)`` gives ``differences``
    back exactly; with loops (a full ring of pairs) noisy data are fitted in least squares.

    Args:
        protocol: the layer's protocol.
        differences: ``[..., M]`` measurements in protocol order, volts.

    Returns:
        ``[..., n_inj, n_el]`` potentials, volts (config electrode numbering).
    """
    d = np.asarray(differences, dtype=np.float64)
    if d.shape[-1:] != (protocol.n_measurements,):
        raise ValueError(
            f"differences: expected [..., {protocol.n_measurements}] ({protocol.name}), "
            f"got shape {d.shape}"
        )
    u = (difference_inverse(protocol) @ d.reshape(-1, d.shape[-1]).T).T
    return u.reshape(*d.shape[:-1], protocol.n_injections, protocol.n_electrodes)


class SciospecEmulator(PtyBoard):
    """A Sciospec EIT device on its USB serial port: commands in, acknowledgements and data out.

    Every command ``[tag][len][payload][tag]`` is answered with :data:`SCIOSPEC_ACK`, or
    :data:`SCIOSPEC_NACK_UNKNOWN` (unknown tag or sub-command, wrong length, wrong closing
    tag), or :data:`SCIOSPEC_NACK_NOT_EXECUTED` (a value out of range, start without
    injections); a command left incomplete for ``command_timeout_s`` is dropped with
    :data:`SCIOSPEC_TIMEOUT`. Nothing is sent before ``B4 01 01 B4`` (start). Then, per
    frame, for every configured injection in order, one data frame per channel group::

        B4 len CG [ESout ESin] [freq row u16] [timestamp u32 ms] 16 x (re f32, im f32) B4

    (big endian; the bracketed fields only while switched on by ``B2``; all on: 140 bytes,
    ``len`` = 0x89). ``B4 01 00 B4`` stops after the current frame; a burst count > 0
    stops the stream by itself after that many frames.

    Args:
        frame_source: frame index -> the layer's measurements ``[M]`` in protocol order,
            volts; turned into single-ended potentials by :func:`potentials_from_differences`.
        protocol: the layer's protocol (a pair drive).
        rate_hz: frames per second until the host sets a frame rate (``B0 05 03``).
        channels: the device's channel count (16, 32, 48 or 64; default 32, or 64 above 32
            electrodes); channels without an electrode read 0 V.
        channel_electrodes: config electrode of board electrode 0, 1, ... (default 0, 1, ...).
        first_channel: the channel (1-based) board electrode 0 is wired to; board electrode
            ``b`` is on channel ``first_channel + b``.
        command_timeout_s: how long an incomplete command may wait for its bytes.
    """

    def __init__(
        self,
        frame_source: FrameSource,
        protocol: Protocol,
        rate_hz: float = 10.0,
        *,
        channels: int | None = None,
        channel_electrodes: Sequence[int] | None = None,
        first_channel: int = 1,
        command_timeout_s: float = 0.5,
        max_pending_bytes: int = 1 << 22,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=max_pending_bytes)
        n = protocol.n_electrodes
        if not protocol.pair_drive:
            raise ValueError(
                f"protocol {protocol.name}: a Sciospec device drives one pair at a time"
            )
        channels = channels if channels is not None else (32 if n <= 32 else 64)
        if channels not in (16, 32, 48, 64) or not 1 <= first_channel <= channels - n + 1:
            raise ValueError(
                f"channels: {channels} is not 16, 32, 48 or 64 with room for {n} electrodes "
                f"from channel {first_channel}"
            )
        wiring = np.arange(n) if channel_electrodes is None else np.asarray(channel_electrodes)
        if sorted(wiring.tolist()) != list(range(n)):
            raise ValueError(
                f"channel_electrodes: must list every electrode 0..{n - 1} once, "
                f"got {wiring.tolist()}"
            )
        self.frame_source = frame_source
        self.protocol = protocol
        self.channels = channels
        self.channel_electrodes = wiring.astype(np.int64)
        self.first_channel = int(first_channel)
        self.command_timeout_s = float(command_timeout_s)
        self.default_rate_hz = self.rate_hz
        channel_of = np.empty(n, dtype=np.int64)
        channel_of[self.channel_electrodes] = np.arange(n)
        self.factory_injections = [
            (int(channel_of[a]) + first_channel, int(channel_of[b]) + first_channel)
            for a, b in protocol.injections
        ]
        self.injections: list[tuple[int, int]] = list(self.factory_injections)
        self.outputs = dict.fromkeys(SCIOSPEC_OUTPUTS.values(), True)
        self.settings: dict[int, bytes] = {}
        self.burst_count = 0
        self.measuring = False
        self.commands: list[bytes] = []
        self.unknown_injections = 0
        self._frames_in_burst = 0
        self._rx = bytearray()
        self._rx_since = 0.0
        self._clock_zero_us = 0
        self._inverse = difference_inverse(protocol)
        self._map_key: tuple | None = None
        self._map: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros(0))

    @property
    def streaming(self) -> bool:
        return self.measuring

    def on_power_up(self) -> None:
        """Power-up: the clock starts at 0, the device waits for commands."""
        self._clock_zero_us = self.board_time_us()
        self.measuring = False
        self._rx.clear()

    def restart(self) -> None:
        """The board clock restarts at 0 (what the host sees of a reset mid-measurement)."""
        self._clock_zero_us = self.board_time_us()

    # ------------------------------------------------------------------ commands
    def on_host_bytes(self, data: bytes) -> None:
        """Parse and answer every complete command; time out an incomplete one."""
        now = time.monotonic()
        if data:
            if not self._rx:
                self._rx_since = now
            self._rx += data
        while len(self._rx) >= 2 and len(self._rx) >= self._rx[1] + 3:
            tag, length = self._rx[0], self._rx[1]
            block = bytes(self._rx[: length + 3])
            del self._rx[: length + 3]
            self._rx_since = now
            self.commands.append(block)
            if block[-1] != tag:
                self.write_raw(SCIOSPEC_NACK_UNKNOWN)
            else:
                self.write_raw(self._execute(tag, block[2:-1]))
        if self._rx and now - self._rx_since > self.command_timeout_s:
            self._rx.clear()
            self.write_raw(SCIOSPEC_TIMEOUT)

    def _execute(self, tag: int, payload: bytes) -> bytes:
        """Carry out one well-framed command; return the answer's bytes."""
        sub = payload[0] if payload else None
        if tag == 0xB0 and SCIOSPEC_SETUP_LENGTHS.get(sub) == len(payload):
            return self._setup(sub, payload[1:])
        if tag == 0xB1 and len(payload) == 1 and sub in SCIOSPEC_SETUP_LENGTHS:
            if sub == 0x06:
                value = b"".join(bytes(pair) for pair in self.injections)
            else:
                value = self.settings.get(sub, b"")
            reply = bytes([sub]) + value
            return bytes([0xB1, len(reply)]) + reply + bytes([0xB1]) + SCIOSPEC_ACK
        if tag == 0xB2 and len(payload) == 2 and sub in SCIOSPEC_OUTPUTS and payload[1] < 2:
            self.outputs[SCIOSPEC_OUTPUTS[sub]] = bool(payload[1])
            return SCIOSPEC_ACK
        if tag == SCIOSPEC_DATA_TAG and len(payload) == 1 and sub in (0, 1):
            if sub == 1 and not self.injections:
                return SCIOSPEC_NACK_NOT_EXECUTED
            if sub == 1 and not self.measuring:
                self._frames_in_burst = 0
            self.measuring = sub == 1
            return SCIOSPEC_ACK
        return SCIOSPEC_NACK_UNKNOWN

    def _setup(self, sub: int, value: bytes) -> bytes:
        if sub == 0x01:
            self.injections.clear()
            self.settings.clear()
            self.burst_count = 0
            self.rate_hz = self.default_rate_hz
            return SCIOSPEC_ACK
        if sub == 0x03:
            (rate,) = struct.unpack(">f", value)
            if not (np.isfinite(rate) and rate > 0):
                return SCIOSPEC_NACK_NOT_EXECUTED
            self.rate_hz = float(rate)
        elif sub == 0x02:
            (self.burst_count,) = struct.unpack(">H", value)
        elif sub == 0x06:
            out, into = value
            if out == into or not (1 <= out <= self.channels and 1 <= into <= self.channels):
                return SCIOSPEC_NACK_NOT_EXECUTED
            self.injections.append((out, into))
            return SCIOSPEC_ACK
        self.settings[sub] = value
        return SCIOSPEC_ACK

    # ------------------------------------------------------------------ data
    def _injection_map(self) -> tuple[np.ndarray, np.ndarray]:
        """Per configured injection: protocol injection index (-1: none) and sign."""
        key = tuple(self.injections)
        if self._map_key != key:
            n = self.protocol.n_electrodes
            pairs = np.array(key, dtype=np.int64).reshape(-1, 2) - self.first_channel
            wired = ((pairs >= 0) & (pairs < n)).all(axis=1)  # pairs: board electrodes
            ends = self.channel_electrodes[np.where(wired[:, None], pairs, 0)]
            table = np.full((n, n), -1, dtype=np.int64)
            table[self.protocol.injections[:, 0], self.protocol.injections[:, 1]] = np.arange(
                self.protocol.n_injections
            )
            forward = table[ends[:, 0], ends[:, 1]]
            backward = table[ends[:, 1], ends[:, 0]]
            k = np.where(wired, np.where(forward >= 0, forward, backward), -1)
            sign = np.where(forward >= 0, 1.0, -1.0)
            self._map_key, self._map = key, (k, sign)
        return self._map

    def channel_potentials(self, index: int) -> np.ndarray:
        """``[n_configured_injections, channels]`` potentials of frame ``index``, volts.

        An injection the protocol lacks reads its reverse negated, or 0 V on every channel
        (counted in :attr:`unknown_injections`).
        """
        d = np.asarray(self.frame_source(index), dtype=np.float64)
        u = (self._inverse @ d).reshape(self.protocol.n_injections, -1)  # config electrodes
        k, sign = self._injection_map()
        out = np.zeros((len(k), self.channels))
        known = k >= 0
        self.unknown_injections += int((~known).sum())
        n = self.protocol.n_electrodes
        first = self.first_channel - 1
        out[known, first : first + n] = sign[known, None] * u[k[known]][:, self.channel_electrodes]
        return out

    def expected_measurements(self, index: int) -> np.ndarray:
        """``[M]`` volts a correct host forms from frame ``index``, protocol order.

        The differences of the float32 potentials sent, for a host that configured the
        protocol's injections.
        """
        d = np.asarray(self.frame_source(index), dtype=np.float64)
        u = (self._inverse @ d).reshape(self.protocol.n_injections, -1)
        return self.protocol.measure(u.astype(np.float32).astype(np.float64))

    def data_frames(self, index: int, time_ms: float, period_ms: float) -> bytes:
        """Every data frame of frame ``index`` (injections in the configured order)."""
        potentials = self.channel_potentials(index)
        n_inj = len(self.injections)
        groups = self.channels // SCIOSPEC_CHANNELS_PER_GROUP
        fields = [("tag", "u1"), ("len", "u1"), ("group", "u1")]
        if self.outputs["excitation"]:
            fields += [("out", "u1"), ("in", "u1")]
        if self.outputs["frequency_row"]:
            fields += [("row", ">u2")]
        if self.outputs["timestamp"]:
            fields += [("time", ">u4")]
        fields += [("values", ">f4", (2 * SCIOSPEC_CHANNELS_PER_GROUP,)), ("end", "u1")]
        dtype = np.dtype(fields)
        rec = np.zeros((n_inj, groups), dtype=dtype)
        rec["tag"] = rec["end"] = SCIOSPEC_DATA_TAG
        rec["len"] = dtype.itemsize - 3
        rec["group"] = np.arange(1, groups + 1)
        pairs = np.array(self.injections, dtype=np.uint8).reshape(n_inj, 2)
        if self.outputs["excitation"]:
            rec["out"], rec["in"] = pairs[:, [0]], pairs[:, [1]]
        if self.outputs["timestamp"]:
            stamps = np.floor(np.maximum(time_ms, 0.0) + np.arange(n_inj) * period_ms / n_inj)
            rec["time"] = (stamps.astype(np.int64) % 2**32)[:, None]
        values = np.zeros((n_inj, groups, SCIOSPEC_CHANNELS_PER_GROUP, 2))
        values[..., 0] = potentials.reshape(n_inj, groups, SCIOSPEC_CHANNELS_PER_GROUP)
        rec["values"] = values.reshape(n_inj, groups, -1)
        return rec.tobytes()

    def emit_frame(self, index: int, device_time_us: int) -> None:
        """Send frame ``index``'s data frames; end the burst after ``burst_count`` frames."""
        time_ms = (device_time_us - self._clock_zero_us) / 1000.0
        self.write_frame(self.data_frames(index, time_ms, 1000.0 / self.rate_hz))
        self._frames_in_burst += 1
        if self.burst_count and self._frames_in_burst >= self.burst_count:
            self.measuring = False
