"""MCAP (ROS 2 encoding) and npz recordings: round trips, schema, validation errors, crashes."""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

from eit_skin.cli.main import main
from eit_skin.frames import FrameRecord
from eit_skin.hardware.sources import ReplaySource
from eit_skin.io.cdr import (
    EIT_FRAME_SCHEMA,
    Float32ImageCdr,
    decode_eit_frame_cdr,
    eit_frame_msgdef,
    encode_eit_frame_cdr,
    read_eit_frame,
)
from eit_skin.io.conversion import FrameStream, mcap_to_npz, npz_to_mcap
from eit_skin.io.mcap import McapFrameWriter, read_mcap_frames
from eit_skin.io.npz import load_frames_npz, save_frames_npz

TOPIC = "/arm/pressure/frames"


def record(i: int, m: int = 208) -> FrameRecord:
    rng = np.random.default_rng(i)
    volts = rng.normal(0, 0.1, m).astype(np.float32)
    volts[3] = np.nan
    flags = rng.integers(0, 3, m).astype(np.uint8)
    return FrameRecord(
        stamp_ns=1_700_000_000_000_000_000 + 20_000_000 * i + 7,
        frame_id="arm_link",
        patch="arm",
        layer="pressure",
        n_electrodes=16,
        drive_pattern="adjacent",
        current_a=1.25e-3,
        sequence=2**32 - 3 + i if i < 3 else i,
        voltages=volts,
        channel_flags=flags,
    )


def test_mcap_round_trip_is_identical(tmp_path):
    path = tmp_path / "frames.mcap"
    written = [record(i) for i in range(30)]
    with McapFrameWriter(path) as writer:
        for i, rec in enumerate(written):
            writer.write(
                TOPIC if i % 3 else "/leg/stretch/frames", rec, log_time_ns=rec.stamp_ns + 5
            )
    back = list(read_mcap_frames(path))
    assert [r for _, _, r in back] == written
    assert [t for _, t, _ in back] == [r.stamp_ns + 5 for r in written]
    assert [topic for topic, _, _ in back] == [
        TOPIC if i % 3 else "/leg/stretch/frames" for i in range(30)
    ]
    assert [r for _, _, r in read_mcap_frames(path, [TOPIC])] == [
        r for i, r in enumerate(written) if i % 3
    ]


def test_mcap_schema_and_ros2_decoder(tmp_path):
    path = tmp_path / "frames.mcap"
    written = [record(i) for i in range(4)]
    with McapFrameWriter(path) as writer:
        for rec in written:
            writer.write(TOPIC, rec)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        (schema,) = summary.schemas.values()
        (channel,) = summary.channels.values()
        assert schema.name == EIT_FRAME_SCHEMA == "eit_skin_msgs/msg/EitFrame"
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
        assert reader.get_header().profile == "ros2"
        decoded = [msg for _, _, _, msg in reader.iter_decoded_messages()]
    for msg, rec in zip(decoded, written, strict=True):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == rec.stamp_ns
        assert msg.header.frame_id == "arm_link" and msg.sequence == rec.sequence
        assert (msg.patch, msg.layer, msg.drive_pattern) == ("arm", "pressure", "adjacent")
        assert msg.n_electrodes == 16 and msg.current_a == 1.25e-3
        assert np.array(msg.voltages, np.float32).tobytes() == rec.voltages.tobytes()
        assert bytes(msg.channel_flags) == rec.channel_flags.tobytes()


def test_msgdef_is_the_rosbag2_concatenation():
    text = eit_frame_msgdef()
    with open(Path(__file__).resolve().parents[2] / "msg" / "EitFrame.msg") as f:
        assert text.startswith(f.read().rstrip("\n"))
    sep = "=" * 80
    assert f"\n{sep}\nMSG: std_msgs/Header\n" in text
    assert f"\n{sep}\nMSG: builtin_interfaces/Time\n" in text
    assert "builtin_interfaces/Time stamp" in text and "uint32 nanosec" in text


def test_cdr_matches_the_reference_serialisers():
    rec = record(5, m=13)
    as_dict = {
        "header": {
            "stamp": {"sec": rec.stamp_ns // 10**9, "nanosec": rec.stamp_ns % 10**9},
            "frame_id": rec.frame_id,
        },
        "patch": rec.patch,
        "layer": rec.layer,
        "n_electrodes": rec.n_electrodes,
        "drive_pattern": rec.drive_pattern,
        "current_a": rec.current_a,
        "sequence": rec.sequence,
        "voltages": rec.voltages.tolist(),
        "channel_flags": rec.channel_flags.tobytes(),
    }
    encoder = serialize_dynamic(EIT_FRAME_SCHEMA, eit_frame_msgdef())[EIT_FRAME_SCHEMA]
    assert encode_eit_frame_cdr(rec) == encoder(as_dict)
    assert decode_eit_frame_cdr(encode_eit_frame_cdr(rec)) == rec


def test_real_eit_frame_messages():
    msgs = pytest.importorskip("eit_skin_msgs.msg")
    serialization = pytest.importorskip("rclpy.serialization")
    rec = record(1, m=20)
    msg = rec.to_msg()
    assert isinstance(msg, msgs.EitFrame)
    assert FrameRecord.from_msg(msg) == rec
    # rclpy leaves alignment padding uninitialised, so compare through both decoders
    assert decode_eit_frame_cdr(serialization.serialize_message(msg)) == rec
    back = serialization.deserialize_message(encode_eit_frame_cdr(rec), msgs.EitFrame)
    assert FrameRecord.from_msg(back) == rec


def _cdr(rec: FrameRecord, order: str) -> bytes:
    """An EitFrame as plain CDR in byte order ``order`` ("<" or ">"), written field by field
    from the message definition (alignment counted after the 4-byte header)."""
    out = bytearray(b"\x00\x01\x00\x00" if order == "<" else b"\x00\x00\x00\x00")

    def put(fmt: str, *values) -> None:
        size = struct.calcsize(fmt)
        out.extend(b"\x00" * (-(len(out) - 4) % size))
        out.extend(struct.pack(order + fmt, *values))

    def text(value: str) -> None:
        put("I", len(value) + 1)
        out.extend(value.encode() + b"\x00")

    put("iI", *divmod(rec.stamp_ns, 10**9))
    text(rec.frame_id)
    text(rec.patch)
    text(rec.layer)
    put("H", rec.n_electrodes)
    text(rec.drive_pattern)
    put("d", rec.current_a)
    put("I", rec.sequence)
    put("I", rec.voltages.size)
    out.extend(rec.voltages.astype(order + "f4").tobytes())
    put("I", rec.channel_flags.size)
    out.extend(rec.channel_flags.tobytes())
    return bytes(out)


NAMES = [
    ("arm_link", "arm", "pressure", "adjacent"),
    ("", "", "", ""),
    ("a", "bc", "def", "skip-2"),
    ("abc", "d", "ef", "g"),
]


@pytest.mark.parametrize("names", NAMES)
def test_frames_are_read_from_cdr_of_either_byte_order_with_every_string_length(names):
    """``read_eit_frame`` (the reconstruction node's decoder): every padding case of the four
    strings before the double, little- and big-endian, and rclpy's own bytes."""
    serialization = pytest.importorskip("rclpy.serialization")
    frame_id, patch, layer, pattern = names
    base = record(4, m=24)
    rec = FrameRecord(base.stamp_ns, frame_id, patch, layer, 16, pattern, 2.5e-4, 7,
                      base.voltages, base.channel_flags)  # fmt: skip
    little = _cdr(rec, "<")
    assert little == encode_eit_frame_cdr(rec)  # the helper writes what the codec writes
    for data in (little, _cdr(rec, ">"), serialization.serialize_message(rec.to_msg())):
        assert decode_eit_frame_cdr(data) == rec
        fields = read_eit_frame(data)
        assert (fields.stamp_ns, fields.sequence, fields.drive_pattern) == (
            rec.stamp_ns, 7, pattern)  # fmt: skip
        assert not fields.voltages.flags.writeable


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "arm_link", "ünï"])
def test_image_bytes_are_a_sensor_msgs_image_for_every_frame_id_length(frame_id):
    """The node's float images go out as bytes (Float32ImageCdr): rclpy reads them as the
    Image it would have serialised itself (every padding case of frame_id and encoding),
    stamped and filled anew per frame in the same bytes."""
    serialization = pytest.importorskip("rclpy.serialization")
    from sensor_msgs.msg import Image

    cdr = Float32ImageCdr(3, 5, frame_id)
    assert cdr.fits(3, 5, frame_id) and not cdr.fits(5, 3, frame_id)
    assert not cdr.fits(3, 5, frame_id + "x")
    for sec, nanosec, scale in ((-5, 999_999_999, 1.0), (1_800_000_000, 7, -2.5)):
        image = scale * np.arange(15, dtype=np.float32).reshape(3, 5) - 0.5
        image[1, 2] = np.nan
        data = cdr.fill(sec, nanosec, image.astype(np.float64))
        msg = serialization.deserialize_message(data, Image)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (sec, nanosec)
        assert msg.header.frame_id == frame_id
        assert (msg.height, msg.width, msg.encoding, msg.step) == (3, 5, "32FC1", 20)
        assert msg.is_bigendian == 0
        assert bytes(msg.data) == image.astype("<f4").tobytes()
        assert len(serialization.serialize_message(msg)) == len(data)


def test_truncated_or_foreign_bytes_are_refused_with_the_byte_offset():
    data = encode_eit_frame_cdr(record(3, m=12))
    for cut in range(len(data)):
        with pytest.raises(ValueError, match=r"^byte \d+: "):
            read_eit_frame(data[:cut])
    with pytest.raises(ValueError, match="byte 0: not a plain CDR EitFrame"):
        read_eit_frame(b"\x00\x03" + data[2:])  # XCDR2 / parameter-list encapsulation


def test_writer_accepts_ros_messages(tmp_path):
    pytest.importorskip("eit_skin_msgs.msg")
    rec = record(2)
    with McapFrameWriter(tmp_path / "m.mcap") as writer:
        writer.write(TOPIC, rec.to_msg(), log_time_ns=42)
    ((topic, log_time, back),) = read_mcap_frames(tmp_path / "m.mcap")
    assert (topic, log_time, back) == (TOPIC, 42, rec)


def test_npz_round_trip_and_atomic_write(tmp_path):
    rng = np.random.default_rng(0)
    ref, frames, t = rng.normal(size=208), rng.normal(size=(5, 208)), np.arange(5) * 0.02
    frames[2, 7] = np.nan  # missing values in frames are allowed
    path = tmp_path / "run.npz"
    save_frames_npz(path, ref, frames, t)
    r2, f2, t2 = load_frames_npz(path, n_measurements=208)
    np.testing.assert_array_equal(r2, ref)
    np.testing.assert_array_equal(f2, frames)
    np.testing.assert_array_equal(t2, t)
    save_frames_npz(path, ref, frames)  # overwrite, no t
    assert load_frames_npz(path)[2] is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]


@pytest.mark.parametrize(
    ("arrays", "n", "match"),
    [
        ({"frames": np.zeros((2, 4))}, None, "missing key 'reference'"),
        ({"reference": np.zeros(4)}, None, "missing key 'frames'"),
        ({"reference": np.zeros((4, 1)), "frames": np.zeros((2, 4))}, None, "'reference'.*shape"),
        ({"reference": np.zeros(4), "frames": np.zeros((2, 5))}, None, "'frames'.*shape"),
        (
            {"reference": np.zeros(2), "frames": np.zeros((2, 2)), "t": [0, np.nan]},
            None,
            "'t'.*finite",
        ),
        ({"reference": np.zeros(4), "frames": np.zeros((1, 4))}, 208, "M=4.*208"),
        ({"reference": np.zeros(4), "frames": np.zeros((2, 4)), "t": np.zeros(3)}, None, "'t'"),
        ({"reference": np.array(["a"]), "frames": np.zeros((1, 1))}, None, "'reference'.*real"),
    ],
)
def test_npz_errors_name_the_file_and_key(tmp_path, arrays, n, match):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=match) as info:
        load_frames_npz(path, n_measurements=n)
    assert str(path) in str(info.value)


def test_npz_not_an_archive(tmp_path):
    path = tmp_path / "junk.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"junk\.npz"):
        load_frames_npz(path)


def test_npz_mcap_npz_conversion(tmp_path):
    rng = np.random.default_rng(1)
    frames = rng.normal(0, 0.1, (6, 208)).astype(np.float32).astype(np.float64)
    frames[4, 10] = np.nan
    t = 1_700_000_000.0 + np.arange(6) * 0.02
    save_frames_npz(tmp_path / "a.npz", frames[0], frames, t)
    stream = FrameStream(TOPIC, patch="arm", layer="pressure", n_electrodes=16)
    n = npz_to_mcap(tmp_path / "a.npz", tmp_path / "a.mcap", stream)
    assert n == 6
    ((_, _, rec4),) = [x for x in read_mcap_frames(tmp_path / "a.mcap") if x[2].sequence == 4]
    assert rec4.channel_flags[10] == 2 and rec4.patch == "arm"
    assert mcap_to_npz(tmp_path / "a.mcap", tmp_path / "b.npz", reference_frames=2) == 6
    ref, back, t_back = load_frames_npz(tmp_path / "b.npz")
    np.testing.assert_array_equal(back, frames)
    np.testing.assert_allclose(t_back, t, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ref, (frames[0] + frames[1]) / 2)


def test_mcap_to_npz_needs_a_topic_when_several(tmp_path):
    with McapFrameWriter(tmp_path / "two.mcap") as writer:
        writer.write("/a/frames", record(0))
        writer.write("/b/frames", record(1))
    with pytest.raises(ValueError, match="reference_frames"):  # channel 3 is NaN: no reference
        mcap_to_npz(tmp_path / "two.mcap", tmp_path / "x.npz", topic="/b/frames")
    clean = FrameRecord(**{**vars(record(1)), "voltages": np.zeros(208), "channel_flags": []})
    with McapFrameWriter(tmp_path / "two.mcap") as writer:
        writer.write("/a/frames", record(0))
        writer.write("/b/frames", clean)
    with pytest.raises(ValueError, match="several EitFrame topics"):
        mcap_to_npz(tmp_path / "two.mcap", tmp_path / "x.npz")
    assert mcap_to_npz(tmp_path / "two.mcap", tmp_path / "x.npz", topic="/b/frames") == 1


def test_export_makes_flagged_values_missing_even_when_stuck(tmp_path):
    """Saturated and invalid values become NaN (the pipeline's missing values); a channel stuck
    at the rail in every frame keeps a finite placeholder reference, so export still works."""
    flags = np.zeros((2, 208), np.uint8)
    flags[:, [7, 9]] = [1, 2]  # saturated, invalid: in every frame
    flags[1, 11] = 1
    frames = [
        FrameRecord(**{**vars(record(i)), "voltages": np.full(208, 0.5 + i), "channel_flags": f})
        for i, f in enumerate(flags)
    ]
    with McapFrameWriter(tmp_path / "stuck.mcap") as writer:
        for rec in frames:
            writer.write(TOPIC, rec)
    assert mcap_to_npz(tmp_path / "stuck.mcap", tmp_path / "stuck.npz", reference_frames=2) == 2
    ref, back, _ = load_frames_npz(tmp_path / "stuck.npz")
    assert np.isnan(back[:, [7, 9]]).all() and np.isnan(back[1, 11]) and back[0, 11] == 0.5
    assert np.isnan(back).sum() == 5
    np.testing.assert_array_equal(ref[[7, 9, 11, 12]], [1.0, 1.0, 0.5, 1.0])


# --- crash safety: killed recorders and cut files ---------------------------------------------

RECORDER = """
import sys, time
import numpy as np
from eit_skin.cli.main import main
from eit_skin.frames import FrameRecord
from eit_skin.hardware.sources import ReplaySource
from eit_skin.io.mcap import McapFrameWriter

writer = McapFrameWriter(sys.argv[1])  # default bounds: what the driver records with
flushed, i = 0, 0
while True:
    now = time.time_ns()
    volts = np.random.default_rng(i).normal(0.0, 0.1, 208)
    frame = FrameRecord(now, "arm_skin_link", "arm", "pressure", 16, "adjacent", 1e-3, i, volts, [])
    writer.write("/arm/pressure/frames", frame, log_time_ns=now)
    print("wrote", i, now, flush=True)
    if writer.flushed_messages != flushed:
        flushed = writer.flushed_messages
        print("flushed", flushed, flush=True)
    i += 1
    time.sleep(0.01)  # a 100 Hz source
"""


def test_sigkill_loses_at_most_the_last_second(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    child = subprocess.Popen(
        [sys.executable, "-c", RECORDER, str(path)], stdout=subprocess.PIPE, text=True
    )
    lines = []
    try:
        # The events, printed by the child: >= 150 frames (1.5 s) on disk, then 120 more
        # frames written (>= 1.2 s at 100 Hz), so the kill falls anywhere between flushes.
        flushed, last = 0, -1
        while flushed < 150 or last < flushed + 120:
            lines.append(child.stdout.readline())
            assert lines[-1], f"recorder exited with {child.wait()}"
            word, number = lines[-1].split()[:2]
            if word == "flushed" and flushed < 150:
                flushed = int(number)
            last = int(number) if word == "wrote" else last
            assert last < 3000, f"only {flushed} of {last + 1} frames flushed"
        killed_ns = time.time_ns()
        child.kill()
    finally:
        child.kill()
        lines += child.communicate()[0].splitlines()
    assert child.returncode == -signal.SIGKILL
    written = {}
    for line in lines:
        if line.startswith("wrote"):
            _, i, t = line.split()
            written[int(i)] = int(t)
    damage = []
    recovered = list(read_mcap_frames(path, on_damage=damage.append))
    assert len(damage) == 1 and str(path) in str(damage[0])
    sequences = [r.sequence for _, _, r in recovered]
    assert sequences == list(range(len(recovered))) and len(recovered) >= flushed
    older = [i for i, t in written.items() if t < killed_ns - 1_000_000_000]
    assert older and max(older) < len(recovered), (max(older), len(recovered))
    for _, log_ns, r in recovered[::37]:
        assert log_ns == r.stamp_ns
        expected = np.random.default_rng(r.sequence).normal(0.0, 0.1, 208).astype(np.float32)
        assert r.voltages.tobytes() == expected.tobytes()

    assert main(["frames", "export", str(path), str(tmp_path / "out.npz")]) == 0
    out, err = capsys.readouterr()
    assert f"{len(recovered)} frames (recovered)" in out
    assert "skipped" in err and str(path) in err and "Traceback" not in err
    assert load_frames_npz(tmp_path / "out.npz")[1].shape == (len(recovered), 208)


def _chunked(path, n_frames: int = 12, per_chunk: int = 3) -> list[tuple[int, int]]:
    """A finished file of chunks of ``per_chunk`` frames; returns (bytes, frames) per flush."""
    on_disk = []
    with McapFrameWriter(path, flush_period_s=None) as writer:
        for i in range(n_frames):
            writer.write(TOPIC, record(i, m=13))
            if i % per_chunk == per_chunk - 1:
                writer.flush()
                on_disk.append((path.stat().st_size, writer.flushed_messages))
    return on_disk


def test_a_cut_file_yields_every_complete_chunk_and_never_raises(tmp_path):
    full = tmp_path / "full.mcap"
    on_disk = _chunked(full)
    data = full.read_bytes()
    written = [r for _, _, r in read_mcap_frames(full)]
    assert len(written) == 12
    cut = tmp_path / "cut.mcap"
    (first_chunk_end, _), (second_chunk_end, _) = on_disk[:2]
    sizes = {  # every offset of the header and of one whole chunk with its index, and a comb
        *range(0, 40),
        *range(first_chunk_end, second_chunk_end + 1),
        *range(0, len(data), 13),
        *range(len(data) - 12, len(data)),
    }
    for size in sorted(sizes):
        cut.write_bytes(data[:size])
        damage = []
        got = [r for _, _, r in read_mcap_frames(cut, on_damage=damage.append)]
        complete = max([n for end, n in on_disk if end <= size], default=0)
        assert complete <= len(got) and got == written[: len(got)], size
        assert len(damage) == 1 and damage[0].size == size and damage[0].end <= size
        if size < len(data) - 8:  # before the footer, something was skipped at a byte offset
            assert "bytes" in str(damage[0]) or "no summary" in str(damage[0]), damage[0]
        if size % 10 == 0:
            with pytest.raises(ValueError, match="unfinished MCAP"):  # strict: no on_damage
                list(read_mcap_frames(cut))


def test_a_corrupt_chunk_is_skipped_and_the_next_ones_are_read(tmp_path):
    path = tmp_path / "rotten.mcap"
    on_disk = _chunked(path)
    data = bytearray(path.read_bytes()[: on_disk[-1][0]])  # unfinished: no summary
    middle = (on_disk[0][0] + on_disk[1][0]) // 2  # inside the second chunk's data
    data[middle] ^= 0xFF
    path.write_bytes(bytes(data))
    damage = []
    got = [r for _, _, r in read_mcap_frames(path, on_damage=damage.append)]
    assert got == [record(i, m=13) for i in (0, 1, 2, 6, 7, 8, 9, 10, 11)]
    (found,) = damage
    assert f"bytes {on_disk[0][0]}.." in str(found) and "unreadable Chunk record" in str(found)


def test_a_written_but_idle_recording_is_flushed_by_time(tmp_path):
    path = tmp_path / "idle.mcap"
    writer = McapFrameWriter(path, flush_period_s=0.2)
    try:
        for i in range(3):
            writer.write(TOPIC, record(i))
        deadline = time.monotonic() + 30.0  # safety net; the flusher runs every 0.2 s
        while writer.flushed_messages < 3:  # no further write: only the flusher thread can
            assert time.monotonic() < deadline
            time.sleep(0.01)
        damage = []
        got = [r for _, _, r in read_mcap_frames(path, on_damage=damage.append)]
        assert got == [record(i) for i in range(3)] and damage
    finally:
        writer.close()
    assert [r for _, _, r in read_mcap_frames(path)] == [record(i) for i in range(3)]


def test_export_of_an_empty_or_foreign_file_is_one_clear_line(tmp_path, capsys):
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert main(["frames", "export", str(empty), str(tmp_path / "x.npz")]) == 1
    err = capsys.readouterr().err
    assert f"{empty}: no EitFrame messages" in err and "empty file" in err
    assert len(err.strip().splitlines()) == 1
    foreign = tmp_path / "foreign.mcap"
    save_frames_npz(foreign, np.zeros(4), np.zeros((1, 4)))
    assert main(["frames", "export", str(foreign), str(tmp_path / "x.npz")]) == 1
    err = capsys.readouterr().err
    assert f"{foreign}: not an MCAP file" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()


def test_replay_of_a_cut_recording_publishes_what_was_complete(tmp_path):
    full = tmp_path / "full.mcap"
    on_disk = _chunked(full)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: on_disk[1][0] + 40])  # 2 chunks and a piece
    source = ReplaySource(cut, ["pressure"], realtime=False)
    published = []
    while not source.finished:
        source.tick(0, published.append)
    assert published == [record(i, m=13) for i in range(on_disk[1][1])]
    status = source.status()
    assert status.level == 1 and "cut short" in status.values["skipped"]
    assert str(cut) in status.message


def test_a_nan_reference_channel_is_read_and_left_to_the_pipeline(tmp_path):
    """A missing reference channel is data, not a file error: the pipeline excludes it."""
    path = tmp_path / "ref.npz"
    np.savez(path, reference=np.array([1.0, np.nan, 1.0]), frames=np.ones((2, 3)))
    reference, frames, _ = load_frames_npz(path)
    assert np.isnan(reference[1]) and frames.shape == (2, 3)
