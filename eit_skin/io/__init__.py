"""Recordings on disk: MCAP (ROS 2 bags) and the offline npz frames format.

Modules: ``cdr`` (EitFrame CDR codec and message definition), ``mcap`` (crash-safe MCAP
writer, reader that recovers unfinished files), ``npz`` (the offline frames format, atomic npz
writes), ``conversion`` (MCAP <-> npz, ``eit-skin frames``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from eit_skin import lazy_exports

#: Public name -> the module of this subpackage that defines it (imported on first use,
#: so importing one module never imports the whole subpackage).
_EXPORTS: dict[str, str] = {
    "EIT_FRAME_SCHEMA": "cdr",
    "FrameStream": "conversion",
    "McapDamage": "mcap",
    "McapFrameWriter": "mcap",
    "decode_eit_frame_cdr": "cdr",
    "eit_frame_msgdef": "cdr",
    "encode_eit_frame_cdr": "cdr",
    "load_frames_npz": "npz",
    "mcap_to_npz": "conversion",
    "npz_to_mcap": "conversion",
    "read_mcap_frames": "mcap",
    "save_frames_npz": "npz",
    "write_npz_atomic": "npz",
}

__all__ = [
    "EIT_FRAME_SCHEMA",
    "FrameStream",
    "McapDamage",
    "McapFrameWriter",
    "decode_eit_frame_cdr",
    "eit_frame_msgdef",
    "encode_eit_frame_cdr",
    "load_frames_npz",
    "mcap_to_npz",
    "npz_to_mcap",
    "read_mcap_frames",
    "save_frames_npz",
    "write_npz_atomic",
]

if TYPE_CHECKING:
    from eit_skin.io.cdr import (
        EIT_FRAME_SCHEMA,
        decode_eit_frame_cdr,
        eit_frame_msgdef,
        encode_eit_frame_cdr,
    )
    from eit_skin.io.conversion import FrameStream, mcap_to_npz, npz_to_mcap
    from eit_skin.io.mcap import McapDamage, McapFrameWriter, read_mcap_frames
    from eit_skin.io.npz import load_frames_npz, save_frames_npz, write_npz_atomic


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
