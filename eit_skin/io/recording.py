"""Recording and replay files: MCAP with ROS 2 encoding, and the offline ``.npz`` frames format.

MCAP: one channel per topic, message encoding ``cdr``, schema ``eit_skin_msgs/msg/EitFrame``
with encoding ``ros2msg`` and the rosbag2-style concatenated definition, so ``ros2 bag`` and
Foxglove read the files. Messages are (de)serialised here with numpy (no rclpy needed); the
writer accepts real ``eit_skin_msgs.msg.EitFrame`` objects as well as ``FrameRecord``.

npz (the stable input of ``eit-skin reconstruct``): ``reference`` float [M] volts (finite),
``frames`` float [T, M] volts (T >= 1, NaN marks a missing value), optional ``t`` float [T]
seconds.
"""

from __future__ import annotations

import os
import struct
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.frames import FrameRecord, excluded_channels

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
        candidates.append(Path(__file__).resolve().parents[1] / "msg" / f"{name}.msg")
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


# --- CDR (XCDR1 little endian) for EitFrame, vectorised ---------------------------------------

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


class _CdrReader:
    def __init__(self, data: bytes) -> None:
        if data[:2] != b"\x00\x01":
            raise ValueError(f"not little-endian plain CDR (encapsulation {data[:4].hex()})")
        self.data = memoryview(data)[4:]
        self.pos = 0

    def align(self, n: int) -> None:
        self.pos += -self.pos % n

    def unpack(self, fmt: str) -> Any:
        size = struct.calcsize(fmt)
        self.align(size)
        (value,) = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return value

    def string(self) -> str:
        n = self.unpack("I")
        text = bytes(self.data[self.pos : self.pos + n]).rstrip(b"\x00").decode()
        self.pos += n
        return text

    def array(self, dtype: str) -> np.ndarray:
        n = self.unpack("I")
        dt = np.dtype(dtype)
        self.align(dt.itemsize)
        values = np.frombuffer(self.data, dt, n, self.pos).copy()
        self.pos += n * dt.itemsize
        return values


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
    """Parse CDR bytes of an EitFrame (inverse of ``encode_eit_frame_cdr``)."""
    r = _CdrReader(data)
    sec = r.unpack("i")
    nanosec = r.unpack("I")
    return FrameRecord(
        stamp_ns=sec * 1_000_000_000 + nanosec,
        frame_id=r.string(),
        patch=r.string(),
        layer=r.string(),
        n_electrodes=r.unpack("H"),
        drive_pattern=r.string(),
        current_a=r.unpack("d"),
        sequence=r.unpack("I"),
        voltages=r.array("<f4"),
        channel_flags=r.array("u1"),
    )


# --- MCAP ---------------------------------------------------------------------------------------


class McapFrameWriter:
    """Write EitFrame messages to an MCAP file (ROS 2 profile, zstd chunks).

    Use as a context manager or call ``close()``; the file is complete only after closing.
    """

    def __init__(self, path: str | Path) -> None:
        from mcap.writer import Writer

        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file)
        self._writer.start(profile="ros2", library="eit_skin")
        self._schema_id = self._writer.register_schema(
            name=EIT_FRAME_SCHEMA, encoding="ros2msg", data=eit_frame_msgdef().encode()
        )
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self.messages = 0

    def write(self, topic: str, frame: FrameRecord | Any, log_time_ns: int | None = None) -> None:
        """Append one message; ``frame`` is a FrameRecord or an EitFrame message.

        ``log_time_ns`` is the recording time, ns since the epoch (default: the header stamp).
        """
        record = frame if isinstance(frame, FrameRecord) else FrameRecord.from_msg(frame)
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schema_id
            )
            self._channels[topic] = channel
        log_time = record.stamp_ns if log_time_ns is None else int(log_time_ns)
        self._writer.add_message(
            channel_id=channel,
            log_time=log_time,
            publish_time=log_time,
            sequence=self._sequence,
            data=encode_eit_frame_cdr(record),
        )
        self._sequence += 1
        self.messages += 1

    def close(self) -> None:
        if not self._file.closed:
            self._writer.finish()
            self._file.close()

    def __enter__(self) -> McapFrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_mcap_frames(
    path: str | Path, topics: list[str] | None = None
) -> Iterator[tuple[str, int, FrameRecord]]:
    """Yield (topic, log_time_ns, FrameRecord) for every EitFrame message, in log-time order.

    Channels with another schema are skipped. Raises ValueError naming the file and topic if a
    message does not decode.
    """
    from mcap.reader import make_reader

    with open(path, "rb") as stream:
        reader = make_reader(stream)
        for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            if (
                schema is None
                or schema.name != EIT_FRAME_SCHEMA
                or channel.message_encoding != "cdr"
            ):
                continue
            try:
                record = decode_eit_frame_cdr(message.data)
            except (ValueError, struct.error, UnicodeDecodeError) as error:
                raise ValueError(
                    f"{path}: topic {channel.topic}, log_time {message.log_time}: "
                    f"undecodable EitFrame ({error})"
                ) from error
            yield channel.topic, message.log_time, record


# --- npz ----------------------------------------------------------------------------------------


def _check_frames(
    where: str,
    reference: Any,
    frames: Any,
    t: Any | None,
    n_measurements: int | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    def real_array(key: str, value: Any) -> np.ndarray:
        array = np.asarray(value)
        if array.dtype.kind not in "fiu":
            raise ValueError(f"{where}: '{key}' must be real numbers, got dtype {array.dtype}")
        return array.astype(np.float64)

    reference = real_array("reference", reference)
    frames = real_array("frames", frames)
    if reference.ndim != 1 or reference.size == 0:
        raise ValueError(f"{where}: 'reference' must have shape [M], got {reference.shape}")
    m = reference.size
    if not np.isfinite(reference).all():
        bad = int(np.flatnonzero(~np.isfinite(reference))[0])
        raise ValueError(f"{where}: 'reference' has a non-finite value at index {bad}")
    if frames.ndim != 2 or frames.shape[0] == 0 or frames.shape[1] != m:
        raise ValueError(
            f"{where}: 'frames' must have shape [T>=1, M={m}] like 'reference', got {frames.shape}"
        )
    if n_measurements is not None and m != n_measurements:
        raise ValueError(
            f"{where}: 'reference' has M={m} measurements, the protocol expects {n_measurements}"
        )
    if t is not None:
        t = real_array("t", t)
        if t.shape != (frames.shape[0],) or not np.isfinite(t).all():
            raise ValueError(
                f"{where}: 't' must be finite with shape [T={frames.shape[0]}], got {t.shape}"
            )
    return reference, frames, t


def save_frames_npz(
    path: str | Path, reference: np.ndarray, frames: np.ndarray, t: np.ndarray | None = None
) -> None:
    """Write the offline frames file atomically (temporary file + rename).

    Args:
        path: destination (the name is used as given; no ``.npz`` is appended).
        reference: float [M] volts, finite.
        frames: float [T, M] volts.
        t: optional float [T] seconds.
    """
    path = Path(path)
    reference, frames, t = _check_frames(str(path), reference, frames, t, None)
    arrays = {"reference": reference, "frames": frames}
    if t is not None:
        arrays["t"] = t
    write_npz_atomic(path, **arrays)


def write_npz_atomic(path: str | Path, **arrays: np.ndarray | float) -> None:
    """Write an npz next to ``path`` and rename it into place: complete or absent, never half.

    The name is used as given (no ``.npz`` appended); a failure removes the temporary file
    and re-raises.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "wb") as stream:
            np.savez(stream, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_frames_npz(
    path: str | Path, n_measurements: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read and validate an offline frames file: returns (reference [M], frames [T, M], t|None).

    Raises ValueError naming the file and key for a missing key, a wrong shape or dtype, a
    non-finite reference or an M different from ``n_measurements``.
    """
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError("a single .npy array, not an .npz archive")
        with data:
            arrays = {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as error:
        raise ValueError(f"{path}: not a readable .npz frames file ({error})") from error
    for key in ("reference", "frames"):
        if key not in arrays:
            raise ValueError(f"{path}: missing key '{key}' (found {sorted(arrays)})")
    return _check_frames(
        str(path), arrays["reference"], arrays["frames"], arrays.get("t"), n_measurements
    )


# --- conversion -----------------------------------------------------------------------------------


def mcap_to_npz(
    mcap_path: str | Path,
    npz_path: str | Path,
    topic: str | None = None,
    reference_frames: int = 1,
) -> int:
    """Export one topic's frames to the npz format; returns T.

    ``frames`` are the voltages (float32 -> float64, NaN where a flag keeps the channel out of
    imaging: saturated or invalid, as the reconstruction pipeline treats it), ``t`` the header
    stamps in seconds since the epoch, ``reference`` the NaN-ignoring mean of the first
    ``reference_frames`` frames (a channel flagged in all of them - e.g. stuck at the rail -
    gets the mean of its flagged values there: a finite placeholder, never imaged since the
    channel is NaN in those frames). With ``topic=None`` the file must hold exactly one
    EitFrame topic.
    """
    head_size = max(1, reference_frames)
    rows, raw_head, stamps, seen = [], [], [], set()
    for name, _, record in read_mcap_frames(mcap_path, [topic] if topic else None):
        seen.add(name)
        if len(seen) > 1:
            raise ValueError(f"{mcap_path}: several EitFrame topics {sorted(seen)}; pass topic=")
        volts = record.voltages.astype(np.float64)
        if len(raw_head) < head_size:
            raw_head.append(volts.copy())
        if record.channel_flags.size:
            volts[excluded_channels(record.channel_flags, volts.size)] = np.nan
        if rows and volts.size != rows[0].size:
            raise ValueError(f"{mcap_path}: topic {name} changes M from {rows[0].size}")
        rows.append(volts)
        stamps.append(record.stamp_ns)
    if not rows:
        raise ValueError(f"{mcap_path}: no EitFrame messages" + (f" on {topic}" if topic else ""))
    frames = np.stack(rows)
    head = frames[:head_size]
    reference = np.full(frames.shape[1], np.nan)
    for values in (head, np.stack(raw_head)):  # flagged values only where nothing else
        missing = ~np.isfinite(reference) & ~np.isnan(values).all(axis=0)
        reference[missing] = np.nanmean(values[:, missing], axis=0)
    if not np.isfinite(reference).all():
        raise ValueError(
            f"{mcap_path}: channel {int(np.flatnonzero(~np.isfinite(reference))[0])} is invalid "
            f"in all of the first {len(head)} frames, so there is no reference; raise "
            "reference_frames"
        )
    save_frames_npz(npz_path, reference, frames, np.asarray(stamps, dtype=np.int64) / 1e9)
    return len(rows)


def npz_to_mcap(
    npz_path: str | Path,
    mcap_path: str | Path,
    topic: str,
    *,
    patch: str,
    layer: str,
    n_electrodes: int,
    drive_pattern: str = "adjacent",
    current_a: float = 1e-3,
    frame_id: str = "",
    rate_hz: float = 50.0,
    start_ns: int = 0,
) -> int:
    """Write an npz file's frames as EitFrame messages; returns T.

    Stamps come from ``t`` (seconds since the epoch) or, without it, ``start_ns`` + i /
    ``rate_hz``. NaN values are written as NaN with FLAG_INVALID. The reference is not stored
    (MCAP holds raw frames only).
    """
    _, frames, t = load_frames_npz(npz_path)
    if t is not None:
        stamps = np.round(t * 1e9).astype(np.int64)
    else:
        stamps = start_ns + np.round(np.arange(frames.shape[0]) * (1e9 / rate_hz)).astype(np.int64)
    flags = np.where(np.isnan(frames), 2, 0).astype(np.uint8)
    with McapFrameWriter(mcap_path) as writer:
        for i in range(frames.shape[0]):
            writer.write(
                topic,
                FrameRecord(
                    stamp_ns=int(stamps[i]),
                    frame_id=frame_id,
                    patch=patch,
                    layer=layer,
                    n_electrodes=n_electrodes,
                    drive_pattern=drive_pattern,
                    current_a=current_a,
                    sequence=i % 2**32,
                    voltages=frames[i],
                    channel_flags=flags[i],
                ),
            )
    return int(frames.shape[0])
