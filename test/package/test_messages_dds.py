"""Two separate processes exchange EitFrame and TouchEvent over real Fast DDS."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

PEER = Path(__file__).parents[1] / "support" / "dds_peer.py"


def test_frame_and_event_cross_process_boundary() -> None:
    echo = subprocess.Popen(
        [sys.executable, str(PEER), "echo"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    pub = subprocess.Popen([sys.executable, str(PEER), "pub"], stderr=subprocess.PIPE, text=True)
    try:
        out, err = echo.communicate(timeout=EVENT_S)
    finally:
        pub.terminate()
        pub.wait(timeout=EVENT_S)
        echo.kill()
    assert echo.returncode == 0, err
    got = json.loads(out.strip().splitlines()[-1])

    frame = got["frame"]
    assert frame["stamp"] == [1700000000, 123456789]
    assert frame["frame_id"] == "arm_skin_link"
    assert (frame["patch"], frame["layer"]) == ("arm", "pressure")
    assert frame["n_electrodes"] == 16 and frame["drive_pattern"] == "adjacent"
    assert frame["current_a"] == pytest.approx(1e-3, rel=0, abs=0)
    assert frame["sequence"] >= 1
    sent = np.array([0.001 * i - 0.1 for i in range(208)], dtype=np.float32)
    np.testing.assert_array_equal(np.array(frame["voltages"], dtype=np.float32), sent)
    assert frame["flags"] == [1 if i == 7 else 0 for i in range(208)]

    event = got["event"]
    assert event["label"] == 2 and event["state"] == 0  # PINCH, START
    assert event["confidence"] == pytest.approx(0.75)
    assert event["centroid"] == pytest.approx([0.01, -0.02, 0.0])
    assert event["area_m2"] == pytest.approx(2.5e-4)
    assert event["peak"] == pytest.approx(1500.0)
    assert event["duration"] == [1, 500000000]


def test_message_constants_match_documentation() -> None:
    from eit_skin_msgs.msg import EitFrame, TouchEvent

    assert (TouchEvent.PUSH, TouchEvent.RUB, TouchEvent.PINCH, TouchEvent.GRAB) == (0, 1, 2, 3)
    assert (TouchEvent.START, TouchEvent.UPDATE, TouchEvent.END) == (0, 1, 2)
    assert (EitFrame.FLAG_OK, EitFrame.FLAG_SATURATED, EitFrame.FLAG_INVALID) == (0, 1, 2)
