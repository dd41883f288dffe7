"""The skin board's serial wire protocol: frame encoding and a streaming, resynchronising parser.

One frame carries one drive cycle (e.g. 16 injections x 13 differential voltages = 208 values).
The byte layout is specified in ``docs/wire-protocol.md``; the constants below are its single
source of truth. All multi-byte fields are little-endian.

``FrameParser.feed`` accepts arbitrary chunks of a byte stream, never raises, never emits a frame
whose CRC-32 failed, resynchronises on the next sync word after garbage, truncation or
corruption, keeps bounded memory, and counts every discarded byte and every error by kind.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from eit_skin.frames import FLAG_INVALID

SYNC = b"\xeb\x90"
"""The two sync bytes that start every frame."""
PROTOCOL_VERSION = 1
PREAMBLE = struct.Struct("<2sBBHH")
"""sync, version, value_encoding, value_count M, payload_length (bytes 0..7)."""
PAYLOAD_HEADER = struct.Struct("<IQHBBff")
"""sequence, device_time_us, n_electrodes, pattern_id, pattern_param, current_a,
volts_per_count (bytes 8..31)."""
CRC = struct.Struct("<I")
PREAMBLE_SIZE = PREAMBLE.size  # 8
HEADER_SIZE = PREAMBLE.size + PAYLOAD_HEADER.size  # 32: offset of the first value
CRC_SIZE = CRC.size
BYTES_PER_VALUE = 5  # 4 value bytes + 1 flag byte
MAX_WIRE_VALUES = (0xFFFF - PAYLOAD_HEADER.size) // BYTES_PER_VALUE
"""The largest value count whose payload length fits the uint16 field (13102)."""


class ValueEncoding(IntEnum):
    """How the M values of a frame are encoded."""

    INT32_COUNTS = 0
    """int32 ADC counts (e.g. the sum of 1000 oversampled 12-bit conversions); volts =
    counts x volts_per_count."""
    FLOAT32_VOLTS = 1
    """IEEE-754 float32 volts; the volts_per_count field is 1.0 and ignored."""


class PatternId(IntEnum):
    """The drive pattern the board ran; ``pattern_param`` carries k for SKIP."""

    ADJACENT = 0
    OPPOSITE = 1
    SKIP = 2
    EXPLICIT = 3


def payload_length(n_values: int) -> int:
    """Payload length field (bytes 8 up to the CRC) for ``n_values`` values."""
    return PAYLOAD_HEADER.size + BYTES_PER_VALUE * n_values


def frame_size(n_values: int) -> int:
    """Total bytes of a frame with ``n_values`` values (1076 for 208)."""
    return HEADER_SIZE + BYTES_PER_VALUE * n_values + CRC_SIZE


def _float32_exact(value: float, name: str) -> float:
    as32 = float(np.float32(value))
    if not np.isfinite(as32):
        raise ValueError(f"{name} must be finite as float32, got {value!r}")
    return as32


@dataclass(frozen=True, eq=False)
class DeviceFrame:
    """One decoded drive cycle as sent by the board.

    Attributes:
        sequence: frame counter, uint32, wraps at 2**32.
        device_time_us: device clock at acquisition, microseconds, uint64.
        n_electrodes: electrodes on the driven layer.
        pattern_id: drive pattern the board ran.
        current_a: injected current amplitude, amperes (float32 on the wire).
        voltages_v: float64 [M] differential voltages, volts, read-only.
        flags: uint8 [M] per-channel FLAG_* bitmask, read-only (zeros when omitted).
        pattern_param: k of the SKIP pattern, else 0.
        value_encoding: how the values travel on the wire.
        volts_per_count: volts per ADC count for INT32_COUNTS (float32 on the wire), else 1.0.
    """

    sequence: int
    device_time_us: int
    n_electrodes: int
    pattern_id: PatternId
    current_a: float
    voltages_v: np.ndarray
    flags: np.ndarray | None = None
    pattern_param: int = 0
    value_encoding: ValueEncoding = ValueEncoding.FLOAT32_VOLTS
    volts_per_count: float = 1.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not 0 <= self.sequence < 2**32:
            raise ValueError(f"sequence must be a uint32, got {self.sequence}")
        if not 0 <= self.device_time_us < 2**64:
            raise ValueError(f"device_time_us must be a uint64, got {self.device_time_us}")
        if not 1 <= self.n_electrodes <= 0xFFFF:
            raise ValueError(f"n_electrodes must be in 1..65535, got {self.n_electrodes}")
        if not 0 <= self.pattern_param <= 0xFF:
            raise ValueError(f"pattern_param must be a uint8, got {self.pattern_param}")
        set_(self, "pattern_id", PatternId(self.pattern_id))
        set_(self, "value_encoding", ValueEncoding(self.value_encoding))
        set_(self, "current_a", _float32_exact(self.current_a, "current_a"))
        if self.value_encoding is ValueEncoding.FLOAT32_VOLTS:
            set_(self, "volts_per_count", 1.0)
        else:
            scale = _float32_exact(self.volts_per_count, "volts_per_count")
            if scale <= 0.0:
                raise ValueError(f"volts_per_count must be > 0, got {self.volts_per_count}")
            set_(self, "volts_per_count", scale)
        volts = np.array(self.voltages_v, dtype=np.float64)
        if volts.ndim != 1 or not 0 < volts.size <= MAX_WIRE_VALUES:
            raise ValueError(f"voltages_v must be 1-D with 1..{MAX_WIRE_VALUES} values")
        flags = (
            np.zeros(volts.size, np.uint8)
            if self.flags is None
            else np.array(self.flags, dtype=np.uint8)
        )
        if flags.shape != volts.shape:
            raise ValueError(f"flags shape {flags.shape} != voltages_v shape {volts.shape}")
        volts.setflags(write=False)
        flags.setflags(write=False)
        set_(self, "voltages_v", volts)
        set_(self, "flags", flags)

    @property
    def n_values(self) -> int:
        """M, the number of values."""
        return int(self.voltages_v.size)

    def __eq__(self, other: object) -> bool:
        """Field-wise equality, arrays compared bit-exactly (NaN equals the same NaN)."""
        if not isinstance(other, DeviceFrame):
            return NotImplemented
        return (
            self.sequence == other.sequence
            and self.device_time_us == other.device_time_us
            and self.n_electrodes == other.n_electrodes
            and self.pattern_id == other.pattern_id
            and self.pattern_param == other.pattern_param
            and self.current_a == other.current_a
            and self.value_encoding == other.value_encoding
            and self.volts_per_count == other.volts_per_count
            and self.voltages_v.tobytes() == other.voltages_v.tobytes()
            and self.flags.tobytes() == other.flags.tobytes()
        )

    __hash__ = None  # type: ignore[assignment]


def encode_frame(frame: DeviceFrame) -> bytes:
    """Encode ``frame`` to its wire bytes (``frame_size(M)`` bytes, CRC-32 appended).

    For INT32_COUNTS the voltages are divided by ``volts_per_count`` and rounded to the nearest
    count; non-finite voltages become count 0 with FLAG_INVALID set. Raises ValueError when a
    count does not fit an int32.
    """
    m = frame.n_values
    flags = frame.flags
    if frame.value_encoding is ValueEncoding.FLOAT32_VOLTS:
        values = frame.voltages_v.astype("<f4").tobytes()
    else:
        volts = frame.voltages_v
        finite = np.isfinite(volts)
        counts = np.rint(np.where(finite, volts, 0.0) / frame.volts_per_count)
        if np.any(np.abs(counts) > 2**31 - 1):
            raise ValueError("a voltage exceeds the int32 count range for this volts_per_count")
        values = counts.astype("<i4").tobytes()
        if not finite.all():
            flags = flags | np.where(finite, 0, FLAG_INVALID).astype(np.uint8)
    body = (
        PREAMBLE.pack(SYNC, PROTOCOL_VERSION, frame.value_encoding, m, payload_length(m))
        + PAYLOAD_HEADER.pack(
            frame.sequence,
            frame.device_time_us,
            frame.n_electrodes,
            frame.pattern_id,
            frame.pattern_param,
            frame.current_a,
            frame.volts_per_count,
        )
        + values
        + flags.tobytes()
    )
    return body + CRC.pack(zlib.crc32(body[len(SYNC) :]))


@dataclass
class ParserStats:
    """Running counters of a FrameParser.

    Every byte fed is accounted for: ``bytes == frame_bytes + discarded_bytes + buffered``
    (``buffered`` is the parser's property). Each rejected candidate frame is counted once
    under exactly one of crc_errors, truncated, bad_version, bad_length, bad_header.
    """

    bytes: int = 0
    """Bytes fed."""
    frames: int = 0
    """Frames emitted."""
    frame_bytes: int = 0
    """Bytes belonging to emitted frames."""
    discarded_bytes: int = 0
    """Bytes skipped while searching for sync (garbage and rejected candidates)."""
    resyncs: int = 0
    """Times the parser lost sync and had to skip bytes."""
    crc_errors: int = 0
    """Complete candidate frames whose CRC-32 did not match."""
    truncated: int = 0
    """CRC failures explained by a frame cut short: a valid frame started inside its span."""
    bad_version: int = 0
    """Sync word followed by an unknown protocol version."""
    bad_length: int = 0
    """Value count above the limit, or payload length inconsistent with the value count."""
    bad_header: int = 0
    """Unknown value encoding, or a CRC-valid frame with invalid header fields."""

    @property
    def errors(self) -> int:
        """Total rejected candidate frames."""
        return (
            self.crc_errors + self.truncated + self.bad_version + self.bad_length + self.bad_header
        )


_KNOWN_PATTERNS = frozenset(int(p) for p in PatternId)
_DTYPES = {
    ValueEncoding.INT32_COUNTS: np.dtype("<i4"),
    ValueEncoding.FLOAT32_VOLTS: np.dtype("<f4"),
}


class FrameParser:
    """Streaming parser: bytes in, validated DeviceFrames out.

    Args:
        max_values: largest value count accepted; bounds the buffered bytes to
            ``frame_size(max_values)`` between calls.
    """

    def __init__(self, max_values: int = 4096) -> None:
        if not 1 <= max_values <= MAX_WIRE_VALUES:
            raise ValueError(f"max_values must be in 1..{MAX_WIRE_VALUES}, got {max_values}")
        self.max_values = max_values
        self.stats = ParserStats()
        self._buf = bytearray()
        self._base = 0  # stream offset of self._buf[0]
        self._in_sync = True
        self._crc_fail_end = -1  # stream offset where the last CRC-failed candidate would end
        self._scan = (-1, -1)  # (candidate, scanned-up-to) stream offsets of the lookahead

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after a reconnect); they are counted as discarded."""
        self._discard(len(self._buf))
        self._base += len(self._buf)
        self._buf.clear()
        self._in_sync = True
        self._crc_fail_end = -1

    def _discard(self, n: int) -> None:
        if n <= 0:
            return
        self.stats.discarded_bytes += n
        if self._in_sync:
            self.stats.resyncs += 1
            self._in_sync = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[DeviceFrame]:
        """Consume a chunk of the stream; return the frames it completed, in order. Never raises."""
        stats = self.stats
        buf = self._buf
        buf += data
        stats.bytes += len(data)
        frames: list[DeviceFrame] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # keep a trailing first sync byte: it may start the next sync word
                keep = 1 if n > pos and buf[n - 1] == SYNC[0] else 0
                self._discard(n - keep - pos)
                pos = n - keep
                break
            self._discard(start - pos)
            pos = start
            if n - pos < PREAMBLE_SIZE:
                break
            _, version, encoding, m, length = PREAMBLE.unpack_from(buf, pos)
            if version != PROTOCOL_VERSION:
                stats.bad_version += 1
                self._discard(1)
                pos += 1
                continue
            if encoding > 1:
                stats.bad_header += 1
                self._discard(1)
                pos += 1
                continue
            if m == 0 or m > self.max_values or length != PAYLOAD_HEADER.size + 5 * m:
                stats.bad_length += 1
                self._discard(1)
                pos += 1
                continue
            size = HEADER_SIZE + 5 * m + CRC_SIZE
            if n - pos < size:
                # Incomplete candidate. If a complete valid frame already starts inside its
                # span, the candidate was cut short: drop it now instead of waiting for bytes
                # that belong to later frames.
                if not self._complete_frame_inside(pos, n):
                    break
                stats.truncated += 1
                self._discard(1)
                pos += 1
                continue
            raw = bytes(buf[pos : pos + size])
            if (
                zlib.crc32(memoryview(raw)[2 : size - CRC_SIZE])
                != CRC.unpack_from(raw, size - 4)[0]
            ):
                stats.crc_errors += 1
                self._crc_fail_end = self._base + pos + size
                self._discard(1)
                pos += 1
                continue
            frame = self._decode(raw, encoding, m)
            if frame is None:
                stats.bad_header += 1
                self._discard(1)
                pos += 1
                continue
            if self._base + pos < self._crc_fail_end:
                # the rejected candidate was cut short by this frame: a truncation
                stats.crc_errors -= 1
                stats.truncated += 1
            self._crc_fail_end = -1
            self._in_sync = True
            frames.append(frame)
            stats.frames += 1
            stats.frame_bytes += size
            pos += size
        del buf[:pos]
        self._base += pos
        return frames

    def _complete_frame_inside(self, pos: int, n: int) -> bool:
        """Whether a complete, CRC-valid frame starts after ``pos`` in the buffer.

        Called while the candidate at ``pos`` is incomplete, so everything up to ``n`` lies
        inside its span. Incremental: bytes already scanned for this candidate are skipped,
        except candidates that were still incomplete themselves.
        """
        buf = self._buf
        cand, scanned = self._scan
        start = scanned - self._base if cand == self._base + pos else pos + 1
        resume = -1
        q = buf.find(SYNC, start)
        while q >= 0:
            if q > n - PREAMBLE_SIZE:
                resume = q if resume < 0 else resume
                break
            _, version, encoding, m, length = PREAMBLE.unpack_from(buf, q)
            size = HEADER_SIZE + 5 * m + CRC_SIZE
            if (
                version == PROTOCOL_VERSION
                and encoding <= 1
                and 0 < m <= self.max_values
                and length == PAYLOAD_HEADER.size + 5 * m
            ):
                if n - q < size:
                    resume = q if resume < 0 else resume  # undecided: look again later
                elif (
                    zlib.crc32(bytes(buf[q + 2 : q + size - CRC_SIZE]))
                    == CRC.unpack_from(buf, q + size - CRC_SIZE)[0]
                ):
                    self._scan = (-1, -1)
                    return True
            q = buf.find(SYNC, q + 1)
        if resume < 0:
            resume = max(n - 1, pos + 1)  # a first sync byte may end the buffer
        self._scan = (self._base + pos, self._base + resume)
        return False

    @staticmethod
    def _decode(raw: bytes, encoding: int, m: int) -> DeviceFrame | None:
        seq, t_us, n_el, pattern, param, current, scale = PAYLOAD_HEADER.unpack_from(raw, 8)
        enc = ValueEncoding(encoding)
        if (
            n_el == 0
            or pattern not in _KNOWN_PATTERNS
            or not np.isfinite(current)
            or (enc is ValueEncoding.INT32_COUNTS and not (np.isfinite(scale) and scale > 0.0))
        ):
            return None
        values = np.frombuffer(raw, _DTYPES[enc], m, HEADER_SIZE)
        flags = np.frombuffer(raw, np.uint8, m, HEADER_SIZE + 4 * m).copy()
        if enc is ValueEncoding.INT32_COUNTS:
            volts = values * scale  # float64: exact count x float32 scale
        else:
            volts = values.astype(np.float64)
            bad = ~np.isfinite(volts)
            if bad.any():
                flags[bad] |= FLAG_INVALID
        flags.setflags(write=False)
        volts.setflags(write=False)
        frame = DeviceFrame.__new__(DeviceFrame)
        # fields are validated by construction of the wire format: skip __post_init__
        for name, value in (
            ("sequence", seq),
            ("device_time_us", t_us),
            ("n_electrodes", n_el),
            ("pattern_id", PatternId(pattern)),
            ("current_a", current),
            ("voltages_v", volts),
            ("flags", flags),
            ("pattern_param", param),
            ("value_encoding", enc),
            ("volts_per_count", scale if enc is ValueEncoding.INT32_COUNTS else 1.0),
        ):
            object.__setattr__(frame, name, value)
        return frame
