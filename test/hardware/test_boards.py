"""Board profiles' readers (eit_skin.hardware.boards, .sciospec) on byte streams written here.

The streams are formatted in this file from the boards' own code (docs/boards.md), not by the
emulators, so a reader and an emulator that share a mistake cannot pass together. Every
stream is also fed split at every byte: a frame never depends on how the port chunks it.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from eit_skin.hardware.sciospec import ACK, START, STOP, SYSTEM_TAG, message, setup_commands
from eit_skin.hardware.sources import board_reader
from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.model import PatchError
from eit_skin.patch.protocol import build_protocol
from eit_skin.patch.yaml_reader import read_yaml

HYDROGEL = "data/real/hydrogel_ohmc16.yaml"
SCIOSPEC = "data/real/sciospec_adjacent.yaml"
FULL = {"drive": "adjacent", "measure": "adjacent", "layout": "full"}


def layer_with(path: str, repo, protocol=None, **device):
    data = read_yaml(repo / path, PatchError)
    data["layers"][0]["device"] = device
    if protocol is not None:
        data["layers"][0]["protocol"] = protocol
    layer = patch_from_dict(data, str(path)).layers[0]
    return layer, build_protocol(layer.protocol, layer.n_electrodes)


def reader_for(layer, protocol):
    return board_reader(protocol, layer.device, layer.name, layer.current_a, lambda f: None)


def fixed_28_4(value: float) -> bytes:
    """One OpenEIT number as the firmware's sprintf_fixed32 writes a non-negative 28.4 value."""
    full = round(value * 16)
    return b"%8d.%04d," % (full >> 4, (full & 15) * 625)


def openeit_line(values, end=b"\r\n") -> bytes:
    return b"magnitudes: " + b"".join(fixed_28_4(v) for v in values) + end


def feed_split_everywhere(make_reader, stream: bytes):
    """Frames of ``stream`` fed whole, and fed in two parts cut at every byte: all equal."""
    whole = make_reader().feed(stream)
    for cut in range(1, len(stream)):
        reader = make_reader()
        parts = reader.feed(stream[:cut]) + reader.feed(stream[cut:])
        assert len(parts) == len(whole), cut
        for a, b in zip(parts, whole, strict=True):
            np.testing.assert_array_equal(a.values, b.values)
    return whole


@pytest.fixture(scope="module")
def openeit(repo):
    return layer_with(HYDROGEL, repo, profile="openeit")


@pytest.fixture(scope="module")
def frames16():
    rng = np.random.default_rng(1)
    return np.round(rng.uniform(10, 5e4, (3, 192)) * 16) / 16


def test_openeit_lines_give_the_numbers_at_any_split_and_any_line_end(openeit, frames16):
    layer, protocol = openeit
    for end in (b"\r\n", b"\n", b"\r"):
        stream = b"".join(openeit_line(v, end) for v in frames16[:2])
        got = feed_split_everywhere(lambda: reader_for(layer, protocol), stream)
        assert len(got) == 2
        for frame, want in zip(got, frames16, strict=False):
            np.testing.assert_array_equal(frame.values, want)
            assert frame.device_time_us is None  # no board clock: stamped on arrival


def test_openeit_bad_lines_are_counted_per_reason_and_lose_no_good_frame(openeit, frames16):
    layer, protocol = openeit
    good = [openeit_line(v) for v in frames16]
    short = openeit_line(frames16[0][:191])
    cut = good[0][:700]  # truncated: the rest of the line never came
    word = good[1].replace(b"  123", b"  abc", 1)
    word = word if word != good[1] else good[1][:30] + b"x" + good[1][31:]
    nan_line = good[2].replace(b",", b", nan,", 1).replace(fixed_28_4(frames16[2][1]), b"", 1)
    stream = b"".join(
        [good[0], b"garbage \x00\xff line\r\n", short, good[1], cut, good[2], word, nan_line]
    )
    reader = reader_for(layer, protocol)
    reader.feed(b"d\n")  # the tail of a line from before the connect: not the board's fault
    frames = reader.feed(b"\r\n" + stream)
    refused = reader.stats.refused
    assert refused["not_a_frame"] == 0 and refused["prefix"] == 1  # the garbage line
    assert refused["values"] == 2  # the short line, the cut line joined to the next
    assert refused["not_a_number"] == 1
    assert "byte" in reader.last_refusal
    values = [f.values for f in frames]
    assert len(values) == 3  # good[0], good[1], the nan line; good[2] went with `cut`
    np.testing.assert_array_equal(values[0], frames16[0])
    np.testing.assert_array_equal(values[1], frames16[1])
    nan_frame = frames[2]
    assert np.isnan(nan_frame.values[1]) and nan_frame.flags[1] and not nan_frame.flags[0]
    assert reader.stats.bytes == 2 + 2 + len(stream)


def test_openeit_mode_line_on_connect_again_after_silence_and_after_a_restart(openeit, frames16):
    layer, protocol = openeit
    reader = reader_for(layer, protocol)
    reader.reset()
    assert reader.commands(0.0) == b"d\nd\n"  # twice: the firmware reads only > 2 bytes
    assert reader.commands(1.0) == b""
    assert reader.unanswered(1.0) == ""
    reader.feed(b"\n" + openeit_line(frames16[0][:32]))  # an 8-electrode frame: another mode
    again = reader.commands(10.0)
    assert again == b"d\nd\n"
    silent = reader.unanswered(10.0)
    assert "openeit" in silent and "192" in silent and "magnitudes" in silent, silent
    reader.feed(b"mode 4: 16 electrode imaging\n")
    assert reader.stats.messages == 1 and not reader.acknowledged  # a frame answers, not text
    reader.feed(openeit_line(frames16[0]))
    assert reader.acknowledged and reader.unanswered(30.0) == "" and reader.commands(30.0) == b""
    half = openeit_line(frames16[1])[:400]
    assert reader.feed(half + b"OpenEIT\n") == []
    assert reader.stats.restarts == 1 and reader.stats.refused["values"] == 2
    assert reader.commands(31.0) == b"d\nd\n"  # the board restarted in its boot mode
    frames = reader.feed(openeit_line(frames16[2]))
    assert len(frames) == 1
    np.testing.assert_array_equal(frames[0].values, frames16[2])


def test_lines_profile_separators_label_and_dropped_zeros(repo):
    layer, protocol = layer_with(
        "data/real/ottawa_ph1.yaml", repo, FULL, profile="lines", drop_zeros=True
    )
    assert protocol.frame_size == 256 and protocol.n_measurements == 208
    rng = np.random.default_rng(2)
    used = rng.uniform(-1, 1, 208).round(4)
    texts = [
        ", ".join(f"{v:.4f}" for v in used) + ", \n",
        "frame: " + "; ".join(f"{v:.4f}" for v in used) + "\r\n",
        " ".join(f"{v:.4f}" for v in used) + "\n",
    ]
    stream = "".join(texts).encode()
    got = feed_split_everywhere(lambda: reader_for(layer, protocol), stream)
    assert len(got) == 3
    for frame in got:
        np.testing.assert_array_equal(frame.values, used)
        np.testing.assert_array_equal(protocol.select(frame.values), used)
    full, fprotocol = layer_with("data/real/ottawa_ph1.yaml", repo, FULL, profile="lines")
    reader = reader_for(full, fprotocol)
    (frame,) = reader.feed(texts[0].encode() + (", ".join(["0.0"] * 256) + "\n").encode())
    assert reader.stats.refused == {**reader.stats.refused, "partial_line": 1}
    np.testing.assert_array_equal(frame.values, np.zeros(256))


def test_lines_prefix_is_required_when_given(repo):
    layer, protocol = layer_with(
        "data/real/ottawa_ph1.yaml", repo, FULL, profile="lines", prefix="V:", drop_zeros=True
    )
    reader = reader_for(layer, protocol)
    values = ", ".join(["1.5"] * 208)
    frames = reader.feed(f"\nX: {values}\nV: {values}\n".encode())
    assert len(frames) == 1 and reader.stats.refused["prefix"] == 1


@pytest.mark.parametrize(
    ("device", "key"),
    [
        ({"profile": "openeit", "baud": -5}, "device.baud"),
        ({"profile": "lines", "drop_zeros": True}, "device.drop_zeros"),
        ({"profile": "lines", "values": 100}, "device.values"),
        ({"profile": "sciospec", "gain": 3}, "device.gain"),
        ({"profile": "sciospec", "first_channel": 60}, "device.first_channel"),
        ({"profile": "openei"}, "device.profile"),
        ({"profile": "openeit", "seperators": ","}, "device.seperators"),
    ],
)
def test_a_bad_device_section_is_refused_naming_the_key(repo, device, key):
    with pytest.raises(PatchError, match=rf"layers\[0\]\.{key}"):
        layer_with(SCIOSPEC, repo, **device)


def test_openeit_needs_its_own_frame(repo):
    with pytest.raises(PatchError, match=r"protocol: OpenEIT sends 192 magnitudes"):
        layer_with(SCIOSPEC, repo, profile="openeit")


def test_the_device_changes_no_content_hash(repo, openeit):
    layer, _ = openeit
    plain = patch_from_dict(read_yaml(repo / HYDROGEL, PatchError)).layers[0]
    assert layer.device.profile == "openeit" and layer.device.baud == 115200
    assert layer.content_hash == plain.content_hash


# ------------------------------------------------------------------------------- Sciospec


def sciospec_stage(group, es_out, es_in, ms, values16) -> bytes:
    """One data frame as sciopy's parse_single_frame reads it (140 bytes)."""
    data = b"".join(struct.pack(">ff", v.real, v.imag) for v in values16)
    payload = bytes((group, es_out, es_in, 0, 0)) + struct.pack(">I", ms) + data
    return message(0xB4, payload)


ACK_BYTES = bytes((SYSTEM_TAG, 1, ACK, SYSTEM_TAG))


@pytest.fixture(scope="module")
def sciospec(repo):
    return layer_with(SCIOSPEC, repo, profile="sciospec", first_channel=3)


def as_float32(pot):
    """Complex potentials as the board's float32 parts carry them (complex128)."""
    return pot.real.astype(np.float32).astype(float) + 1j * pot.imag.astype(np.float32)


def potentials(protocol, rng):
    return rng.normal(size=(protocol.n_injections, protocol.n_electrodes)) + 1j * rng.normal(
        size=(protocol.n_injections, protocol.n_electrodes)
    )


def cycle_bytes(protocol, pot, ms0, first_channel=3, groups=(1, 2)):
    """The stages of one drive cycle: channel c carries electrode c - first_channel."""
    out = []
    for k, (src, snk) in enumerate(protocol.injections):
        row = np.zeros(32, complex)
        row[first_channel - 1 : first_channel - 1 + protocol.n_electrodes] = pot[k]
        for g in groups:
            out.append(
                sciospec_stage(
                    g, src + first_channel, snk + first_channel, ms0 + k, row[16 * (g - 1) :][:16]
                )
            )
    return b"".join(out)


def acknowledge_setup(reader, first_t: int = 0):
    """Answer every setup command from now on with an acknowledgement; the commands sent."""
    sent = []
    for t in range(first_t, 200):
        command = reader.commands(float(t) * 0.01)
        if not command:
            break
        sent.append(command)
        reader.feed(ACK_BYTES)
    return sent


def handshake(reader):
    """A connect whose whole setup is acknowledged; the commands sent, in order."""
    reader.reset()
    return acknowledge_setup(reader)


def test_sciospec_setup_one_command_per_acknowledgement(sciospec):
    layer, protocol = sciospec
    reader = reader_for(layer, protocol)
    reader.reset()
    first = reader.commands(0.0)
    assert first == STOP and reader.commands(0.1) == b""  # waits for the acknowledgement
    reader.feed(bytes((SYSTEM_TAG, 1, 0x81, SYSTEM_TAG)))  # nothing to stop: fine
    sent = [first, *acknowledge_setup(reader, first_t=1)]
    want = [raw for _, raw in setup_commands(protocol, layer.device, layer.current_a)]
    assert sent == want and sent[-1] == START and reader.acknowledged
    # injection k drives channels (k + 3, k + 4): electrode 0 on channel 3
    assert message(0xB0, bytes((6, 3, 4))) in sent and message(0xB0, bytes((6, 18, 3))) in sent
    assert message(0xB0, b"\x05" + struct.pack(">d", layer.current_a)) in sent
    assert reader.farewell() == STOP


def test_sciospec_frames_are_the_protocols_differences_at_any_split(sciospec):
    layer, protocol = sciospec
    rng = np.random.default_rng(3)
    pots = [potentials(protocol, rng) for _ in range(2)]
    stream = cycle_bytes(protocol, pots[0], 1000) + cycle_bytes(protocol, pots[1], 1100)

    def ready():
        reader = reader_for(layer, protocol)
        handshake(reader)
        return reader

    frames = feed_split_everywhere(ready, stream)
    assert len(frames) == 2
    for frame, pot in zip(frames, pots, strict=True):
        f32 = as_float32(pot)
        np.testing.assert_array_equal(frame.values, protocol.measure(f32))
    assert frames[0].device_time_us == 1015 * 1000  # the last stage's clock
    assert [f.sequence for f in frames] == [0, 1]


def test_sciospec_incomplete_cycles_restarts_and_garbage_lose_no_good_frame(sciospec):
    layer, protocol = sciospec
    rng = np.random.default_rng(4)
    pot = [potentials(protocol, rng) for _ in range(4)]
    reader = reader_for(layer, protocol)
    before = reader.feed(cycle_bytes(protocol, pot[0], 0)[:280])
    assert not before and reader.stats.refused["before_start"] == 2
    handshake(reader)
    one = cycle_bytes(protocol, pot[1], 5000)
    missing_stage = one[: 140 * 6] + one[140 * 8 :]  # stage 3 lost
    restarted = cycle_bytes(protocol, pot[2], 9000)[: 140 * 10]
    stream = (
        missing_stage
        + b"\x00\x13\x37garbage"
        + restarted
        + cycle_bytes(protocol, pot[3], 10)  # the clock ran back: the board restarted
    )
    frames = reader.feed(stream)
    assert len(frames) == 1
    f32 = as_float32(pot[3])
    np.testing.assert_array_equal(frames[0].values, protocol.measure(f32))
    refused = reader.stats.refused
    assert refused["incomplete"] == 2 and refused["framing"] == 1
    assert reader.stats.restarts == 1


def test_sciospec_refused_or_unanswered_setup_names_the_command(sciospec):
    layer, protocol = sciospec
    reader = reader_for(layer, protocol)
    reader.reset()
    reader.commands(0.0)
    reader.feed(ACK_BYTES)
    assert reader.commands(0.1) == message(0xB0, b"\x01")
    reader.feed(bytes((SYSTEM_TAG, 1, 0x82, SYSTEM_TAG)))
    assert "reset setup" in reader.unanswered(0.2) and "not recognised" in reader.unanswered(0.2)
    quiet = reader_for(layer, protocol)
    quiet.reset()
    quiet.commands(0.0)
    quiet.feed(b"magnitudes: 1, 2, 3\r\n")  # another board's bytes
    assert quiet.commands(1.0) == b""
    assert quiet.commands(2.5) == STOP  # no answer in ack_timeout_s: the setup again
    line = quiet.unanswered(2.6)
    assert "stop" in line and "b4 01 00 b4" in line and "magnitudes" in line


def test_the_schema_doc_has_the_current_options_table(repo):
    from eit_skin.patch.device import options_table

    assert options_table() in (repo / "docs/patch-schema.md").read_text(), (
        "docs/patch-schema.md: regenerate the device options table (options_table())"
    )
