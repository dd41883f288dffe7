"""Sciospec EIT16/32/64 over USB-FS serial: setup commands, acknowledgements, data frames.

Every message is ``[tag][len][len bytes of payload][tag]`` (the open MIT client
``spatialaudio/sciopy``: ``usb_hs_handling.py`` ``set_measurement_config_usb_hs``,
``StartStopMeasurement_usb_hs``; ``setup_m.py`` ``parse_single_frame``):

* host commands: ``B0`` set setup (sub-command first: 01 reset, 02 burst count, 03 frame
  rate, 04 frequency block, 05 amplitude, 06 one injection pair, 08 measure mode, 09 gain,
  0C excitation switch type, 0D ADC range), ``B2`` output configuration, ``B4 01 01 B4`` start,
  ``B4 01 00 B4`` stop;
* the board's answers: ``18 01 83 18`` acknowledged, ``18 01 81 18`` / ``18 01 82 18`` not
  executed / not recognised, ``18 01 04 18`` booted, ``18 01 92 18`` data held up;
* a data frame per excitation stage and channel group: ``B4 89 [group] [ES out] [ES in]
  [frequency row: 2] [timestamp: uint32 BE, ms] [16 x (re, im) float32 BE] B4`` (140 bytes):
  the single-ended complex potentials of the group's 16 channels during that injection.

The host sends the setup one command at a time, each after the previous one's
acknowledgement, then start; it collects one stage per injection of the layer's protocol (in
its order, every channel group the electrodes are wired to) and forms the protocol's
differences (:meth:`~eit_skin.patch.protocol.Protocol.measure`): complex values, whose real
part or magnitude :meth:`~eit_skin.patch.protocol.Protocol.select` takes (``complex_part``).
"""

from __future__ import annotations

import struct

import numpy as np

from eit_skin.hardware.boards import BoardFrame, BoardReader, invalid_flags
from eit_skin.patch.device import DeviceSpec
from eit_skin.patch.protocol import Protocol

SYSTEM_TAG = 0x18
DATA_TAG = 0xB4
DATA_LENGTH = 0x89
"""Payload bytes of a data frame: group, two excitation bytes, 2 frequency-row bytes, a
4-byte timestamp and 16 complex float32 values (1 + 2 + 2 + 4 + 128 = 137)."""
CHANNELS_PER_GROUP = 16
ACK, NOT_EXECUTED, NOT_RECOGNISED, BOOTED, DATA_HOLDUP = 0x83, 0x81, 0x82, 0x04, 0x92
KNOWN_TAGS = frozenset((SYSTEM_TAG, 0xB0, 0xB1, 0xB2, 0xB4, 0x90, 0xA1, 0xD0, 0xD1, 0xD2))
START = bytes((0xB4, 0x01, 0x01, 0xB4))
STOP = bytes((0xB4, 0x01, 0x00, 0xB4))
_GAINS = {1: 0, 10: 1, 100: 2, 1000: 3}
_ADC_RANGES = {1: 1, 5: 2, 10: 3}
_DATA = np.dtype(">f4")
_STAGE = DATA_LENGTH + 3  # bytes of one data frame


def message(tag: int, payload: bytes) -> bytes:
    """``[tag][len][payload][tag]``."""
    return bytes((tag, len(payload))) + payload + bytes((tag,))


def board_channels(protocol: Protocol, first_channel: int) -> np.ndarray:
    """``[n_el]`` 1-based board channel of each config electrode."""
    config_to_board = np.argsort(protocol.board_to_config)
    return first_channel + config_to_board


def setup_commands(
    protocol: Protocol, device: DeviceSpec, current_a: float
) -> list[tuple[str, bytes]]:
    """The host's commands on connect, in order: ``(name, bytes)``; the last one starts."""
    channels = board_channels(protocol, int(device.get("first_channel")))
    f = float(device.get("excitation_hz"))
    commands = [
        ("stop", STOP),
        ("reset setup", message(0xB0, b"\x01")),
        ("burst count 0 (until stop)", message(0xB0, b"\x02\x00\x00")),
        ("amplitude", message(0xB0, b"\x05" + struct.pack(">d", current_a))),
        ("ADC range", message(0xB0, bytes((0x0D, _ADC_RANGES[int(device.get("adc_range_v"))])))),
        ("gain", message(0xB0, bytes((0x09, 0x01, _GAINS[int(device.get("gain"))])))),
        ("single-ended mode", message(0xB0, b"\x08\x01\x01")),
        ("excitation switch type", message(0xB0, b"\x0c\x01")),
        (
            "frame rate",
            message(0xB0, b"\x03" + struct.pack(">f", float(device.get("frame_rate_hz")))),
        ),
        ("frequency", message(0xB0, b"\x04" + struct.pack(">ffHB", f, f, 1, 0))),
    ]
    for k, (source, sink) in enumerate(protocol.injections):
        pair = bytes((0x06, int(channels[source]), int(channels[sink])))
        commands.append((f"injection {k}", message(0xB0, pair)))
    commands += [
        ("output: excitation setting", message(0xB2, b"\x01\x01")),
        ("output: timestamp", message(0xB2, b"\x03\x01")),
        ("output: frequency row", message(0xB2, b"\x02\x01")),
        ("start", START),
    ]
    return commands


class SciospecReader(BoardReader):
    """Sciospec setup, acknowledgements and data frames -> the layer's frames.

    Reasons a frame is refused: ``framing`` (bytes that form no message: one count per run),
    ``before_start`` (data before the host's start was acknowledged), ``unknown_injection``
    (a stage whose pair the protocol does not drive), ``incomplete`` (a drive cycle with a
    stage or channel group missing, or cut by a restart).
    """

    profile = "sciospec"
    REASONS = ("framing", "before_start", "unknown_injection", "incomplete")
    EXPECTING = "acknowledgements of its setup"

    def __init__(
        self, protocol: Protocol, device: DeviceSpec, layer: str, current_a: float
    ) -> None:
        super().__init__(protocol, device, layer)
        self.setup = setup_commands(protocol, device, current_a)
        channels = board_channels(protocol, int(device.get("first_channel")))
        self._stage_of = {
            (int(channels[s]), int(channels[t])): k for k, (s, t) in enumerate(protocol.injections)
        }
        first, last = int(channels.min()), int(channels.max())
        self._groups = tuple(
            range((first - 1) // CHANNELS_PER_GROUP + 1, (last - 1) // CHANNELS_PER_GROUP + 2)
        )
        base = (self._groups[0] - 1) * CHANNELS_PER_GROUP + 1
        self._column = channels - base  # [n_el] column of each config electrode
        self._width = CHANNELS_PER_GROUP * len(self._groups)
        self._buf = bytearray()
        self._in_sync = True
        self._step = 0  # index of the setup command awaiting its acknowledgement
        self._step_sent = False
        self.nacked = ""
        self._sequence = 0
        self._last_ms: int | None = None
        self._new_cycle()

    def _new_cycle(self) -> None:
        self._potentials = np.full((self.protocol.n_injections, self._width), np.nan, complex)
        self._stage = 0
        self._missing = set(self._groups)
        self._cycle_bytes = 0
        self._waiting_for_first = False

    def reset(self) -> None:
        super().reset()
        self.stats.discarded_bytes += len(self._buf)
        self._buf.clear()
        self._step, self._step_sent, self.nacked = 0, False, ""
        self._new_cycle()

    def farewell(self) -> bytes:
        return STOP

    def commands(self, now_s: float) -> bytes:
        """The next setup command once the previous one is acknowledged.

        The whole setup again after ``ack_timeout_s`` without an answer.
        """
        if self.acknowledged:
            return b""
        if self._step_sent and now_s - (self._sent_at or 0.0) < self.ack_timeout_s:
            return b""
        if self._step_sent:  # timed out: start over (the board may have restarted)
            self._step = 0
        if self._step == 0:
            self.attempts += 1
        self._sent_at, self._step_sent = now_s, True
        return self.setup[self._step][1]

    def unanswered(self, now_s: float) -> str:
        if self.acknowledged:
            return ""
        name, raw = self.setup[self._step]
        if self.nacked:
            return f"profile sciospec: the board refused {self.nacked}"
        if self.attempts < 2:
            return ""
        seen = repr(self._recent) if self._recent else "nothing"
        return (
            f"profile sciospec: no acknowledgement of {name} ({raw.hex(' ')}) within "
            f"{self.ack_timeout_s:g} s, {self.attempts} tries; saw {seen}"
        )

    def feed(self, data: bytes) -> list[BoardFrame]:
        self.stats.bytes += len(data)
        buf = self._buf
        buf += data
        frames: list[BoardFrame] = []
        pos, n = 0, len(buf)
        while n - pos >= 2:
            run = self._data_run(pos, n)
            if run:  # consecutive data frames: decoded together
                frames += self._stages(np.frombuffer(buf, np.uint8, run * _STAGE, pos))
                pos += run * _STAGE
                continue
            tag = buf[pos]
            length = buf[pos + 1]
            end = pos + 2 + length
            if tag not in KNOWN_TAGS or (end < n and buf[end] != tag):
                self._lose_sync(buf[pos : pos + 1])
                pos += 1
                continue
            if end >= n:
                break  # the rest has not arrived yet
            self._in_sync = True
            self._message(tag, bytes(buf[pos + 2 : end]))
            self.stats.discarded_bytes += length + 3
            pos = end + 1
        del buf[:pos]
        self.stats.frames += len(frames)
        return frames

    def _data_run(self, pos: int, n: int) -> int:
        """How many complete, well-framed data frames follow one another from ``pos``."""
        count = (n - pos) // _STAGE
        if not count or self._buf[pos] != DATA_TAG or self._buf[pos + 1] != DATA_LENGTH:
            return 0
        rows = np.frombuffer(self._buf, np.uint8, count * _STAGE, pos).reshape(count, _STAGE)
        good = (rows[:, 0] == DATA_TAG) & (rows[:, 1] == DATA_LENGTH) & (rows[:, -1] == DATA_TAG)
        run = int(np.argmin(good)) if not good.all() else count
        if run:
            self._in_sync = True
        return run

    def _stages(self, raw: np.ndarray) -> list[BoardFrame]:
        """Data frames ``raw`` [K * 140] bytes -> the drive cycles they complete."""
        rows = raw.reshape(-1, _STAGE)
        head = rows[:, 2:11].astype(np.int64)
        ms = (head[:, 5] << 24) | (head[:, 6] << 16) | (head[:, 7] << 8) | head[:, 8]
        values = rows[:, 11:139].copy().view(_DATA).astype(np.float64)
        potentials = values[:, 0::2] + 1j * values[:, 1::2]  # [K, 16]
        frames = []
        for k in range(len(rows)):
            frame = self._stage_frame(
                int(head[k, 0]), int(head[k, 1]), int(head[k, 2]), int(ms[k]), potentials[k]
            )
            if frame is not None:
                frames.append(frame)
        return frames

    def _lose_sync(self, byte: bytes) -> None:
        self._seen(bytes(byte), start=self._in_sync)
        self.stats.discarded_bytes += 1
        if self._in_sync:
            self._in_sync = False
            self.stats.refused["framing"] += 1
            self.last_refusal = f"byte {self.stats.bytes - len(self._buf)}: lost message framing"

    def _message(self, tag: int, payload: bytes) -> None:
        self.stats.messages += 1
        if tag != SYSTEM_TAG or len(payload) != 1:
            return
        code = payload[0]
        if code == BOOTED:
            self.stats.restarts += 1
            self.acknowledged, self._step, self._step_sent = False, 0, False
            self._new_cycle()
        elif code == ACK and not self.acknowledged and self._step_sent:
            self._step += 1
            self._step_sent = False
            if self._step == len(self.setup):
                self.acknowledged = True
        elif code in (NOT_EXECUTED, NOT_RECOGNISED) and self._step_sent:
            name, raw = self.setup[self._step]
            if self._step == 0:  # stop while not measuring: nothing to stop
                self._step += 1
                self._step_sent = False
                return
            what = "not executed" if code == NOT_EXECUTED else "not recognised"
            self.nacked = f"{name} ({raw.hex(' ')}): {what}"
            self.last_refusal = f"setup command {self.nacked}"

    def _stage_frame(
        self, group: int, es_out: int, es_in: int, ms: int, values: np.ndarray
    ) -> BoardFrame | None:
        """One excitation stage (its 16 complex potentials); the frame it completes, if any."""
        size = _STAGE
        if not self.acknowledged:
            self._refuse("before_start", "data frame before the setup was acknowledged", size)
            return None
        if self._last_ms is not None and ms < self._last_ms:
            self.stats.restarts += 1
            self._drop_cycle("the board's clock ran back (a restart)")
        self._last_ms = ms
        stage = self._stage_of.get((es_out, es_in))
        if stage is None:
            self._refuse(
                "unknown_injection",
                f"stage with excitation {es_out}->{es_in}: not an injection of the protocol",
                size,
            )
            return None
        if group not in self._groups:
            self.stats.discarded_bytes += size  # channels no electrode is wired to
            return None
        if stage == 0 and group == self._groups[0] and (self._stage or self._cycle_bytes):
            self._drop_cycle(f"stage {self._stage} of {self.protocol.n_injections} missing")
        if self._waiting_for_first and stage != 0:
            self.stats.discarded_bytes += size
            return None
        if stage != self._stage or group not in self._missing:
            self._drop_cycle(f"stage {stage} group {group} out of order")
            self.stats.discarded_bytes += size
            self._waiting_for_first = True
            return None
        self._waiting_for_first = False
        column = (group - self._groups[0]) * CHANNELS_PER_GROUP
        self._potentials[stage, column : column + CHANNELS_PER_GROUP] = values
        self._cycle_bytes += size
        self._missing.discard(group)
        if self._missing:
            return None
        self._stage += 1
        self._missing = set(self._groups)
        if self._stage < self.protocol.n_injections:
            return None
        config = np.empty((self.protocol.n_injections, self.protocol.n_electrodes), complex)
        config[:] = self._potentials[:, self._column]
        measured = self.protocol.measure(config)
        self._sequence += 1
        self._new_cycle()
        return BoardFrame(measured, invalid_flags(measured), ms * 1000, self._sequence - 1)

    def _drop_cycle(self, why: str) -> None:
        if self._stage or self._cycle_bytes:
            self._refuse("incomplete", f"drive cycle dropped: {why}", self._cycle_bytes)
        self._new_cycle()
