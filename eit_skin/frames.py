"""The frame record and its channel flag table: the ROS-free form of one ``EitFrame``.

A layer's frames travel on ``<namespace>/<layer>/frames`` (:data:`FRAMES_TOPIC_NAME`; the topic
map ``eit_skin.ros.topics`` builds the names, recordings are read by :func:`is_frames_topic`).

One frame is one drive cycle of one layer: ``M`` differential voltages in the protocol's
measurement order (:class:`eit_skin.patch.protocol.Protocol`) with one flag byte per channel.
The flag bits are defined here once; ``msg/EitFrame.msg`` declares the same constants (a test
checks that they agree), and the wire parser, the ADC model and the pipeline use these names.
"""

from __future__ import annotations

import array
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Channel flag bits (``EitFrame.channel_flags``): name -> bit, as in ``msg/EitFrame.msg``.
FLAG_OK = 0
FLAG_SATURATED = 1
"""The ADC hit a rail during this channel's conversions."""
FLAG_INVALID = 2
"""Not a measurement (NaN, dead channel, firmware marked it bad)."""
FLAG_OUT_OF_RANGE = 4
"""Beyond the board's full scale (the layer's ``full_scale_v``): no measurement of the sheet."""
FLAG_JUMP = 8
"""Jumped more than ``jump_k`` times the channel's measured noise since the previous frame."""
FLAGS: dict[str, int] = {
    "FLAG_OK": FLAG_OK,
    "FLAG_SATURATED": FLAG_SATURATED,
    "FLAG_INVALID": FLAG_INVALID,
    "FLAG_OUT_OF_RANGE": FLAG_OUT_OF_RANGE,
    "FLAG_JUMP": FLAG_JUMP,
}
#: Flags that keep a channel out of imaging.
EXCLUDING_FLAGS = FLAG_SATURATED | FLAG_INVALID | FLAG_OUT_OF_RANGE | FLAG_JUMP
#: Last name of the topic that carries a layer's frames: ``<namespace>/<layer>/frames``.
FRAMES_TOPIC_NAME = "frames"


def is_frames_topic(topic: str, layer: str) -> bool:
    """Whether ``topic`` carries the frames of ``layer`` (``.../<layer>/frames``, any namespace)."""
    return f"/{topic.lstrip('/')}".endswith(f"/{layer}/{FRAMES_TOPIC_NAME}")


def excluded_channels(flags: np.ndarray | None, n_channels: int) -> np.ndarray:
    """Bool ``[M]``: channels whose flags exclude them from imaging (none if ``flags`` is empty)."""
    if flags is None or np.size(flags) == 0:
        return np.zeros(n_channels, dtype=bool)
    return (np.asarray(flags, dtype=np.uint8) & EXCLUDING_FLAGS) != 0


def implausible_flags(
    volts: np.ndarray,
    full_scale_v: float | None,
    jump_limit_v: np.ndarray | None,
    previous_v: np.ndarray | None,
    accepted_v: np.ndarray | None = None,
) -> np.ndarray:
    """uint8 ``[M]``: :data:`FLAG_OUT_OF_RANGE` and :data:`FLAG_JUMP` bits of one frame.

    Args:
        volts: ``[M]`` the frame, V (NaN: missing, never flagged here).
        full_scale_v: the board's full scale, V (``|v| > full_scale_v`` is out of range);
            None: not known, no range check.
        jump_limit_v: ``[M]`` largest plausible change in one frame, V; None: no jump check.
        previous_v: ``[M]`` the previous frame as received, V (NaN: no comparison).
        accepted_v: ``[M]`` each channel's last value not flagged, V; a jump must also be
            one from it, so the way back from a one-frame spike is not flagged. None: the
            previous frame's.
    """
    v = np.asarray(volts, dtype=np.float64)
    flags = np.zeros(v.shape, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        if full_scale_v is not None:
            flags[np.abs(v) > full_scale_v] |= FLAG_OUT_OF_RANGE
        if previous_v is not None and jump_limit_v is not None:
            jumped = np.abs(v - previous_v) > jump_limit_v
            if accepted_v is not None:
                jumped &= np.abs(v - accepted_v) > jump_limit_v
            flags[jumped] |= FLAG_JUMP
    return flags


def flagged_as_nan(voltages: np.ndarray, flags: np.ndarray | None) -> np.ndarray:
    """float64 copy of ``voltages`` ``[M]`` or ``[T, M]``, NaN where ``flags`` exclude it.

    ``flags``: uint8 of the same shape, or empty (nothing excluded). What ``eit-skin frames
    export`` writes and what the pipeline images: a flagged channel and a NaN are the same
    missing value.
    """
    volts = np.array(voltages, dtype=np.float64)
    if flags is not None and np.size(flags):
        volts[excluded_channels(flags, volts.size)] = np.nan
    return volts


#: The :class:`FrameRecord` fields every frame of one stream shares.
STREAM_FIELDS = ("frame_id", "patch", "layer", "n_electrodes", "drive_pattern", "current_a")


@dataclass(frozen=True, eq=False)
class FrameRecord:
    """The fields of one EitFrame message, ROS-free.

    Attributes:
        stamp_ns: header.stamp, acquisition time, ns since the epoch.
        frame_id: header.frame_id.
        patch, layer: names from the patch config.
        n_electrodes: electrodes on the layer.
        drive_pattern: protocol name (adjacent, opposite, skip-k, explicit).
        current_a: injected current, amperes.
        sequence: device frame counter (uint32).
        voltages: float32 [M] volts, read-only.
        channel_flags: uint8 [M] (or [0] = all OK), read-only.
    """

    stamp_ns: int
    frame_id: str
    patch: str
    layer: str
    n_electrodes: int
    drive_pattern: str
    current_a: float
    sequence: int
    voltages: np.ndarray
    channel_flags: np.ndarray

    def __post_init__(self) -> None:
        volts = np.array(self.voltages, dtype=np.float32).reshape(-1)
        flags = np.array(self.channel_flags, dtype=np.uint8).reshape(-1)
        if flags.size not in (0, volts.size):
            raise ValueError(f"channel_flags has {flags.size} entries for {volts.size} voltages")
        if not 0 <= self.sequence < 2**32 or not 0 <= self.n_electrodes < 2**16:
            raise ValueError("sequence must be uint32 and n_electrodes uint16")
        volts.setflags(write=False)
        flags.setflags(write=False)
        object.__setattr__(self, "voltages", volts)
        object.__setattr__(self, "channel_flags", flags)
        object.__setattr__(self, "stamp_ns", int(self.stamp_ns))
        object.__setattr__(self, "current_a", float(self.current_a))

    def __eq__(self, other: object) -> bool:
        """Field-wise equality with bit-exact arrays."""
        if not isinstance(other, FrameRecord):
            return NotImplemented
        scalars = ("stamp_ns", "frame_id", "patch", "layer", "n_electrodes", "drive_pattern")
        return (
            all(getattr(self, k) == getattr(other, k) for k in scalars)
            and struct.pack("<d", self.current_a) == struct.pack("<d", other.current_a)
            and self.sequence == other.sequence
            and self.voltages.tobytes() == other.voltages.tobytes()
            and self.channel_flags.tobytes() == other.channel_flags.tobytes()
        )

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def of_stream(
        cls,
        stream: Any,
        stamp_ns: int,
        sequence: int,
        voltages: np.ndarray,
        channel_flags: np.ndarray,
    ) -> FrameRecord:
        """One frame of ``stream``: any object with the attributes named in :data:`STREAM_FIELDS`.

        Args:
            stream: where ``frame_id``, ``patch``, ``layer``, ``n_electrodes``,
                ``drive_pattern`` and ``current_a`` are read.
            stamp_ns: time stamp, ns since the epoch.
            sequence: device frame counter (uint32).
            voltages: ``[M]`` volts.
            channel_flags: uint8 ``[M]`` (or ``[0]``: all OK).
        """
        return cls(
            stamp_ns=stamp_ns,
            sequence=sequence,
            voltages=voltages,
            channel_flags=channel_flags,
            **{name: getattr(stream, name) for name in STREAM_FIELDS},
        )

    @classmethod
    def from_msg(cls, msg: Any) -> FrameRecord:
        """From an ``eit_skin_msgs.msg.EitFrame`` (or any object with its attributes)."""
        stamp = msg.header.stamp
        return cls(
            stamp_ns=int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec),
            frame_id=msg.header.frame_id,
            patch=msg.patch,
            layer=msg.layer,
            n_electrodes=msg.n_electrodes,
            drive_pattern=msg.drive_pattern,
            current_a=msg.current_a,
            sequence=msg.sequence,
            voltages=np.asarray(msg.voltages, dtype=np.float32),
            channel_flags=np.frombuffer(bytes(msg.channel_flags), np.uint8)
            if isinstance(msg.channel_flags, (bytes, bytearray))
            else np.asarray(msg.channel_flags, dtype=np.uint8),
        )

    def to_msg(self) -> Any:
        """To an ``eit_skin_msgs.msg.EitFrame`` (needs the built messages and rclpy)."""
        from eit_skin_msgs.msg import EitFrame

        msg = EitFrame()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(self.stamp_ns, 1_000_000_000)
        msg.header.frame_id = self.frame_id
        msg.patch, msg.layer = self.patch, self.layer
        msg.n_electrodes = self.n_electrodes
        msg.drive_pattern = self.drive_pattern
        msg.current_a = self.current_a
        msg.sequence = self.sequence
        msg.voltages = array.array("f", self.voltages.tobytes())  # 10x faster than a list
        msg.channel_flags = array.array("B", self.channel_flags.tobytes())
        return msg
