"""MCAP (ROS 2 encoding) and npz recordings: round trips, schema, validation errors."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

from eit_skin.frames import FrameRecord
from eit_skin.io.cdr import (
    EIT_FRAME_SCHEMA,
    decode_eit_frame_cdr,
    eit_frame_msgdef,
    encode_eit_frame_cdr,
)
from eit_skin.io.conversion import mcap_to_npz, npz_to_mcap
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
    with open(__file__.replace("test/test_recording.py", "msg/EitFrame.msg")) as f:
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
        ({"reference": np.array([0, np.nan, 0]), "frames": np.zeros((1, 3))}, None, "index 1"),
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
    n = npz_to_mcap(
        tmp_path / "a.npz", tmp_path / "a.mcap", TOPIC, patch="arm", layer="pressure",
        n_electrodes=16,
    )  # fmt: skip
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
