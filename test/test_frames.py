"""The frame record's flag table against the message definition it mirrors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from eit_skin.frames import EXCLUDING_FLAGS, FLAGS, excluded_channels, flagged_as_nan

MSG = Path(__file__).resolve().parents[1] / "msg" / "EitFrame.msg"


def msg_constants() -> dict[str, int]:
    """``uint8 NAME = value`` constants of msg/EitFrame.msg."""
    pattern = re.compile(r"^\s*uint8\s+(FLAG_\w+)\s*=\s*(\d+)", re.M)
    return {name: int(value) for name, value in pattern.findall(MSG.read_text())}


def test_flag_table_is_the_message_definition():
    constants = msg_constants()
    assert constants, f"no FLAG_ constants found in {MSG}"
    assert constants == FLAGS


def test_excluding_flags_are_every_non_ok_bit():
    assert sum(v for k, v in FLAGS.items() if k != "FLAG_OK") == EXCLUDING_FLAGS
    flags = np.array([0, FLAGS["FLAG_SATURATED"], FLAGS["FLAG_INVALID"], 3], np.uint8)
    assert excluded_channels(flags, 4).tolist() == [False, True, True, True]
    assert excluded_channels(np.zeros(0, np.uint8), 3).tolist() == [False] * 3
    assert excluded_channels(None, 2).tolist() == [False, False]


def test_flagged_channels_become_nan_per_frame():
    """One frame or a stack of them: each frame's own flagged channels are NaN, nothing else
    changes, and the input is left as it was."""
    volts = np.arange(8, dtype=np.float32).reshape(2, 4)
    flags = np.array([[0, FLAGS["FLAG_SATURATED"], 0, 0], [0, 0, 0, FLAGS["FLAG_INVALID"]]])
    out = flagged_as_nan(volts, flags.astype(np.uint8))
    assert out.dtype == np.float64
    assert np.isnan(out).tolist() == [[False, True, False, False], [False, False, False, True]]
    assert out[~np.isnan(out)].tolist() == [0, 2, 3, 4, 5, 6]
    assert not np.isnan(volts).any()
    assert flagged_as_nan(volts[0], np.zeros(0, np.uint8)).tolist() == [0, 1, 2, 3]
    assert np.isnan(flagged_as_nan(volts[1], flags[1].astype(np.uint8))).tolist() == [
        False, False, False, True,
    ]  # fmt: skip
