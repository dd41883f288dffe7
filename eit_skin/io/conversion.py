"""Conversion between MCAP recordings and the offline npz frames format (``eit-skin frames``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.frames import FLAG_INVALID, FrameRecord, flagged_as_nan
from eit_skin.io.mcap import McapDamage, McapFrameWriter, read_mcap_frames
from eit_skin.io.npz import DEFAULT_BLOCK_FRAMES, NpzStreamWriter, load_frames_npz


def mcap_to_npz(
    mcap_path: str | Path,
    npz_path: str | Path,
    topic: str | None = None,
    reference_frames: int = 1,
    on_damage: Callable[[McapDamage], None] | None = None,
    block_frames: int = DEFAULT_BLOCK_FRAMES,
) -> int:
    """Export one topic's frames to the npz format, ``block_frames`` at a time; returns T.

    ``frames`` are the voltages (float32 -> float64, NaN where a flag keeps the channel out of
    imaging: saturated or invalid, as the reconstruction pipeline treats it), ``t`` the header
    stamps in seconds since the epoch, ``reference`` the NaN-ignoring mean of the first
    ``reference_frames`` frames (a channel flagged in all of them - e.g. stuck at the rail -
    gets the mean of its flagged values there: a finite placeholder, never imaged since the
    channel is NaN in those frames). With ``topic=None`` the file must hold exactly one
    EitFrame topic. An unfinished MCAP file (its recorder was killed) raises ValueError unless
    ``on_damage`` is given: then its complete records are exported and ``on_damage`` receives
    what was skipped (see :func:`~eit_skin.io.mcap.read_mcap_frames`).
    """
    damage: list[McapDamage] = []

    def note(found: McapDamage) -> None:
        damage.append(found)
        if on_damage is not None:
            on_damage(found)

    head_size = max(1, reference_frames)
    raw_head, head, seen = [], [], set()
    rows, stamps = [], []
    n_frames, m = 0, None
    topics = [topic] if topic else None
    messages = read_mcap_frames(mcap_path, topics, None if on_damage is None else note)
    npz_path = Path(npz_path)
    # frames and t go to disk every block_frames rows: memory does not grow with the recording
    writer = NpzStreamWriter(
        npz_path,
        {
            "reference": ((None,), np.float64),
            "frames": ((None, None), np.float64),
            "t": ((None,), np.float64),
        },
    )
    with writer:
        for name, _, record in messages:
            seen.add(name)
            if len(seen) > 1:
                raise ValueError(
                    f"{mcap_path}: several EitFrame topics {sorted(seen)}; pass topic="
                )
            if len(raw_head) < head_size:
                raw_head.append(record.voltages.astype(np.float64))
            volts = flagged_as_nan(record.voltages, record.channel_flags)
            if m is not None and volts.size != m:
                raise ValueError(f"{mcap_path}: topic {name} changes M from {m}")
            m = volts.size
            if len(head) < head_size:
                head.append(volts)
            rows.append(volts)
            stamps.append(record.stamp_ns)
            n_frames += 1
            if len(rows) == block_frames:
                writer.append(frames=np.stack(rows), t=np.asarray(stamps, dtype=np.int64) / 1e9)
                rows, stamps = [], []
        if not n_frames:
            raise ValueError(
                f"{mcap_path}: no EitFrame messages"
                + (f" on {topic}" if topic else "")
                + "".join(f" ({found})" for found in damage)
            )
        if rows:
            writer.append(frames=np.stack(rows), t=np.asarray(stamps, dtype=np.int64) / 1e9)
        reference = _reference(mcap_path, np.stack(head), np.stack(raw_head))
        writer.append(reference=reference)
    return n_frames


def _reference(mcap_path: str | Path, head: np.ndarray, raw_head: np.ndarray) -> np.ndarray:
    """``[M]`` NaN-ignoring mean of the first frames ``head`` ``[n, M]`` (flagged as NaN).

    A channel flagged in all of them takes the mean of its flagged values ``raw_head``.
    """
    reference = np.full(head.shape[1], np.nan)
    for values in (head, raw_head):  # flagged values only where nothing else
        missing = ~np.isfinite(reference) & ~np.isnan(values).all(axis=0)
        reference[missing] = np.nanmean(values[:, missing], axis=0)
    if not np.isfinite(reference).all():
        raise ValueError(
            f"{mcap_path}: channel {int(np.flatnonzero(~np.isfinite(reference))[0])} is "
            f"invalid in all of the first {len(head)} frames, so there is no reference; "
            "raise reference_frames"
        )
    return reference


@dataclass(frozen=True)
class FrameStream:
    """What a layer's frames are published as: the topic and the EitFrame header fields.

    Attributes:
        topic: the frames topic.
        patch, layer: names from the patch config.
        n_electrodes: electrodes on the layer.
        drive_pattern: protocol name (adjacent, opposite, skip-k, explicit).
        current_a: injected current, amperes.
        frame_id: header.frame_id.
    """

    topic: str
    patch: str
    layer: str
    n_electrodes: int
    drive_pattern: str = "adjacent"
    current_a: float = 1e-3
    frame_id: str = ""


def npz_to_mcap(
    npz_path: str | Path,
    mcap_path: str | Path,
    stream: FrameStream,
    *,
    rate_hz: float = 50.0,
    start_ns: int = 0,
) -> int:
    """Write an npz file's frames as EitFrame messages of ``stream``; returns T.

    Stamps come from ``t`` (seconds since the epoch) or, without it, ``start_ns`` + i /
    ``rate_hz``. NaN values are written as NaN with FLAG_INVALID. The reference is not stored
    (MCAP holds raw frames only).
    """
    _, frames, t = load_frames_npz(npz_path)
    if t is not None:
        stamps = np.round(t * 1e9).astype(np.int64)
    else:
        stamps = start_ns + np.round(np.arange(frames.shape[0]) * (1e9 / rate_hz)).astype(np.int64)
    flags = np.where(np.isnan(frames), FLAG_INVALID, 0).astype(np.uint8)
    with McapFrameWriter(mcap_path) as writer:
        for i in range(frames.shape[0]):
            writer.write(
                stream.topic,
                FrameRecord.of_stream(stream, int(stamps[i]), i % 2**32, frames[i], flags[i]),
            )
    return int(frames.shape[0])
