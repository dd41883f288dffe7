"""The emulated board end to end: FakeDevice on a pty -> SerialLink -> frames bit-exact."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from eit_skin.hardware.fake_device import FakeDevice, WireHeader
from eit_skin.hardware.serial_link import SerialLink
from eit_skin.hardware.wire import ValueEncoding
from eit_skin.io.npz import save_frames_npz
from test.support.patience import EVENT_S


def source(i: int) -> np.ndarray:
    return np.random.default_rng(i).normal(0.0, 0.2, 208)


def read_frames(link: SerialLink, n: int, timeout_s: float = EVENT_S) -> list:
    """Poll until ``n`` frames came; ``timeout_s`` is a safety net for a loaded machine."""
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n:
        assert time.monotonic() < deadline, f"got {len(got)} of {n}; {link.status()}"
        got += [r.frame for r in link.poll(timeout_s=0.01)]
    return got


def wait_connected(link: SerialLink, timeout_s: float = EVENT_S) -> None:
    """Poll until connected; ``timeout_s`` is a safety net for a loaded machine."""
    deadline = time.monotonic() + timeout_s
    while not link.connected:
        assert time.monotonic() < deadline, link.status()
        link.poll(timeout_s=0.01)


@pytest.mark.parametrize("encoding", list(ValueEncoding))
def test_fake_device_to_serial_link_is_bit_exact(encoding):
    with FakeDevice(source, rate_hz=400.0, header=WireHeader(value_encoding=encoding)) as device:
        link = SerialLink(device.slave_path)
        wait_connected(link)
        device.start(count=40)
        got = read_frames(link, 40)
        link.close()
    assert [f.sequence for f in got] == list(range(40))
    for f in got:
        expected = device.frame(f.sequence, device_time_us=f.device_time_us)
        assert f == expected
        if encoding is ValueEncoding.FLOAT32_VOLTS:
            np.testing.assert_array_equal(f.voltages_v, source(f.sequence).astype(np.float32))
        else:
            assert np.abs(f.voltages_v - source(f.sequence)).max() <= device.volts_per_count / 2
    times = [f.device_time_us for f in got]
    assert np.diff(times).tolist() == [2500] * 39  # stamped on the 400 Hz schedule
    assert link.status().parser.errors == 0


def test_a_finite_run_writes_its_last_frames_once_a_lagging_reader_makes_room():
    """300 frames (~300 kB, far more than a pty holds) sent at 5 kHz to a reader that
    reads nothing until the device has queued them all: every one still arrives, in order
    (a loaded run once read 23 of 40: the tail stayed queued once the run ended)."""
    n = 300
    with FakeDevice(source, rate_hz=5000.0) as device:
        link = SerialLink(device.slave_path)
        wait_connected(link)
        device.start(count=n)
        deadline = time.monotonic() + EVENT_S  # safety net; it ends on the event
        while device.frames_sent < n:
            assert time.monotonic() < deadline, device.frames_sent
            time.sleep(0.01)
        assert device.pending_bytes > 0  # the reader has not made room: frames are queued
        got = read_frames(link, n)
        link.close()
    assert [f.sequence for f in got] == list(range(n))
    assert device.frames_dropped == 0 and device.pending_bytes == 0


def test_unplug_and_replug_through_the_symlink(tmp_path):
    path = tmp_path / "eit_skin_arm"
    device = FakeDevice(source, rate_hz=500.0)
    device.open()
    device.link(path)
    link = SerialLink(str(path), backoff_initial_s=0.01, backoff_max_s=0.05)
    wait_connected(link)
    for i in range(5):
        device.send(device.frame(i))
    before = read_frames(link, 5)
    device.unplug()
    assert not path.exists()
    deadline = time.monotonic() + 60.0  # safety net on a loaded machine: it ends on the event
    while link.connected:
        assert time.monotonic() < deadline
        link.poll(timeout_s=0.01)
    device.open()  # the same link path now points at a new pty
    assert path.resolve() == Path(device.slave_path)
    wait_connected(link)
    for i in range(5, 10):
        device.send(device.frame(i))
    after = read_frames(link, 5)
    device.close()
    link.close()
    assert [f.sequence for f in before + after] == list(range(10))
    status = link.status()
    assert (status.reconnects, status.disconnects) == (1, 1)


def test_link_refuses_to_replace_a_regular_file(tmp_path):
    target = tmp_path / "precious"
    target.write_text("keep me")
    with FakeDevice(lambda i: np.zeros(208)) as device, pytest.raises(FileExistsError):
        device.link(target)
    assert target.read_text() == "keep me"


def test_a_failing_frame_source_is_reported_by_stop_not_lost():
    """The sending thread dies on the source's error: stop() raises it with the frame count,
    so a dead fake board never looks like a quiet one."""

    def failing(i: int) -> np.ndarray:
        if i == 3:
            raise ValueError("frame 3 is corrupt")
        return source(i)

    device = FakeDevice(failing, rate_hz=1000.0)
    device.open()
    device.start()
    device._thread.join(60.0)  # the thread ends by itself at frame 3
    assert isinstance(device.failed, ValueError)
    with pytest.raises(RuntimeError, match=r"after 3 frames.*frame 3 is corrupt"):
        device.close()
    assert device.slave_path == ""  # unplugged all the same


def test_cli_streams_an_npz_file_on_a_symlink(tmp_path):
    frames = np.random.default_rng(0).normal(0, 0.1, (7, 208))
    npz = tmp_path / "in.npz"
    save_frames_npz(npz, frames[0], frames)
    link_path = tmp_path / "eit_skin_test"
    cmd = [sys.executable, "-m", "eit_skin.cli.main", "fake-device", "--link", str(link_path),
           "--rate", "200", "--frames", str(npz)]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        first_line = proc.stdout.readline()
        assert "fake device on /dev/pts/" in first_line and str(link_path) in first_line
        link = SerialLink(str(link_path))
        wait_connected(link)
        got = read_frames(link, 20)
        link.close()
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        out, _ = proc.communicate(timeout=EVENT_S)
    assert proc.returncode == 0
    assert "sent" in out and not link_path.exists()
    seqs = [f.sequence for f in got]
    assert len(seqs) >= 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    for f in got:
        np.testing.assert_array_equal(f.voltages_v, frames[f.sequence % 7].astype(np.float32))


def test_cli_without_frames_streams_the_simulator(tmp_path):
    """Without --frames the device sends physics: the arm's pressure layer under a push."""
    from eit_skin.patch.loading import load_patch
    from eit_skin.resources import config_path
    from eit_skin.sim.simulator import SkinSimulator

    link_path = tmp_path / "eit_skin_sim"
    cmd = [sys.executable, "-m", "eit_skin.cli.main", "fake-device", "--link", str(link_path),
           "--rate", "100", "--patch", "arm", "--scenario", "push", "--seed", "3"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        assert "fake device on /dev/pts/" in proc.stdout.readline()
        assert "simulator: patch arm, layer pressure" in proc.stdout.readline()
        link = SerialLink(str(link_path))
        wait_connected(link)
        got = read_frames(link, 10)
        link.close()
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        proc.communicate(timeout=EVENT_S)
    patch = load_patch(config_path("arm"))
    simulator = SkinSimulator(patch, "push", rate_hz=100, seed=3)
    layer = patch.layer("pressure")
    for frame in got:
        expected = simulator.frame(frame.sequence % simulator.n_frames)["pressure"].voltages_v
        np.testing.assert_array_equal(frame.voltages_v, expected.astype(np.float32))
        assert frame.n_electrodes == layer.n_electrodes
        assert frame.current_a == np.float32(layer.current_a)
