"""EitFrame recordings in MCAP with the ROS 2 profile (what ``ros2 bag`` and Foxglove read).

One channel per topic, message encoding ``cdr``, schema ``eit_skin_msgs/msg/EitFrame`` with
encoding ``ros2msg`` and the rosbag2-style concatenated definition (:mod:`eit_skin.io.cdr`).
The writer accepts real ``eit_skin_msgs.msg.EitFrame`` objects as well as ``FrameRecord``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from eit_skin.frames import FrameRecord
from eit_skin.io.cdr import (
    EIT_FRAME_SCHEMA,
    decode_eit_frame_cdr,
    eit_frame_msgdef,
    encode_eit_frame_cdr,
)


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
