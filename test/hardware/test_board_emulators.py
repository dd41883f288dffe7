"""The board emulators, read as a host would: their bytes against the boards' formats.

Each format is re-read here by a small independent reader (a regex, ``struct``), written
from the boards' code, not from the emulators: OpenEIT's ``magnitudes:`` lines, Arduino
``Serial.print(v, 4)`` lines, Sciospec's ``[tag][len][payload][tag]`` frames.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import struct
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np
import pytest

from eit_skin.hardware.board_emulators import (
    LineFormat,
    LinesEmulator,
    OpenEITEmulator,
    arduino_print_float,
)
from eit_skin.hardware.sciospec_emulator import (
    SCIOSPEC_ACK,
    SCIOSPEC_NACK_NOT_EXECUTED,
    SCIOSPEC_NACK_UNKNOWN,
    SCIOSPEC_TIMEOUT,
    SciospecEmulator,
    SciospecWiring,
    potentials_from_differences,
)
from eit_skin.io.npz import load_frames_npz
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from test.support.patience import EVENT_S

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def real(name: str):
    """(protocol, frames [T, M]) of a recording in data/real."""
    layer = load_patch(os.path.join(ROOT, "data", "real", f"{name}.yaml")).layers[0]
    _, frames, _ = load_frames_npz(os.path.join(ROOT, "data", "real", f"{name}.npz"))
    return build_protocol(layer.protocol, layer.n_electrodes), frames


@pytest.fixture(scope="module")
def hydrogel():
    return real("hydrogel_ohmc16")


@pytest.fixture(scope="module")
def sciospec():
    return real("sciospec_adjacent")


class Host:
    """The host end of a board's pty: writes commands, collects every byte it reads."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.data = bytearray()

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)

    def read_until(self, done: Callable[[bytes], bool], what: str) -> bytes:
        """Read until ``done(all bytes so far)``; ``EVENT_S`` is a safety net only."""
        deadline = time.monotonic() + EVENT_S
        while not done(bytes(self.data)):
            assert time.monotonic() < deadline, f"no {what}; got {bytes(self.data[-300:])!r}"
            select.select([self.fd], [], [], 0.05)
            with contextlib.suppress(BlockingIOError):
                self.data += os.read(self.fd, 1 << 16)
        return bytes(self.data)

    def take(self) -> bytes:
        """Everything read so far (and forget it)."""
        out = bytes(self.data)
        self.data.clear()
        return out

    def close(self) -> None:
        os.close(self.fd)


# ---------------------------------------------------------------------------------- OpenEIT

#: One value of ``sprintf_fixed32`` (``%8d.%04d``) and its ``,``.
OPENEIT_VALUE = rb"( *\d+)\.(\d{4}),"


def openeit_lines(data: bytes) -> list[bytes]:
    """Complete ``\\n``-terminated lines."""
    return data.split(b"\n")[:-1]


def openeit_values(line: bytes) -> np.ndarray:
    """The magnitudes of one frame line (``\\r`` stripped), checked field by field."""
    assert line.startswith(b"magnitudes: ") and line.endswith(b"\r"), line[:40]
    body = line[len(b"magnitudes: ") : -1]
    fields = re.findall(OPENEIT_VALUE, body)
    assert b"".join(i + b"." + f + b"," for i, f in fields) == body
    assert all(len(i) >= 8 for i, _ in fields)  # the integer part padded to 8 columns
    fraction = np.array([int(f) for _, f in fields])
    assert np.all(fraction % 625 == 0)  # a 4-bit fraction printed as 16ths x 625
    return np.array([int(i) for i, _ in fields]) + fraction / 10000.0


def count_frame_lines(n: int) -> Callable[[bytes], bool]:
    return lambda data: sum(line.startswith(b"magnitudes") for line in openeit_lines(data)) >= n


def test_openeit_boots_with_its_banner_and_streams_16_electrode_magnitude_lines(hydrogel):
    protocol, frames = hydrogel
    with OpenEITEmulator(lambda i: frames[i], protocol, rate_hz=200.0) as board:
        host = Host(board.slave_path)
        board.start()
        data = host.read_until(count_frame_lines(4), "4 frame lines")
        host.close()
    assert data.startswith(b"OpenEIT\n")
    lines = openeit_lines(data[len(b"OpenEIT\n") :])
    for index, line in enumerate(lines[:4]):
        values = openeit_values(line)
        assert values.shape == (192,)
        expected = np.floor(np.abs(frames[index]) * 16 + 0.5) / 16  # nearest 1/16
        np.testing.assert_array_equal(values, expected)
        np.testing.assert_array_equal(values, board.expected_measurements(index))


def test_openeit_fixed_point_text_rounds_saturates_and_pads(hydrogel):
    protocol, _ = hydrogel
    row = np.zeros(192)
    row[:5] = [0.03, 0.0313, 1234.96875, 1e12, np.nan]
    board = OpenEITEmulator(lambda i: row, protocol)
    line = board.frame_line(0)
    # 0.03 -> 0; 0.0313 -> 1/16; 1234 + 15.5/16 -> 1235 (ties up); 1e12 saturates; NaN -> 0
    assert line.startswith(
        b"magnitudes:        0.0000,       0.0625,    1235.0000,134217727.9375,       0.0000,"
    )
    values = openeit_values(line[:-1])
    assert values[0] == 0.0 and values[1] == 0.0625 and values[3] == 0x7FFFFFFF / 16


def test_openeit_switches_mode_only_when_more_than_two_bytes_wait(hydrogel):
    protocol, frames = hydrogel
    with OpenEITEmulator(lambda i: frames[i % 4], protocol, rate_hz=400.0) as board:
        host = Host(board.slave_path)
        board.start()
        host.read_until(count_frame_lines(1), "a frame")
        host.take()
        host.write(b"c\n")  # 2 bytes: the firmware never reads them
        host.read_until(count_frame_lines(3), "3 frames")
        assert b"mode" not in host.take()
        host.write(b"c\nc\n")  # 4 bytes: 'c\n' taken, the rest flushed
        data = host.read_until(count_frame_lines(2), "8-electrode frames")
        mode_at = data.index(b"mode 3: 8 electrode imaging\n")
        after = openeit_lines(data[mode_at + len(b"mode 3: 8 electrode imaging\n") :])
        assert openeit_values(after[0]).shape == (32,)  # no 8-electrode data: zeros
        assert not openeit_values(after[0]).any()
        host.take()
        host.write(b"e\ne\n")
        data = host.read_until(count_frame_lines(1), "a 32-electrode frame")
        assert b"mode 3: 32 electrode imaging\n" in data  # sic, the firmware's text
        assert openeit_values(openeit_lines(data.split(b"imaging\n", 1)[1])[0]).shape == (896,)
        host.take()
        host.write(b"d\nxyz")  # 'd\n' + anything: back to 16 electrodes
        data = host.read_until(count_frame_lines(2), "16-electrode frames")
        assert data.count(b"mode 4: 16 electrode imaging\n") == 1
        host.take()
        host.write(b"d\nd\n")  # already in mode 4: no mode line
        data = host.read_until(count_frame_lines(3), "frames")
        assert b"mode" not in data
        assert all(len(openeit_values(line)) == 192 for line in openeit_lines(data)[1:])
        host.close()


def test_openeit_restart_prints_the_banner_mid_line_and_falls_back_to_16_electrodes(hydrogel):
    protocol, frames = hydrogel
    with OpenEITEmulator(lambda i: frames[i % 4], protocol, rate_hz=400.0) as board:
        host = Host(board.slave_path)
        host.write(b"c\nc\n")
        board.start()
        host.read_until(lambda d: b"mode 3" in d and count_frame_lines(2)(d), "mode 3")
        board.restart(cut_at=30)
        data = host.read_until(lambda d: d.count(b"OpenEIT\n") == 2, "a second banner")
        data = host.read_until(lambda d: count_frame_lines(2)(d.rsplit(b"OpenEIT\n", 1)[1]), "x")
        host.close()
    before, after = data.rsplit(b"OpenEIT\n", 1)
    assert len(before.rsplit(b"\n", 1)[1]) == 30  # the cut line, then the banner
    assert openeit_values(openeit_lines(after)[0]).shape == (192,)


# ------------------------------------------------------------------------------ lines boards


def arduino_reference(v: float) -> str:
    """``Serial.print(v, 4)`` for values far from a rounding tie: sign, then %.4f of |v|."""
    if np.isnan(v):
        return "nan"
    if np.isinf(v):
        return "inf"
    return ("-" if v < 0 else "") + f"{abs(v):.4f}"


def test_arduino_print_float_follows_print_float():
    values = np.array([0.0, -0.00001, 123.456789, -2.5, np.nan, -np.inf, 5e9, -5e9, 0.01234])
    assert arduino_print_float(values).tolist() == [
        "0.0000", "-0.0000", "123.4568", "-2.5000", "nan", "inf", "ovf", "ovf", "0.0123",
    ]  # fmt: skip
    rng = np.random.default_rng(0)
    many = rng.normal(0, 3, 2000)
    assert arduino_print_float(many).tolist() == [arduino_reference(v) for v in many]


@pytest.mark.parametrize(
    ("separator", "label", "ending", "drop"),
    [(", ", "", "\n", False), (";", "frame", "\r\n", False), (" ", "", "\n", True)],
)
def test_lines_board_prints_every_value_then_the_separator(separator, label, ending, drop):
    protocol = build_protocol(ProtocolSpec(layout="full"), 16)  # 16 x 16 with zeros
    rng = np.random.default_rng(1)
    frames = rng.normal(0, 0.5, (4, protocol.n_measurements))
    line_format = LineFormat(separator=separator, label=label, line_ending=ending, drop_zeros=drop)
    board = LinesEmulator(lambda i: frames[i], protocol, rate_hz=400.0, line_format=line_format)
    with board:
        host = Host(board.slave_path)
        board.start(count=4)
        data = host.read_until(lambda d: d.count(b"\n") >= 4, "4 lines").decode("ascii")
        host.close()
    pattern = re.compile(
        "^" + (re.escape(label + ": ") if label else "")
        + "((?:-?\\d+\\.\\d{4}" + re.escape(separator) + ")+)" + re.escape(ending) + "$"
    )  # fmt: skip
    lines = re.findall(".*?" + re.escape(ending), data)
    assert len(lines) == 4
    for index, line in enumerate(lines):
        match = pattern.match(line)
        assert match, line[:60]
        values = np.array(match.group(1).split(separator)[:-1], dtype=float)
        full = np.zeros(256)
        full[protocol.frame_index] = frames[index]
        expected = frames[index] if drop else full
        assert values.shape == expected.shape
        assert np.abs(values - expected).max() <= 0.5e-4 + 1e-12
        decoded = np.zeros(256)
        decoded[np.sort(protocol.frame_index) if drop else np.arange(256)] = values
        np.testing.assert_array_equal(protocol.select(decoded), board.expected_measurements(index))
        if not drop:  # the pairs touching a drive electrode print 0.0000
            unused = np.setdiff1d(np.arange(256), protocol.frame_index)
            assert not values[unused].any()


def test_lines_board_refuses_what_it_cannot_honour():
    compact = build_protocol(ProtocolSpec(), 16)
    with pytest.raises(ValueError, match="drop_zeros: the protocol's layout is compact"):
        LinesEmulator(lambda i: np.zeros(208), compact, line_format=LineFormat(drop_zeros=True))
    with pytest.raises(ValueError, match="separator"):
        LineFormat(separator="|")


def test_garbage_and_a_frame_cut_short_reach_the_host_as_written():
    protocol = build_protocol(ProtocolSpec(), 16)
    frames = np.random.default_rng(3).normal(0, 0.5, (2, 208))
    with LinesEmulator(lambda i: frames[i], protocol, rate_hz=400.0) as board:
        host = Host(board.slave_path)
        board.write_raw(b"\x00\xffgarbage")
        board.cut_next_frame(7)
        board.start(count=2)
        line = board.frame_line(1)
        data = host.read_until(lambda d: d.endswith(line), "the second line")
        host.close()
    assert data == b"\x00\xffgarbage" + board.frame_line(0)[:7] + line


# ---------------------------------------------------------------------------------- Sciospec


def command(tag: int, *payload: int) -> bytes:
    return bytes([tag, len(payload), *payload, tag])


def sciopy_setup(n_el: int = 16) -> list[bytes]:
    """The commands of sciopy's ``set_measurement_config_usb_hs`` (adjacent, 16 electrodes)."""
    f32 = list(struct.pack(">f", 10000.0))
    commands = [
        command(0xB0, 0x01),  # reset setup
        command(0xB0, 0x02, 0x00, 0x00),  # burst count 0
        command(0xB0, 0x05, *struct.pack(">d", 0.001)),  # amplitude 1 mA
        command(0xB0, 0x0D, 0x01),  # ADC range +-1 V
        command(0xB0, 0x09, 0x01, 0x00),  # gain 1
        command(0xB0, 0x08, 0x01, 0x01),  # single ended
        command(0xB0, 0x0C, 0x01),  # excitation switch type
        command(0xB0, 0x03, *struct.pack(">f", 200.0)),  # frame rate, Hz
        command(0xB0, 0x04, *f32, *f32, 0x00, 0x01, 0x00),  # one frequency
    ]
    commands += [command(0xB0, 0x06, k, k % n_el + 1) for k in range(1, n_el + 1)]
    outputs = [command(0xB2, 0x01, 0x01), command(0xB2, 0x03, 0x01), command(0xB2, 0x02, 0x01)]
    return [*commands, *outputs]


DATA_FRAME = struct.Struct(">BBBBBHI32fB")  # tag len CG ESout ESin row time 16x(re, im) tag


def data_frames(data: bytes) -> list[tuple]:
    """Consecutive 140-byte data frames at the start of ``data``, checked for framing."""
    assert len(data) % DATA_FRAME.size == 0, len(data)
    frames = [DATA_FRAME.unpack_from(data, i) for i in range(0, len(data), DATA_FRAME.size)]
    assert all(f[0] == 0xB4 and f[1] == 0x89 and f[-1] == 0xB4 for f in frames)
    return frames


def test_sciospec_acknowledges_setup_and_sends_nothing_before_start(sciospec):
    protocol, frames = sciospec
    with SciospecEmulator(lambda i: frames[i], protocol, command_timeout_s=0.05) as board:
        host = Host(board.slave_path)
        board.start()
        setup = sciopy_setup()
        for c in setup:
            host.write(c)
        data = host.read_until(lambda d: len(d) >= 4 * len(setup), "acknowledgements")
        assert data == SCIOSPEC_ACK * len(setup)  # and no data: not started
        host.take()
        host.write(command(0xB1, 0x03))  # get the frame rate
        reply = command(0xB1, 0x03, *struct.pack(">f", 200.0)) + SCIOSPEC_ACK
        assert host.read_until(lambda d: len(d) >= len(reply), "setup") == reply
        host.take()
        for bad, answer in [
            (command(0xB7, 0x01), SCIOSPEC_NACK_UNKNOWN),  # unknown tag
            (command(0xB0, 0x02, 0x00), SCIOSPEC_NACK_UNKNOWN),  # burst count: 1 byte short
            (bytes([0xB0, 0x01, 0x01, 0xB1]), SCIOSPEC_NACK_UNKNOWN),  # wrong closing tag
            (command(0xB0, 0x06, 0x03, 0x03), SCIOSPEC_NACK_NOT_EXECUTED),  # source = sink
            (command(0xB0, 0x03, *struct.pack(">f", -1.0)), SCIOSPEC_NACK_NOT_EXECUTED),
            (bytes([0xB0, 0x03, 0x02]), SCIOSPEC_TIMEOUT),  # the rest never comes
        ]:
            host.write(bad)
            assert host.read_until(lambda d: len(d) >= 4, "an answer") == answer, bad.hex()
            host.take()
        assert board.frames_sent == 0 and board.injections == board.factory_injections
        host.close()


def test_sciospec_streams_potentials_per_injection_and_group_until_stop(sciospec):
    protocol, frames = sciospec
    potentials = potentials_from_differences(protocol, frames)  # [T, 16, 16]
    per_frame = 16 * 2 * DATA_FRAME.size  # 16 injections x 2 channel groups (EIT32)
    with SciospecEmulator(lambda i: frames[i], protocol) as board:
        host = Host(board.slave_path)
        board.start()
        for c in sciopy_setup():
            host.write(c)
        host.write(command(0xB4, 0x01))
        n_setup = 4 * len(sciopy_setup())
        data = host.read_until(lambda d: len(d) >= n_setup + 4 + 3 * per_frame, "3 frames")
        assert data[n_setup : n_setup + 4] == SCIOSPEC_ACK  # start acknowledged first
        host.write(command(0xB4, 0x00))
        data = host.read_until(lambda d: d.endswith(SCIOSPEC_ACK) and len(d) > n_setup + 4, "stop")
        host.take()
        host.write(command(0xB1, 0x02))  # after the stop: only the answer, no data
        reply = command(0xB1, 0x02, 0x00, 0x00) + SCIOSPEC_ACK
        assert host.read_until(lambda d: len(d) >= len(reply), "reply") == reply
        host.close()
    stream = data[n_setup + 4 : -4]
    got = data_frames(stream)
    assert len(got) % 32 == 0 and len(got) >= 96  # whole frames only
    table = np.array([f[2:7] for f in got])  # CG, ESout, ESin, row, time
    inj = np.repeat(np.arange(1, 17), 2)
    for t in range(len(got) // 32):
        block = table[32 * t : 32 * (t + 1)]
        assert block[:, 0].tolist() == [1, 2] * 16
        assert (
            block[:, 1].tolist() == inj.tolist() and block[:, 2].tolist() == (inj % 16 + 1).tolist()
        )
        values = np.array([f[7:-1] for f in got[32 * t : 32 * (t + 1)]]).reshape(16, 2, 16, 2)
        assert not values[..., 1].any()  # imaginary parts: 0
        assert not values[:, 1].any()  # channels 17-32: no electrode
        real_part = values[:, 0, :, 0]  # [injection, channel]
        np.testing.assert_array_equal(real_part, potentials[t].astype(np.float32))
        host_differences = protocol.measure(real_part.astype(np.float64))
        np.testing.assert_array_equal(host_differences, board.expected_measurements(t))
        assert np.abs(host_differences - frames[t]).max() <= 4 * 2**-24 * np.abs(real_part).max()
    times = table[:, 4].astype(np.int64)
    assert np.all(np.diff(times) >= 0)  # ms since power-up, never backwards in one run


def test_sciospec_burst_count_ends_the_stream_and_restart_resets_the_clock(sciospec):
    protocol, frames = sciospec
    per_frame = 32 * DATA_FRAME.size
    with SciospecEmulator(lambda i: frames[i % 4], protocol, rate_hz=100.0) as board:
        host = Host(board.slave_path)
        board.start()
        host.write(command(0xB0, 0x02, 0x00, 0x02) + command(0xB4, 0x01))  # burst of 2
        data = host.read_until(lambda d: len(d) >= 8 + 2 * per_frame, "a burst of 2")
        host.take()
        host.write(command(0xB1, 0x02))
        reply = command(0xB1, 0x02, 0x00, 0x02) + SCIOSPEC_ACK
        assert host.read_until(lambda d: len(d) >= len(reply), "reply") == reply  # no 3rd
        assert len(data_frames(data[8:])) == 64
        host.take()
        host.write(command(0xB0, 0x02, 0x00, 0x00) + command(0xB4, 0x01))  # continuous
        host.read_until(lambda d: len(d) >= 8 + 10 * per_frame, "10 frames")
        board.restart()
        data = host.read_until(lambda d: len(d) >= 8 + 14 * per_frame, "4 more frames")
        host.close()
    stream = data[8 : 8 + 14 * per_frame]
    times = np.array([f[6] for f in data_frames(stream)], dtype=np.int64)
    assert (np.diff(times) < 0).sum() == 1  # the clock went back once: the restart
    assert times[-1] < times[(np.diff(times) < 0).argmax()]


def test_sciospec_electrodes_on_the_second_channel_group(sciospec):
    """16 electrodes on channels 17-32 of an EIT32: group 1 reads 0 V, group 2 carries them;
    an injection the protocol only has reversed is sent negated, one it lacks as 0 V."""
    protocol, frames = sciospec
    board = SciospecEmulator(lambda i: frames[i], protocol, wiring=SciospecWiring(first_channel=17))
    assert board.injections[:2] == [(17, 18), (18, 19)]
    got = data_frames(board.data_frames(0, 0.0, 10.0))
    values = np.array([f[7:-1] for f in got]).reshape(16, 2, 16, 2)[..., 0]
    expected = potentials_from_differences(protocol, frames[0]).astype(np.float32)
    assert not values[:, 0].any()
    np.testing.assert_array_equal(values[:, 1], expected)
    board.injections[:] = [(18, 17), (1, 2)]
    got = data_frames(board.data_frames(0, 0.0, 10.0))
    values = np.array([f[7:-1] for f in got]).reshape(2, 2, 16, 2)[..., 0]
    np.testing.assert_array_equal(values[0, 1], -expected[0])
    assert not values[1].any() and board.unknown_injections == 1


def test_potentials_from_differences_give_back_the_recording(sciospec):
    protocol, frames = sciospec
    potentials = potentials_from_differences(protocol, frames)
    assert potentials.shape == (len(frames), 16, 16)
    np.testing.assert_allclose(protocol.measure(potentials), frames, rtol=0, atol=1e-14)
    as_sent = potentials.astype(np.float32).astype(np.float64)  # what the board sends
    error = np.abs(protocol.measure(as_sent) - frames)
    assert error.max() <= 2 * 2**-24 * np.abs(potentials).max()  # float32 rounding only


def test_potentials_from_differences_recover_potentials_up_to_a_constant():
    """Adjacent drive, adjacent pairs skipping the drive electrodes: per injection the 14
    measured electrodes form a chain, so their potentials come back up to their mean; the
    two drive electrodes, touched by no pair, get 0."""
    protocol = build_protocol(ProtocolSpec(), 16)
    truth = np.random.default_rng(2).normal(0, 1, (16, 16))
    got = potentials_from_differences(protocol, protocol.measure(truth))
    for k, (source, sink) in enumerate(protocol.injections):
        measured = np.setdiff1d(np.arange(16), [source, sink])
        expected = truth[k, measured] - truth[k, measured].mean()
        np.testing.assert_allclose(got[k, measured], expected, atol=1e-12)
        assert got[k, source] == got[k, sink] == 0.0
    with pytest.raises(ValueError, match=r"expected \[\.\.\., 208\]"):
        potentials_from_differences(protocol, np.zeros(192))


# ------------------------------------------------------------------------------- command line


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--rate", "-1"], "--rate must be > 0"),
        (["--device", "openeit", "--separator", "comma"], "--separator applies to --device lines"),
        (["--device", "sciospec", "--channels", "20"], "--channels must be 16, 32, 48 or 64"),
        (["--device", "lines", "--layer", "nope"], "patch 'arm' has no layer 'nope'"),
    ],
)
def test_cli_refuses_bad_arguments_in_one_line(args, message, capsys):
    from eit_skin.cli.main import main

    assert main(["fake-device", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"eit-skin fake-device: {message}") and err.count("\n") == 1


def test_cli_lines_board_runs_a_counted_replay(capsys):
    from eit_skin.cli.main import main

    real_dir = os.path.join(ROOT, "data", "real")
    args = ["fake-device", "--device", "lines", "--separator", "semicolon", "--label", "v",
            "--patch", os.path.join(real_dir, "sciospec_adjacent.yaml"), "--count", "2",
            "--frames", os.path.join(real_dir, "sciospec_adjacent.npz"), "--linger", "0",
            "--rate", "100"]  # fmt: skip
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "lines, 208 values x 1, separator ';'" in out and "sent 2 frames" in out


def test_cli_openeit_replays_a_recording(tmp_path, hydrogel):
    _, frames = hydrogel
    link = tmp_path / "openeit"
    cmd = [sys.executable, "-m", "eit_skin.cli.main", "fake-device", "--device", "openeit",
           "--patch", os.path.join(ROOT, "data", "real", "hydrogel_ohmc16.yaml"),
           "--frames", os.path.join(ROOT, "data", "real", "hydrogel_ohmc16.npz"),
           "--link", str(link), "--rate", "100", "--count", "3", "--linger", "30"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        assert "fake device on /dev/pts/" in proc.stdout.readline()
        assert "OpenEIT, 192 magnitudes" in proc.stdout.readline()
        host = Host(str(link))
        data = host.read_until(count_frame_lines(3), "3 frame lines")
        host.close()
    finally:
        proc.terminate()
        proc.communicate(timeout=EVENT_S)
    assert data.startswith(b"OpenEIT\n")
    for index, line in enumerate(openeit_lines(data[8:])[:3]):
        expected = np.floor(frames[index] * 16 + 0.5) / 16
        np.testing.assert_array_equal(openeit_values(line), expected)
