"""``eit-skin capture`` and ``eit-skin detect`` on a real pseudo-terminal.

The board here is a thread writing OpenEIT imaging lines (formatted in this file from the
firmware's sprintf_fixed32) to the pty's master side; the commands run as the user runs them,
in their own process.
"""

from __future__ import annotations

import itertools
import os
import select
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest
import yaml

from test.hardware.test_boards import openeit_line
from test.support.patience import EVENT_S

HYDROGEL = "data/real/hydrogel_ohmc16.yaml"


class LineBoard:
    """A pty whose master writes ``lines`` in a loop at ``rate_hz``, and records host bytes."""

    def __init__(self, lines: list[bytes], rate_hz: float = 50.0) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.lines, self.period = lines, 1.0 / rate_hz
        self.received = bytearray()
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            readable, writable, _ = select.select([self.master], [self.master], [], 0)
            if readable:
                self.received += os.read(self.master, 4096)
            if writable:
                line = self.lines[self.sent % len(self.lines)]
                os.write(self.master, line)  # a raw pty takes a line of a few kB at once
                self.sent += 1

    def __enter__(self) -> LineBoard:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture(scope="module")
def hydrogel_lines(repo):
    reference = np.load(repo / "data/real/hydrogel_ohmc16.npz")["reference"]
    # on the 1/16 grid: what the firmware's 28.4 fixed-point numbers can carry
    scaled = [np.round(reference * (1 + 0.01 * k) * 16) / 16 for k in range(5)]
    return scaled, [openeit_line(v) for v in scaled]


def eit_skin(*args, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "eit_skin.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_detect_names_the_board_its_rate_count_and_the_patch(repo, hydrogel_lines):
    _, lines = hydrogel_lines
    with LineBoard(lines) as board:
        done = eit_skin("detect", board.path, "--patch", str(repo / HYDROGEL), "--listen", "1")
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "profile openeit" in out and "192 numbers per frame" in out, out
    assert "16-electrode imaging" in out
    assert "fits: hydrogel_ohmc16/pressure\n" in out  # its device section names the board
    assert "one-frame check against pressure's model: correlation" in out
    assert board.received == b""  # detect only listens to a board that talks


def test_detect_says_so_when_nothing_is_recognised(repo):
    with LineBoard([b"hello there\r\n"], rate_hz=20) as board:
        done = eit_skin("detect", board.path, "--listen", "0.5")
    assert done.returncode == 1
    assert "no known format" in done.stdout and "no board profile recognised" in done.stdout
    assert board.received.startswith(bytes.fromhex("b4 01 00 b4"))  # the Sciospec probe


def test_capture_writes_the_frames_the_board_sent(repo, tmp_path, hydrogel_lines):
    values, lines = hydrogel_lines
    data = yaml.safe_load((repo / HYDROGEL).read_text())
    data["layers"][0]["device"] = {"profile": "openeit"}
    patch = tmp_path / "hydrogel_openeit.yaml"
    patch.write_text(yaml.safe_dump(data))
    out = tmp_path / "captured.npz"
    with LineBoard(lines) as board:
        done = eit_skin(
            "capture",
            "--patch",
            str(patch),
            "--port",
            board.path,
            "--seconds",
            "0.6",
            "--reference-seconds",
            "0.2",
            "--out",
            str(out),
        )
    assert done.returncode == 0, done.stderr
    assert board.received.startswith(b"d\nd\n")  # the 16-electrode mode line, twice
    saved = np.load(out)
    frames = saved["frames"]
    assert frames.shape[1] == 192 and len(frames) >= 5
    known = np.array(values, dtype=np.float32)
    match = [int(np.argmin(np.abs(known - f).max(axis=1))) for f in frames]
    for frame, k in zip(frames, match, strict=True):  # each frame is one the board sent
        np.testing.assert_array_equal(frame, known[k])
    assert all((b - a) % 5 == 1 for a, b in itertools.pairwise(match))  # none lost
    first = frames[saved["t"] < 0.2]
    np.testing.assert_allclose(saved["reference"], first.mean(axis=0))
    assert "wrote" in done.stderr


def test_capture_with_no_board_writes_nothing(repo, tmp_path):
    out = tmp_path / "none.npz"
    with LineBoard([b""], rate_hz=5) as board:
        done = eit_skin(
            "capture", "--patch", "arm", "--port", board.path, "--wait", "0.5", "--out", str(out)
        )
    assert done.returncode == 1 and not out.exists()
    assert "no frame from" in done.stderr and "nothing written" in done.stderr


def test_detect_finds_a_sciospec_runs_its_setup_checks_a_frame_and_stops_it(repo):
    """A Sciospec says nothing until started: detect asks, sets it up, and stops it again."""
    from eit_skin.hardware.sciospec_emulator import SciospecEmulator
    from eit_skin.io.npz import load_frames_npz
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.protocol import build_protocol

    patch = repo / "data/real/sciospec_adjacent.yaml"
    layer = load_patch(patch).layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    reference, _, _ = load_frames_npz(repo / "data/real/sciospec_adjacent.npz")
    board = SciospecEmulator(lambda i: reference, protocol, rate_hz=20.0)
    board.open()
    board.start()
    try:
        done = eit_skin("detect", board.slave_path, "--patch", str(patch), "--listen", "1")
        deadline = time.monotonic() + EVENT_S  # the board reads the stop between two frames
        while board.measuring and time.monotonic() < deadline:
            time.sleep(0.01)
        measuring_after = board.measuring
    finally:
        board.close()
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "no known format" in out and "a Sciospec device answered" in out, out
    assert "frames/s after the setup" in out and "looks right" in out, out
    assert not measuring_after  # the driver's farewell: B4 01 00 B4
