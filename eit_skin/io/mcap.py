"""EitFrame recordings in MCAP with the ROS 2 profile (what ``ros2 bag`` and Foxglove read).

One channel per topic, message encoding ``cdr``, schema ``eit_skin_msgs/msg/EitFrame`` with
encoding ``ros2msg`` and the rosbag2-style concatenated definition (:mod:`eit_skin.io.cdr`).
The writer accepts real ``eit_skin_msgs.msg.EitFrame`` objects as well as ``FrameRecord``.

Crash safety: :class:`McapFrameWriter` writes its messages in zstd chunks that it closes and
hands to the operating system at least every ``flush_period_s``, so a recording process
killed with SIGKILL (or a power cut after the page cache reached the disk) loses at most its
last ``flush_period_s`` of messages. Such a file has no summary and no footer;
:func:`read_mcap_frames` then reads it record by record, recovers every complete chunk and
reports what it skipped (:class:`McapDamage`) with byte offsets.
"""

from __future__ import annotations

import io
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from eit_skin.frames import FrameRecord
from eit_skin.io.cdr import (
    EIT_FRAME_SCHEMA,
    decode_eit_frame_cdr,
    eit_frame_msgdef,
    encode_eit_frame_cdr,
)

MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes that open (and close) every MCAP file."""
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
_OPCODE_NAMES = {
    0x01: "Header",
    0x02: "Footer",
    0x03: "Schema",
    0x04: "Channel",
    0x05: "Message",
    0x06: "Chunk",
    0x07: "MessageIndex",
    0x08: "ChunkIndex",
    0x09: "Attachment",
    0x0A: "AttachmentIndex",
    0x0B: "Statistics",
    0x0C: "Metadata",
    0x0D: "MetadataIndex",
    0x0E: "SummaryOffset",
    0x0F: "DataEnd",
}


class McapFrameWriter:
    """Write EitFrame messages to an MCAP file (ROS 2 profile, zstd chunks); thread-safe.

    Args:
        path: the file to create (replaced if it exists).
        chunk_bytes: a chunk is closed once it holds this many uncompressed bytes.
        flush_period_s: a chunk is closed and written to the file at the latest this long
            after its first message (by the next ``write`` or by a background thread), so
            SIGKILL loses at most this much of the recording; ``None``: only ``chunk_bytes``,
            ``flush()`` and ``close()`` write chunks.

    Use as a context manager or call ``close()``: only a closed file has its summary and
    footer (a reader without them has to scan the whole file, see :func:`read_mcap_frames`).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_bytes: int = 1 << 20,
        flush_period_s: float | None = 0.5,
    ) -> None:
        from mcap.writer import Writer

        if chunk_bytes <= 0:
            raise ValueError(f"chunk_bytes must be > 0, got {chunk_bytes}")
        if flush_period_s is not None and not flush_period_s > 0:
            raise ValueError(f"flush_period_s must be > 0 or None, got {flush_period_s}")
        self.path = Path(path)
        self.flush_period_s = flush_period_s
        self._lock = threading.Lock()
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=chunk_bytes)
        self._writer.start(profile="ros2", library="eit_skin")
        self._schema_id = self._writer.register_schema(
            name=EIT_FRAME_SCHEMA, encoding="ros2msg", data=eit_frame_msgdef().encode()
        )
        self._file.flush()  # the header is on disk at once: even an empty recording is MCAP
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self._pending_since: float | None = None  # monotonic s of the oldest unflushed message
        self.messages = 0
        """Messages written so far."""
        self.flushed_messages = 0
        """Messages handed to the operating system (they survive SIGKILL of this process)."""
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_period_s is not None:
            self._flusher = threading.Thread(
                target=self._flush_periodically, name=f"McapFrameWriter({self.path.name})"
            )
            self._flusher.daemon = True
            self._flusher.start()

    def write(self, topic: str, frame: FrameRecord | Any, log_time_ns: int | None = None) -> None:
        """Append one message; ``frame`` is a FrameRecord or an EitFrame message.

        ``log_time_ns`` is the recording time, ns since the epoch (default: the header stamp).
        """
        record = frame if isinstance(frame, FrameRecord) else FrameRecord.from_msg(frame)
        data = encode_eit_frame_cdr(record)
        log_time = record.stamp_ns if log_time_ns is None else int(log_time_ns)
        with self._lock:
            if self._file.closed:
                raise ValueError(f"{self.path}: write after close")
            channel = self._channels.get(topic)
            if channel is None:
                channel = self._writer.register_channel(
                    topic=topic, message_encoding="cdr", schema_id=self._schema_id
                )
                self._channels[topic] = channel
            self._writer.add_message(
                channel_id=channel,
                log_time=log_time,
                publish_time=log_time,
                sequence=self._sequence,
                data=data,
            )
            self._sequence += 1
            self.messages += 1
            now = time.monotonic()
            if self._pending_since is None:
                self._pending_since = now
            if self.flush_period_s is not None and now - self._pending_since >= self.flush_period_s:
                self._flush_locked()

    def flush(self) -> None:
        """Close the open chunk and hand everything written so far to the operating system."""
        with self._lock:
            if not self._file.closed:
                self._flush_locked()

    def _flush_locked(self) -> None:
        self._writer.flush()  # closes the chunk (if it holds messages) and flushes the file
        self._pending_since = None
        self.flushed_messages = self.messages

    def _flush_periodically(self) -> None:
        while not self._stop.wait(self.flush_period_s):
            with self._lock:
                if self._pending_since is not None and not self._file.closed:
                    self._flush_locked()

    def close(self) -> None:
        """Write the last chunk, the summary and the footer, and close the file."""
        self._stop.set()
        if self._flusher is not None and self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if not self._file.closed:
                self._writer.finish()
                self._file.close()
                self.flushed_messages = self.messages

    def __enter__(self) -> McapFrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class McapDamage:
    """What a reader skipped in an MCAP file that its writer did not finish.

    Attributes:
        path: the file.
        size: its length, bytes.
        end: byte offset where the last record that could be read ends.
        skipped: one line per skipped part, with its byte offsets.
    """

    path: str
    size: int
    end: int
    skipped: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.path}: unfinished MCAP file ({self.size} bytes): " + "; ".join(self.skipped)


def read_mcap_frames(
    path: str | Path,
    topics: list[str] | None = None,
    on_damage: Callable[[McapDamage], None] | None = None,
) -> Iterator[tuple[str, int, FrameRecord]]:
    """Yield (topic, log_time_ns, FrameRecord) for every EitFrame message.

    A finished file is read through its index, in log-time order. A file without summary
    or footer (its writer was killed, or the file was cut) is read record by record in file
    order: every complete chunk is recovered, and after the last message the damage is
    passed to ``on_damage``; without ``on_damage`` it raises ValueError naming the file and
    the byte offsets skipped. Channels with another schema are skipped.

    Raises:
        ValueError: not an MCAP file; a message does not decode (names the file, topic and
            log time); or unrecovered damage (see above).
    """
    with open(path, "rb") as stream:
        size = stream.seek(0, io.SEEK_END)
        stream.seek(0)
        if _finished(stream, size):
            stream.seek(0)
            messages = _indexed_messages(path, stream, topics)
        else:
            stream.seek(0)
            messages = _scanned_messages(path, stream, size, topics, on_damage)
        for schema_name, encoding, topic, log_time, data in messages:
            if schema_name != EIT_FRAME_SCHEMA or encoding != "cdr":
                continue
            try:
                record = decode_eit_frame_cdr(data)
            except (ValueError, struct.error, UnicodeDecodeError) as error:
                raise ValueError(
                    f"{path}: topic {topic}, log_time {log_time}: undecodable EitFrame ({error})"
                ) from error
            yield topic, log_time, record


_Message = tuple[str | None, str, str, int, bytes]  # schema name, encoding, topic, log time, data


def _finished(stream: BinaryIO, size: int) -> bool:
    """Whether the file ends with the magic and a readable summary."""
    from mcap.reader import make_reader

    if size < 2 * len(MCAP_MAGIC):
        return False
    stream.seek(size - len(MCAP_MAGIC))
    if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        return False
    stream.seek(0)
    try:
        return make_reader(stream).get_summary() is not None
    except Exception:  # a damaged summary: any parse error means "scan the file instead"
        return False


def _indexed_messages(
    path: str | Path, stream: BinaryIO, topics: list[str] | None
) -> Iterator[_Message]:
    from mcap.reader import make_reader

    reader = make_reader(stream)
    try:
        for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            name = None if schema is None else schema.name
            yield name, channel.message_encoding, channel.topic, message.log_time, message.data
    except Exception as error:  # corrupt data behind an intact index: CRC, zstd, parse errors
        raise ValueError(
            f"{path}: unreadable MCAP data ({type(error).__name__}: {error})"
        ) from error


def _scanned_messages(
    path: str | Path,
    stream: BinaryIO,
    size: int,
    topics: list[str] | None,
    on_damage: Callable[[McapDamage], None] | None,
) -> Iterator[_Message]:
    """Messages of every complete record, in file order; then report what was skipped."""
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import breakup_chunk

    skipped: list[str] = []
    schemas: dict[int, str] = {}
    channels: dict[int, Any] = {}
    orphans: dict[int, int] = {}  # channel id -> messages whose Channel record was lost
    footer = False
    magic = stream.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        if not MCAP_MAGIC.startswith(magic):
            raise ValueError(f"{path}: not an MCAP file (starts with {magic.hex(' ')})")
        skipped.append("empty file" if not magic else f"bytes 0..{size}: cut inside the magic")
    pos = len(magic)
    while magic == MCAP_MAGIC and not footer:
        head = stream.read(_RECORD_HEAD.size)
        if not head:
            skipped.append(f"no summary or footer after byte {pos} (the writer did not finish)")
            break
        if len(head) < _RECORD_HEAD.size:
            skipped.append(f"bytes {pos}..{size}: cut inside a record header")
            break
        opcode, length = _RECORD_HEAD.unpack(head)
        kind = _OPCODE_NAMES.get(opcode, f"opcode 0x{opcode:02x}")
        body_start = pos + _RECORD_HEAD.size
        if length > size - body_start:
            skipped.append(
                f"bytes {pos}..{size}: {kind} record cut short "
                f"({size - body_start} of {length} bytes)"
            )
            break
        body = stream.read(length)
        end = body_start + length
        try:
            if opcode == 0x06:
                records = breakup_chunk(Chunk.read(_data_stream(body)), validate_crc=True)
            elif opcode in (0x03, 0x04):
                records = [(Schema if opcode == 0x03 else Channel).read(_data_stream(body))]
            elif opcode == 0x05:
                records = [Message.read(_data_stream(body), length)]
            else:
                records = []
        except Exception as error:  # a complete but corrupt record: CRC, zstd, field parse
            skipped.append(f"bytes {pos}..{end}: unreadable {kind} record ({error})")
            records = []
        for item in records:
            if isinstance(item, Schema):
                schemas[item.id] = item.name
            elif isinstance(item, Channel):
                channels[item.id] = item
            elif isinstance(item, Message):
                channel = channels.get(item.channel_id)
                if channel is None:
                    orphans[item.channel_id] = orphans.get(item.channel_id, 0) + 1
                elif topics is None or channel.topic in topics:
                    schema = schemas.get(channel.schema_id)
                    yield schema, channel.message_encoding, channel.topic, item.log_time, item.data
        footer = opcode == 0x02  # the last record (only the closing magic follows)
        pos = end
    if footer and stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        skipped.append(f"bytes {pos}..{size}: closing magic cut or wrong")
    for channel_id, count in orphans.items():
        skipped.append(f"{count} messages of channel {channel_id}, whose Channel record was lost")
    if skipped:
        damage = McapDamage(str(path), size, pos, tuple(skipped))
        if on_damage is None:
            raise ValueError(str(damage))
        on_damage(damage)


def _data_stream(body: bytes) -> Any:
    from mcap.data_stream import ReadDataStream

    return ReadDataStream(io.BytesIO(body))
