"""Skin boards: wire protocol, serial link, device clock, emulated boards, frame sources.

``board_emulators``: OpenEIT and line-printing boards, byte for byte on a pty;
``sciospec_emulator``: the Sciospec board.

Modules: ``wire`` (binary framing and the resynchronising parser), ``serial_link``
(reconnecting serial port), ``device_clock`` (board clock -> host time), ``fake_device`` (a
board on a pseudo-terminal), ``sources`` (serial, simulated and replayed frame sources),
``boards`` (board profiles' readers: eit_skin wire, OpenEIT, line-printing boards),
``sciospec`` (Sciospec setup and data frames), ``cn0565`` (the Analog Devices CN0565 through
pyadi-iio), ``source_status`` (frame rate and status of any source), ``detect`` (which
profile a port's bytes follow).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "BoardFrame": "boards",
    "BoardReader": "boards",
    "SciospecReader": "sciospec",
    "board_reader": "sources",
    "DeviceClock": "device_clock",
    "DeviceFrame": "wire",
    "FakeDevice": "fake_device",
    "FrameParser": "wire",
    "PatternId": "wire",
    "ReplaySource": "sources",
    "SerialLink": "serial_link",
    "SerialSource": "sources",
    "SimulatedSource": "sources",
    "WireHeader": "fake_device",
    "encode_frame": "wire",
}

__all__ = [
    "BoardFrame",
    "BoardReader",
    "DeviceClock",
    "DeviceFrame",
    "FakeDevice",
    "FrameParser",
    "PatternId",
    "ReplaySource",
    "SciospecReader",
    "SerialLink",
    "SerialSource",
    "SimulatedSource",
    "WireHeader",
    "board_reader",
    "encode_frame",
]

if TYPE_CHECKING:
    from eit_skin.hardware.boards import BoardFrame, BoardReader
    from eit_skin.hardware.device_clock import DeviceClock
    from eit_skin.hardware.fake_device import FakeDevice, WireHeader
    from eit_skin.hardware.sciospec import SciospecReader
    from eit_skin.hardware.serial_link import SerialLink
    from eit_skin.hardware.sources import (
        ReplaySource,
        SerialSource,
        SimulatedSource,
        board_reader,
    )
    from eit_skin.hardware.wire import DeviceFrame, FrameParser, PatternId, encode_frame


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
