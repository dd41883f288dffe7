"""Property tests of FrameParser on corrupted streams (hypothesis, derandomized for CI)."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eit_skin.hardware.wire import DeviceFrame, FrameParser, PatternId, ValueEncoding, encode_frame

FUZZ = settings(
    derandomize=True,
    deadline=None,
    max_examples=300,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
SCALE = float(np.float32(1e-6))


@st.composite
def frames(draw, max_values: int = 40) -> DeviceFrame:
    """A valid frame; values come from a drawn seed (fast for 208 values) plus drawn extremes."""
    m = draw(st.integers(1, max_values))
    encoding = draw(st.sampled_from(list(ValueEncoding)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if encoding is ValueEncoding.FLOAT32_VOLTS:
        volts = rng.normal(0.0, draw(st.sampled_from([1e-3, 1.0, 1e30])), m).astype(np.float32)
        volts[0] = draw(st.floats(width=32, allow_nan=False, allow_infinity=False))
        volts = volts.astype(np.float64)
    else:
        counts = rng.integers(-(2**31) + 1, 2**31, m)
        counts[0] = draw(st.integers(-(2**31) + 1, 2**31 - 1))
        volts = counts * SCALE
    return DeviceFrame(
        sequence=draw(st.integers(0, 2**32 - 1)),
        device_time_us=draw(st.integers(0, 2**64 - 1)),
        n_electrodes=draw(st.integers(1, 64)),
        pattern_id=draw(st.sampled_from(list(PatternId))),
        pattern_param=draw(st.integers(0, 255)),
        current_a=draw(st.floats(width=32, allow_nan=False, allow_infinity=False)),
        voltages_v=volts,
        flags=rng.integers(0, 4, m).astype(np.uint8),
        value_encoding=encoding,
        volts_per_count=SCALE,
    )


def feed_in_chunks(parser: FrameParser, data: bytes, cuts: list[int]) -> list[DeviceFrame]:
    bounds = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    out: list[DeviceFrame] = []
    for lo, hi in itertools.pairwise(bounds):
        out += parser.feed(data[lo:hi])
    return out


def check_accounting(parser: FrameParser) -> None:
    s = parser.stats
    assert s.bytes == s.frame_bytes + s.discarded_bytes + parser.buffered
    assert s.frames * 36 <= s.frame_bytes


@FUZZ
@given(st.binary(max_size=4000), st.lists(st.integers(0, 4000), max_size=8))
def test_random_bytes_never_raise_and_never_make_frames(data, cuts):
    parser = FrameParser()
    assert feed_in_chunks(parser, data, cuts) == []
    check_accounting(parser)
    assert parser.buffered <= len(data)


@FUZZ
@given(
    st.lists(st.tuples(frames(), st.binary(max_size=60)), min_size=1, max_size=6),
    st.lists(st.integers(0, 10_000), max_size=10),
)
def test_frames_interleaved_with_garbage_all_come_through(pairs, cuts):
    data = b"".join(g + encode_frame(f) for f, g in pairs)
    parser = FrameParser()
    out = feed_in_chunks(parser, data, cuts)
    assert out == [f for f, _ in pairs]
    assert parser.stats.frame_bytes == sum(len(encode_frame(f)) for f, _ in pairs)
    assert parser.buffered == 0
    check_accounting(parser)


@FUZZ
@given(
    st.lists(st.tuples(frames(), st.one_of(st.none(), st.integers(0, 10_000))), max_size=6),
    frames(),
    st.lists(st.integers(0, 10_000), max_size=6),
)
def test_truncated_frames_are_dropped_and_whole_ones_survive(items, last, cuts):
    data = b""
    whole = []
    for frame, cut in items:
        raw = encode_frame(frame)
        if cut is None:
            data += raw
            whole.append(frame)
        else:
            data += raw[: cut % len(raw)]
    data += encode_frame(last)  # a complete frame at the end flushes any pending candidate
    parser = FrameParser()
    assert feed_in_chunks(parser, data, cuts) == [*whole, last]
    assert parser.buffered == 0
    check_accounting(parser)


@FUZZ
@given(st.lists(frames(), min_size=1, max_size=5), st.data())
def test_a_single_bit_flip_loses_at_most_the_damaged_frame(sent, data):
    raws = [encode_frame(f) for f in sent]
    k = data.draw(st.integers(0, len(sent) - 1))
    bit = data.draw(st.integers(0, 8 * len(raws[k]) - 1))
    damaged = bytearray(raws[k])
    damaged[bit // 8] ^= 1 << (bit % 8)
    raws[k] = bytes(damaged)
    stream = b"".join(raws) + encode_frame(sent[0])  # trailing good frame flushes the damage
    parser = FrameParser()
    out = feed_in_chunks(parser, stream, data.draw(st.lists(st.integers(0, 10_000), max_size=6)))
    assert out == [f for i, f in enumerate(sent) if i != k] + [sent[0]]
    assert parser.stats.errors + parser.stats.resyncs >= 1
    check_accounting(parser)


@FUZZ
@given(
    st.lists(frames(max_values=208), min_size=1, max_size=8), st.lists(st.integers(), max_size=20)
)
def test_glued_frames_with_random_chunking(sent, cuts):
    data = b"".join(encode_frame(f) for f in sent)
    parser = FrameParser()
    assert feed_in_chunks(parser, data, [abs(c) for c in cuts]) == sent
    s = parser.stats
    assert (s.frames, s.discarded_bytes, s.errors, s.resyncs) == (len(sent), 0, 0, 0)
    check_accounting(parser)
