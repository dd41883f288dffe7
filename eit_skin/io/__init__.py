"""Recordings on disk: MCAP (ROS 2 bags) and the offline npz frames format.

Modules: ``recording`` (frame records, CDR codec, MCAP reader/writer, npz frames, atomic
writes).
"""

from __future__ import annotations

from eit_skin.io.recording import (
    FrameRecord,
    McapFrameWriter,
    load_frames_npz,
    read_mcap_frames,
    save_frames_npz,
    write_npz_atomic,
)

__all__ = [
    "FrameRecord",
    "McapFrameWriter",
    "load_frames_npz",
    "read_mcap_frames",
    "save_frames_npz",
    "write_npz_atomic",
]
