"""SerialLink on real pseudo-terminals: reading, unplug/replug through a symlink, backoff."""

from __future__ import annotations

import os
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from eit_skin.hardware.serial_link import LinkState, SerialLink
from eit_skin.hardware.wire import DeviceFrame, PatternId, encode_frame
from test.support.patience import EVENT_S


def frame(seq: int) -> DeviceFrame:
    volts = np.random.default_rng(seq).normal(0, 0.1, 208).astype(np.float32)
    return DeviceFrame(seq, 1000 * seq, 16, PatternId.ADJACENT, 1e-3, volts.astype(np.float64))


class Pty:
    """A 'device': the master end of a raw pty, exposed through a symlink."""

    def __init__(self, link: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tmp = link.with_name(link.name + ".tmp")
        tmp.symlink_to(os.ttyname(self.slave))
        tmp.replace(link)
        self.link = link

    def send(self, *frames: DeviceFrame) -> None:
        os.write(self.master, b"".join(encode_frame(f) for f in frames))

    def unplug(self) -> None:
        self.link.unlink()
        os.close(self.master)
        os.close(self.slave)


def poll_until(link: SerialLink, condition, timeout_s: float = EVENT_S) -> list:
    """Poll until ``condition(received)``; ``timeout_s`` is a safety net for a loaded machine."""
    received = []
    deadline = time.monotonic() + timeout_s
    while not condition(received):
        assert time.monotonic() < deadline, f"timed out; status {link.status()}"
        received += [r.frame for r in link.poll(timeout_s=0.01)]
    return received


def test_frames_survive_unplug_and_replug(tmp_path):
    path = tmp_path / "eit_skin_arm"
    device = Pty(path)
    link = SerialLink(str(path), backoff_initial_s=0.01, backoff_max_s=0.05)
    before = [frame(i) for i in range(5)]
    poll_until(link, lambda _: link.connected)  # pyserial flushes input on open: send after
    device.send(*before)
    assert poll_until(link, lambda r: len(r) >= 5) == before
    assert link.status().state is LinkState.CONNECTED

    device.unplug()
    poll_until(link, lambda _: not link.connected)
    for _ in range(20):  # port absent: polls keep failing quietly with bounded backoff
        assert link.poll(timeout_s=0.005) == []
    status = link.status()
    assert status.state is LinkState.DISCONNECTED
    assert status.disconnects == 1 and status.failed_attempts >= 1
    assert status.last_error and status.retry_in_s <= 0.05

    device = Pty(path)  # replug: a new pty behind the same path
    after = [frame(i) for i in range(100, 105)]
    poll_until(link, lambda _: link.connected)
    device.send(*after)
    assert poll_until(link, lambda r: len(r) >= 5) == after
    status = link.status()
    assert (status.connects, status.reconnects, status.disconnects) == (2, 1, 1)
    assert status.parser.crc_errors == 0 and status.bytes_received == 10 * 1076
    link.close()
    device.unplug()


def test_absent_port_at_start_does_not_raise(tmp_path):
    link = SerialLink(str(tmp_path / "missing"), backoff_initial_s=0.01, backoff_max_s=0.02)
    assert link.poll() == []
    status = link.status()
    assert status.state is LinkState.DISCONNECTED
    assert status.failed_attempts == 1 and "missing" in status.last_error


def test_backoff_doubles_up_to_the_bound():
    now = [0.0]
    attempts = []

    def opener(port, baud):
        attempts.append(now[0])
        raise OSError("no such device")

    link = SerialLink(
        "/dev/x", opener=opener, clock=lambda: now[0], backoff_initial_s=0.1, backoff_max_s=1.0
    )
    for step in range(800):  # 8 s of polling every 10 ms
        now[0] = step * 0.01
        link.poll()
    gaps = np.round(np.diff(attempts), 6)
    np.testing.assert_allclose(gaps[:6], [0.1, 0.2, 0.4, 0.8, 1.0, 1.0], atol=0.011)
    assert gaps.max() <= 1.0 + 0.011


def test_thread_api_delivers_frames_and_state_changes(tmp_path):
    path = tmp_path / "eit_skin_leg"
    device = Pty(path)
    got, states = [], []
    changed = threading.Condition()  # the link's thread calls back; the test waits on it

    def on_frames(batch):
        with changed:
            got.extend(r.frame for r in batch)
            changed.notify_all()

    def on_state(state):
        with changed:
            states.append(state)
            changed.notify_all()

    def wait_for(predicate) -> None:
        with changed:  # 60 s: a safety net for a loaded machine, not a bound on the link
            assert changed.wait_for(predicate, timeout=EVENT_S), (got, states)

    link = SerialLink(str(path), backoff_initial_s=0.01, backoff_max_s=0.05)
    link.start(on_frames, on_state, poll_timeout_s=0.01)
    wait_for(lambda: len(states) >= 1)
    sent = [frame(i) for i in range(3)]
    device.send(*sent)
    wait_for(lambda: len(got) >= 3)
    device.unplug()
    wait_for(lambda: len(states) >= 2)
    link.stop()
    assert got == sent
    assert [s.state for s in states[:2]] == [LinkState.CONNECTED, LinkState.DISCONNECTED]
    with pytest.raises(RuntimeError):
        link.start(on_frames)
        link.start(on_frames)
    link.stop()
