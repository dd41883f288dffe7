"""Recordings on disk: MCAP (ROS 2 bags) and the offline npz frames format.

Modules: ``recording`` (frame records, CDR codec, MCAP reader/writer, npz frames, atomic
writes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "McapFrameWriter": "recording",
    "load_frames_npz": "recording",
    "read_mcap_frames": "recording",
    "save_frames_npz": "recording",
    "write_npz_atomic": "recording",
}

__all__ = [
    "FrameRecord",
    "McapFrameWriter",
    "load_frames_npz",
    "read_mcap_frames",
    "save_frames_npz",
    "write_npz_atomic",
]

if TYPE_CHECKING:
    from eit_skin.io.recording import (
        McapFrameWriter,
        load_frames_npz,
        read_mcap_frames,
        save_frames_npz,
        write_npz_atomic,
    )


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
