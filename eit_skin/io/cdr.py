"""``eit_skin_msgs/msg/EitFrame`` as ROS 2 serialises it: CDR bytes and the message definition.

The codec is plain XCDR1 little endian (what rmw_fastrtps writes and rosbag2 stores), done with
numpy so recordings can be read and written without rclpy. ``eit_frame_msgdef`` is the
rosbag2-style concatenated ``.msg`` definition that MCAP files carry as the schema.
"""

from __future__ import annotations

import os
import struct
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from eit_skin.frames import FrameRecord

EIT_FRAME_SCHEMA = "eit_skin_msgs/msg/EitFrame"
_SEPARATOR = "=" * 80

_FALLBACK_DEFINITIONS = {
    "std_msgs/Header": (
        "# Standard metadata for higher-level stamped data types.\n"
        "# This is generally used to communicate timestamped data\n"
        "# in a particular coordinate frame.\n\n"
        "# Two-integer timestamp that is expressed as seconds and nanoseconds.\n"
        "builtin_interfaces/Time stamp\n\n"
        "# Transform frame with which this data is associated.\n"
        "string frame_id\n"
    ),
    "builtin_interfaces/Time": (
        "# This message communicates ROS Time defined here:\n"
        "# https://design.ros2.org/articles/clock_and_time.html\n\n"
        "# The seconds component, valid over all int32 values.\n"
        "int32 sec\n\n"
        "# The nanoseconds component, valid in the range [0, 1e9).\n"
        "uint32 nanosec\n"
    ),
}


def _find_msg_file(type_name: str) -> Path | None:
    """``pkg/Name`` -> its .msg file in this repository or an installed share directory."""
    package, name = type_name.split("/")
    candidates = []
    if package == "eit_skin_msgs":
        candidates.append(Path(__file__).resolve().parents[2] / "msg" / f"{name}.msg")
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    candidates += [Path(p) / "share" / package / "msg" / f"{name}.msg" for p in prefixes]
    return next((c for c in candidates if c.is_file()), None)


def eit_frame_msgdef() -> str:
    """The EitFrame definition followed by its dependencies, as rosbag2 stores it in MCAP."""
    parts = []
    for type_name in (EIT_FRAME_SCHEMA.replace("/msg/", "/"), *_FALLBACK_DEFINITIONS):
        path = _find_msg_file(type_name)
        if path is not None:
            text = path.read_text()
        elif type_name in _FALLBACK_DEFINITIONS:
            text = _FALLBACK_DEFINITIONS[type_name]
        else:
            raise FileNotFoundError(f"{type_name}.msg not found in the repository or share dirs")
        parts.append(text if not parts else f"{_SEPARATOR}\nMSG: {type_name}\n{text}")
    return "\n".join(p.rstrip("\n") for p in parts) + "\n"


_CDR_HEADER = b"\x00\x01\x00\x00"


class _CdrWriter:
    def __init__(self) -> None:
        self.buf = bytearray()

    def align(self, n: int) -> None:
        self.buf += b"\x00" * (-len(self.buf) % n)

    def pack(self, fmt: str, value: Any) -> None:
        size = struct.calcsize(fmt)
        self.align(size)
        self.buf += struct.pack("<" + fmt, value)

    def string(self, text: str) -> None:
        data = text.encode()
        self.pack("I", len(data) + 1)
        self.buf += data + b"\x00"

    def array(self, values: np.ndarray) -> None:
        self.pack("I", values.size)
        self.align(values.dtype.itemsize)
        self.buf += values.tobytes()


def encode_eit_frame_cdr(record: FrameRecord) -> bytes:
    """Serialise an EitFrame to CDR bytes (with the 4-byte encapsulation header)."""
    w = _CdrWriter()
    sec, nanosec = divmod(record.stamp_ns, 1_000_000_000)
    w.pack("i", sec)
    w.pack("I", nanosec)
    w.string(record.frame_id)
    w.string(record.patch)
    w.string(record.layer)
    w.pack("H", record.n_electrodes)
    w.string(record.drive_pattern)
    w.pack("d", record.current_a)
    w.pack("I", record.sequence)
    w.array(record.voltages.astype("<f4"))
    w.array(record.channel_flags)
    return _CDR_HEADER + bytes(w.buf)


def decode_eit_frame_cdr(data: bytes) -> FrameRecord:
    """Parse CDR bytes of an EitFrame (inverse of ``encode_eit_frame_cdr``).

    Raises:
        ValueError: not plain CDR, or truncated (the message names the byte offset).
    """
    f = read_eit_frame(data)
    # FrameRecord copies both arrays (native float32, read-only)
    return FrameRecord.of_stream(f, f.stamp_ns, f.sequence, f.voltages, f.channel_flags)


class EitFrameFields(NamedTuple):
    """An EitFrame's fields read straight from its CDR bytes (:func:`read_eit_frame`).

    ``voltages`` (float32 ``[M]`` V, the message's byte order) and ``channel_flags`` (uint8
    ``[M]`` or ``[0]``) are read-only views into the bytes, not copies.
    """

    stamp_sec: int
    stamp_nanosec: int
    frame_id: str
    patch: str
    layer: str
    n_electrodes: int
    drive_pattern: str
    current_a: float
    sequence: int
    voltages: np.ndarray
    channel_flags: np.ndarray

    @property
    def stamp_ns(self) -> int:
        """header.stamp in ns since the epoch."""
        return self.stamp_sec * 1_000_000_000 + self.stamp_nanosec


#: Little-endian (encapsulation byte 1 = 1) and big-endian readers of the fixed fields.
_ORDER = {1: "<", 0: ">"}
_STAMP = {k: struct.Struct(f"{o}iII") for k, o in _ORDER.items()}  # sec, nanosec, len(frame_id)
_U32 = {k: struct.Struct(f"{o}I") for k, o in _ORDER.items()}
_U16 = {k: struct.Struct(f"{o}H") for k, o in _ORDER.items()}
_F64_U32_U32 = {k: struct.Struct(f"{o}dII") for k, o in _ORDER.items()}
_F32 = {k: np.dtype(f"{o}f4") for k, o in _ORDER.items()}


def read_eit_frame(data: bytes) -> EitFrameFields:
    """An EitFrame's CDR bytes (as a ``raw=True`` subscription gets them) -> its fields.

    XCDR1 plain CDR of either byte order, alignment counted from the end of the 4-byte
    encapsulation header. A few microseconds: the reconstruction node reads every frame
    this way instead of letting rclpy build a message object.

    Raises:
        ValueError: not plain CDR, or the bytes end before the message does (names the
            byte offset).
    """
    n_bytes = len(data)
    if n_bytes < 20 or data[0] != 0 or data[1] > 1:
        raise ValueError(
            f"byte 0: not a plain CDR EitFrame ({bytes(data[:4]).hex()}, {n_bytes} bytes)"
        )
    order = data[1]
    u32 = _U32[order]
    pos = 0
    try:
        sec, nanosec, n = _STAMP[order].unpack_from(data, 4)
        pos = 16
        frame_id = str(data[pos : pos + n - 1], "utf-8")
        pos += n
        pos += -pos % 4
        (n,) = u32.unpack_from(data, pos)
        patch = str(data[pos + 4 : pos + 3 + n], "utf-8")
        pos += 4 + n
        pos += -pos % 4
        (n,) = u32.unpack_from(data, pos)
        layer = str(data[pos + 4 : pos + 3 + n], "utf-8")
        pos += 4 + n
        pos += pos % 2
        (n_electrodes,) = _U16[order].unpack_from(data, pos)
        pos += 2
        pos += -pos % 4
        (n,) = u32.unpack_from(data, pos)
        pattern = str(data[pos + 4 : pos + 3 + n], "utf-8")
        pos += 4 + n
        pos += -(pos - 4) % 8  # the double aligns on the payload, after the header
        current, sequence, m = _F64_U32_U32[order].unpack_from(data, pos)
        pos += 16
        voltages = np.frombuffer(data, _F32[order], m, pos)
        pos += 4 * m
        (n,) = u32.unpack_from(data, pos)
        flags = np.frombuffer(data, np.uint8, n, pos + 4)
    except (struct.error, ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"byte {pos}: EitFrame CDR ends early or is damaged ({error})") from None
    return EitFrameFields(
        sec, nanosec, frame_id, patch, layer, n_electrodes, pattern, current, sequence,
        voltages, flags,
    )  # fmt: skip


class Float32ImageCdr:
    """A ``sensor_msgs/Image`` 32FC1 ``[H, W]`` kept as its CDR bytes, refilled per frame.

    Publishing these bytes (rclpy's ``publish`` of ``bytes``) skips rclpy's conversion of a
    Python ``Image`` into a C message and its serialisation: the image node publishes every
    frame's float image this way. The layout is fixed at construction (``frame_id``, shape);
    :meth:`fill` writes the stamp and the pixels (little endian, ``is_bigendian`` 0) in place.

    Args:
        height, width: image shape, pixels.
        frame_id: header.frame_id.
    """

    def __init__(self, height: int, width: int, frame_id: str) -> None:
        self.height, self.width, self.frame_id = int(height), int(width), frame_id
        n_bytes = 4 * self.height * self.width
        w = _CdrWriter()
        w.pack("i", 0)  # header.stamp.sec, nanosec: set by fill
        w.pack("I", 0)
        w.string(frame_id)
        w.pack("I", self.height)
        w.pack("I", self.width)
        w.string("32FC1")
        w.pack("B", 0)  # is_bigendian: the pixels are written little endian
        w.pack("I", 4 * self.width)  # step, bytes per row
        w.pack("I", n_bytes)  # data: uint8[] of that many bytes
        offset = len(_CDR_HEADER) + len(w.buf)
        self._buffer = bytearray(_CDR_HEADER + w.buf) + bytearray(n_bytes)
        self._pixels = np.frombuffer(self._buffer, "<f4", self.height * self.width, offset)

    def fits(self, height: int, width: int, frame_id: str) -> bool:
        """Whether an image of this shape and frame_id can be written into these bytes."""
        return (height, width, frame_id) == (self.height, self.width, self.frame_id)

    def fill(self, stamp_sec: int, stamp_nanosec: int, image: np.ndarray) -> bytes:
        """The message's bytes for ``image`` ``[H, W]`` (any float) stamped ``sec.nanosec``."""
        _STAMP_LE.pack_into(self._buffer, 4, stamp_sec, stamp_nanosec)
        self._pixels[:] = image.reshape(-1)
        return bytes(self._buffer)


_STAMP_LE = struct.Struct("<iI")
