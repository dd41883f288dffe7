"""An emulated Sciospec EIT16/32/64 over USB serial, byte for byte on a pseudo-terminal.

Written from the board's own open code (``spatialaudio/sciopy`` ``usb_hs_handling.py`` and
``setup_m.py``), never from eit_skin's host side: ``[tag][len][payload][tag]`` commands,
acknowledgements, and one complex float32 data frame per injection and channel group. It
shares the pty handling of :class:`~eit_skin.hardware.fake_device.PtyBoard` like the
emulators of :mod:`eit_skin.hardware.board_emulators`; what it does not emulate is listed in
docs/boards.md (*Emulated boards*).
"""

from __future__ import annotations

import functools
import struct
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from eit_skin.hardware.fake_device import FrameSource, PtyBoard
from eit_skin.patch.protocol import Protocol

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


@dataclass(frozen=True)
class SciospecWiring:
    """How a layer's electrodes sit on a Sciospec device's channels.

    Attributes:
        channels: the device's channel count (16, 32, 48 or 64; None: 32, or 64 above 32
            electrodes); channels without an electrode read 0 V.
        channel_electrodes: config electrode of board electrode 0, 1, ... (None: 0, 1, ...).
        first_channel: the channel (1-based) board electrode 0 is wired to; board electrode
            ``b`` is on channel ``first_channel + b``.
    """

    channels: int | None = None
    channel_electrodes: tuple[int, ...] | None = None
    first_channel: int = 1


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
        wiring: the device's channel count and which electrode is on which channel.
        command_timeout_s: how long an incomplete command may wait for its bytes.
    """

    #: Bytes queued while nobody reads before frames are dropped.
    MAX_PENDING_BYTES = 1 << 22

    def __init__(
        self,
        frame_source: FrameSource,
        protocol: Protocol,
        rate_hz: float = 10.0,
        *,
        wiring: SciospecWiring = SciospecWiring(),
        command_timeout_s: float = 0.5,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=self.MAX_PENDING_BYTES)
        n = protocol.n_electrodes
        channels, first_channel = wiring.channels, wiring.first_channel
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
        order = (
            np.arange(n)
            if wiring.channel_electrodes is None
            else np.asarray(wiring.channel_electrodes)
        )
        if sorted(order.tolist()) != list(range(n)):
            raise ValueError(
                f"channel_electrodes: must list every electrode 0..{n - 1} once, "
                f"got {order.tolist()}"
            )
        self.frame_source = frame_source
        self.protocol = protocol
        self.channels = channels
        self.channel_electrodes = order.astype(np.int64)
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
