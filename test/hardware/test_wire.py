"""Wire protocol: layout, round trips, the parser's resynchronisation and its error counters."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from eit_skin.frames import FLAG_INVALID, FLAG_SATURATED
from eit_skin.hardware.wire import (
    HEADER_SIZE,
    SYNC,
    DeviceFrame,
    FrameParser,
    PatternId,
    ValueEncoding,
    encode_frame,
    frame_size,
)

DOC = Path(__file__).resolve().parents[2] / "docs" / "wire-protocol.md"
SCALE = float(np.float32(3.3 / 4096 / 1000))


def make_frame(seq: int, m: int = 208, encoding: ValueEncoding = ValueEncoding.FLOAT32_VOLTS):
    rng = np.random.default_rng(seq)
    if encoding is ValueEncoding.FLOAT32_VOLTS:
        volts = rng.normal(0.0, 0.05, m).astype(np.float32).astype(np.float64)
        scale = 1.0
    else:
        volts = rng.integers(-4_095_000, 4_095_001, m) * SCALE
        scale = SCALE
    flags = rng.integers(0, 2, m).astype(np.uint8) * FLAG_SATURATED
    return DeviceFrame(
        sequence=seq,
        device_time_us=1_000_000 + 10_000 * seq,
        n_electrodes=16,
        pattern_id=PatternId.ADJACENT,
        current_a=1e-3,
        voltages_v=volts,
        flags=flags,
        value_encoding=encoding,
        volts_per_count=scale,
    )


def check_accounting(parser: FrameParser) -> None:
    s = parser.stats
    assert s.bytes == s.frame_bytes + s.discarded_bytes + parser.buffered


def doc_example_frame() -> DeviceFrame:
    """The worked example of docs/wire-protocol.md (4 electrodes, adjacent, int32 counts)."""
    return DeviceFrame(
        sequence=42,
        device_time_us=1_234_567,
        n_electrodes=4,
        pattern_id=PatternId.ADJACENT,
        current_a=1e-3,
        voltages_v=np.array([1_000_000, -250_000, 4_095_000, 0]) * SCALE,
        flags=np.array([0, 0, FLAG_SATURATED, 0], np.uint8),
        value_encoding=ValueEncoding.INT32_COUNTS,
        volts_per_count=3.3 / 4096 / 1000,
    )


@pytest.mark.parametrize("encoding", list(ValueEncoding))
def test_round_trip_is_bit_exact(encoding):
    frames = [make_frame(i, encoding=encoding) for i in range(5)]
    data = b"".join(encode_frame(f) for f in frames)
    assert len(data) == 5 * frame_size(208) == 5 * 1076
    parser = FrameParser()
    out = parser.feed(data)
    assert out == frames
    assert [encode_frame(f) for f in out] == [encode_frame(f) for f in frames]
    assert parser.stats.frames == 5 and parser.stats.errors == 0 and parser.buffered == 0
    check_accounting(parser)


def test_layout_matches_the_specification():
    frame = make_frame(7, m=3, encoding=ValueEncoding.INT32_COUNTS)
    raw = encode_frame(frame)
    assert raw[:2] == SYNC == b"\xeb\x90"
    assert raw[2] == 1 and raw[3] == 0  # version, encoding
    assert struct.unpack_from("<HH", raw, 4) == (3, 24 + 5 * 3)
    seq, t_us, n_el, pattern, param = struct.unpack_from("<IQHBB", raw, 8)
    assert (seq, t_us, n_el, pattern, param) == (7, 1_070_000, 16, 0, 0)
    assert struct.unpack_from("<ff", raw, 24) == (np.float32(1e-3), np.float32(SCALE))
    counts = np.frombuffer(raw, "<i4", 3, HEADER_SIZE)
    np.testing.assert_array_equal(counts * SCALE, frame.voltages_v)
    np.testing.assert_array_equal(np.frombuffer(raw, np.uint8, 3, HEADER_SIZE + 12), frame.flags)
    assert struct.unpack_from("<I", raw, len(raw) - 4)[0] == zlib.crc32(raw[2:-4])
    assert len(raw) == frame_size(3) == 36 + 5 * 3


def test_doc_example_hex_parses_to_the_documented_frame():
    text = DOC.read_text()
    block = re.search(r"<!-- example-frame-hex -->\s*```text\n(.*?)```", text, re.S)
    assert block, "docs/wire-protocol.md lost its example-frame-hex block"
    hex_bytes = bytes.fromhex(re.sub(r"(?m)^[0-9a-f]{4}:", "", block.group(1)).replace("\n", ""))
    expected = doc_example_frame()
    assert hex_bytes == encode_frame(expected)
    (frame,) = FrameParser().feed(hex_bytes)
    assert frame == expected
    assert frame.voltages_v[2] == pytest.approx(3.299194, abs=1e-6)  # the doc's decoded table


def test_byte_by_byte_feed_gives_the_same_frames():
    frames = [make_frame(i, m=20) for i in range(3)]
    data = b"".join(encode_frame(f) for f in frames)
    parser = FrameParser()
    out = [f for b in data for f in parser.feed(bytes([b]))]
    assert out == frames
    check_accounting(parser)


def test_garbage_between_frames_is_counted_and_skipped():
    a, b = make_frame(1, m=10), make_frame(2, m=10)
    garbage = b"\x00\x01hello\xeb\xeb"
    parser = FrameParser()
    out = parser.feed(b"xyz" + encode_frame(a) + garbage + encode_frame(b))
    assert out == [a, b]
    assert parser.stats.discarded_bytes == 3 + len(garbage)
    assert parser.stats.resyncs == 2
    assert parser.stats.errors == 0
    check_accounting(parser)


def test_bad_crc_is_rejected_and_the_next_frame_survives():
    a, b, c = (make_frame(i, m=10) for i in range(3))
    bad = bytearray(encode_frame(b))
    bad[HEADER_SIZE + 5] ^= 0x10
    parser = FrameParser()
    assert parser.feed(encode_frame(a) + bytes(bad) + encode_frame(c)) == [a, c]
    assert parser.stats.crc_errors == 1 and parser.stats.truncated == 0
    assert parser.stats.discarded_bytes == len(bad)
    check_accounting(parser)


def test_truncated_frame_is_counted_as_truncation():
    a, b, c = (make_frame(i, m=30) for i in range(3))
    cut = encode_frame(b)[:100]
    parser = FrameParser()
    assert parser.feed(encode_frame(a) + cut + encode_frame(c)) == [a, c]
    assert parser.stats.truncated == 1 and parser.stats.crc_errors == 0
    assert parser.stats.discarded_bytes == 100
    check_accounting(parser)


def test_every_single_bit_flip_is_rejected():
    before, victim, after = (
        make_frame(i, m=4, encoding=ValueEncoding.INT32_COUNTS) for i in range(3)
    )
    raw = encode_frame(victim)
    head, tail = encode_frame(before), encode_frame(after)
    for bit in range(8 * len(raw)):
        flipped = bytearray(raw)
        flipped[bit // 8] ^= 1 << (bit % 8)
        parser = FrameParser()
        assert parser.feed(head + bytes(flipped) + tail) == [before, after], f"bit {bit}"
        assert parser.stats.errors + parser.stats.resyncs >= 1
        check_accounting(parser)


def test_header_errors_are_counted_by_kind():
    good = make_frame(0, m=8)
    raw = encode_frame(good)

    def reseal(data: bytearray) -> bytes:
        data[-4:] = struct.pack("<I", zlib.crc32(bytes(data[2:-4])))
        return bytes(data)

    cases = {
        "bad_version": bytearray(raw[:2] + b"\x02" + raw[3:]),
        "bad_header": bytearray(raw[:3] + b"\x07" + raw[4:]),  # unknown value encoding
        "bad_length": bytearray(raw[:6] + struct.pack("<H", 25) + raw[8:]),
    }
    pattern = bytearray(raw)
    pattern[22] = 9  # unknown pattern id, CRC re-sealed: a firmware bug, not line noise
    cases_sealed = {"bad_header": reseal(pattern)}
    for kind, data in [*cases.items(), *cases_sealed.items()]:
        parser = FrameParser()
        assert parser.feed(bytes(data) + raw) == [good], kind
        assert getattr(parser.stats, kind) == 1, kind
        assert parser.stats.errors == 1, kind
        check_accounting(parser)


def test_value_count_above_limit_is_bad_length_and_memory_stays_bounded():
    parser = FrameParser(max_values=300)
    big = encode_frame(make_frame(0, m=301))
    assert parser.feed(big) == []
    assert parser.stats.bad_length == 1
    # a header announcing the maximum size: held, but never more than one frame's bytes
    header_only = encode_frame(make_frame(1, m=300))[:40]
    parser.feed(header_only)
    assert parser.buffered == 40
    parser.feed(np.random.default_rng(0).integers(0, 256, 200_000, dtype=np.uint8).tobytes())
    assert parser.buffered < frame_size(300)
    check_accounting(parser)


def test_non_finite_float_values_are_flagged_invalid():
    raw = bytearray(encode_frame(make_frame(0, m=4)))
    raw[HEADER_SIZE + 4 : HEADER_SIZE + 8] = struct.pack("<f", float("nan"))
    raw[-4:] = struct.pack("<I", zlib.crc32(bytes(raw[2:-4])))
    (frame,) = FrameParser().feed(bytes(raw))
    assert np.isnan(frame.voltages_v[1])
    assert frame.flags[1] & FLAG_INVALID
    assert not frame.flags[[0, 2, 3]].any() & FLAG_INVALID


def test_counts_encoding_rounds_to_the_nearest_count():
    frame = DeviceFrame(
        0,
        0,
        16,
        PatternId.ADJACENT,
        1e-3,
        np.array([2.4 * SCALE, -0.6 * SCALE, np.nan]),
        value_encoding=ValueEncoding.INT32_COUNTS,
        volts_per_count=SCALE,
    )
    (out,) = FrameParser().feed(encode_frame(frame))
    np.testing.assert_array_equal(out.voltages_v, [2 * SCALE, -1 * SCALE, 0.0])
    np.testing.assert_array_equal(out.flags, [0, 0, FLAG_INVALID])


def test_encode_rejects_counts_out_of_int32_range():
    frame = DeviceFrame(
        0,
        0,
        16,
        PatternId.ADJACENT,
        1e-3,
        np.array([3e9 * SCALE]),
        value_encoding=ValueEncoding.INT32_COUNTS,
        volts_per_count=SCALE,
    )
    with pytest.raises(ValueError, match="int32"):
        encode_frame(frame)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sequence": 2**32}, "sequence"),
        ({"device_time_us": -1}, "device_time_us"),
        ({"n_electrodes": 0}, "n_electrodes"),
        ({"current_a": float("inf")}, "current_a"),
        ({"voltages_v": np.zeros((2, 2))}, "voltages_v"),
        ({"flags": np.zeros(3, np.uint8)}, "flags"),
        ({"pattern_id": 17}, "PatternId"),
    ],
)
def test_device_frame_validation(kwargs, match):
    base = {
        "sequence": 0,
        "device_time_us": 0,
        "n_electrodes": 16,
        "pattern_id": 0,
        "current_a": 1e-3,
        "voltages_v": np.zeros(4),
    }
    with pytest.raises(ValueError, match=match):
        DeviceFrame(**{**base, **kwargs})


def test_a_truncated_header_does_not_delay_a_shorter_frame_behind_it():
    long_frame, short = make_frame(1, m=208), make_frame(2, m=2)
    parser = FrameParser()
    assert parser.feed(encode_frame(long_frame)[:40] + encode_frame(short)) == [short]
    assert parser.stats.truncated == 1 and parser.buffered == 0
    check_accounting(parser)
