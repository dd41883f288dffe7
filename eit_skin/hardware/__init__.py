"""Skin boards: wire protocol, serial link, device clock, emulated board, frame sources.

Modules: ``wire`` (binary framing and the resynchronising parser), ``serial_link``
(reconnecting serial port), ``device_clock`` (board clock -> host time), ``fake_device`` (a
board on a pseudo-terminal), ``sources`` (serial, simulated and replayed frame sources).
"""

from __future__ import annotations

from eit_skin.hardware.device_clock import DeviceClock
from eit_skin.hardware.fake_device import FakeDevice
from eit_skin.hardware.serial_link import SerialLink
from eit_skin.hardware.sources import ReplaySource, SerialSource, SimulatedSource
from eit_skin.hardware.wire import DeviceFrame, FrameParser, PatternId, encode_frame

__all__ = [
    "DeviceClock",
    "DeviceFrame",
    "FakeDevice",
    "FrameParser",
    "PatternId",
    "ReplaySource",
    "SerialLink",
    "SerialSource",
    "SimulatedSource",
    "encode_frame",
]
