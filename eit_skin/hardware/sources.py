"""Where raw frames come from: a serial board, the physics simulator, or a recording.

Every source turns its input into :class:`~eit_skin.frames.FrameRecord` objects (the
ROS-free fields of an ``EitFrame``) stamped with the acquisition time in host nanoseconds,
and keeps counters for diagnostics. The driver node only publishes what they return.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.frames import FrameRecord, is_frames_topic
from eit_skin.hardware.boards import (
    BoardReader,
    OpenEITReader,
    WireReader,
    lines_reader,
)
from eit_skin.hardware.cn0565 import Cn0565Source
from eit_skin.hardware.device_clock import DeviceClock
from eit_skin.hardware.sciospec import SciospecReader
from eit_skin.hardware.serial_link import LinkState, ReceivedFrame, SerialLink
from eit_skin.hardware.source_status import RateMeter, SourceStatus
from eit_skin.hardware.wire import DeviceFrame, PatternId
from eit_skin.io.mcap import McapDamage, read_mcap_frames
from eit_skin.patch.device import DeviceSpec
from eit_skin.patch.model import Layer, Patch
from eit_skin.patch.protocol import Protocol, build_protocol

FrameSink = Callable[[FrameRecord], None]


def pattern_name(layer: Layer) -> str:
    """The drive pattern name carried in ``EitFrame.drive_pattern`` (e.g. ``skip-2``)."""
    spec = layer.protocol
    return f"skip-{spec.drive_skip}" if spec.drive == "skip" else spec.drive


_PATTERN_IDS = {
    "adjacent": PatternId.ADJACENT,
    "opposite": PatternId.OPPOSITE,
    "skip": PatternId.SKIP,
    "explicit": PatternId.EXPLICIT,
    # multi-electrode current patterns have no source -> sink offset: the wire calls them
    # explicit (the patch's protocol says which)
    "trigonometric": PatternId.EXPLICIT,
    "currents": PatternId.EXPLICIT,
}


def pattern_id(layer: Layer) -> PatternId:
    """The wire protocol's pattern id of a layer's drive pattern."""
    return _PATTERN_IDS[layer.protocol.drive]


def drive_offset(pattern: PatternId, param: int, n_electrodes: int) -> int | None:
    """Electrodes from source to sink of a drive pattern (``None``: explicit pairs).

    Adjacent is 1, opposite ``n // 2``, skip-k ``k + 1``: two patterns with the same offset
    drive the same pairs (skip-0 is adjacent).
    """
    if pattern is PatternId.EXPLICIT:
        return None
    return {PatternId.ADJACENT: 1, PatternId.OPPOSITE: n_electrodes // 2}.get(pattern, param + 1)


REJECT_REASONS = ("values", "electrodes", "pattern", "current")
"""Why a serial frame is not published (checked in this order, the first one counts):
value count != the layer's device frame size (``M``, or ``n_inj x n`` for ``layout: full``),
electrode count != the layer's, a drive pattern other than the
layer's, current <= 0."""


class LayerFrameFactory:
    """Builds FrameRecords of one layer: names, electrode count, pattern, expected M."""

    def __init__(self, patch: Patch, layer: Layer, frame_id: str) -> None:
        self.patch = patch
        self.layer = layer
        self.frame_id = frame_id
        self.protocol: Protocol = build_protocol(layer.protocol, layer.n_electrodes)
        self.pattern = pattern_name(layer)
        self.drive_offset = drive_offset(
            pattern_id(layer), layer.protocol.drive_skip, layer.n_electrodes
        )

    @property
    def n_measurements(self) -> int:
        return self.protocol.n_measurements

    def reject(self, frame: DeviceFrame) -> tuple[str, str] | None:
        """Why ``frame`` does not belong to this layer: (a REJECT_REASONS entry, one line).

        ``None`` for a frame to publish. The wire protocol carries the drive pattern so the
        host can check it (docs/wire-protocol.md); the measurement order is the layer's.
        """
        layer, n = self.layer, self.layer.n_electrodes
        where = f"frame {frame.sequence}"
        if frame.n_values != self.protocol.frame_size:
            layout = layer.protocol.layout
            return "values", (
                f"{where}: {frame.n_values} values, layer {layer.name!r} expects "
                f"{self.protocol.frame_size} ({layout} layout)"
            )
        if frame.n_electrodes != n:
            return "electrodes", (
                f"{where}: {frame.n_electrodes} electrodes, layer {layer.name!r} has {n}"
            )
        if drive_offset(frame.pattern_id, frame.pattern_param, n) != self.drive_offset:
            return "pattern", (
                f"{where}: drive pattern {frame.pattern_id.name.lower()} (param "
                f"{frame.pattern_param}), layer {layer.name!r} drives {self.pattern}"
            )
        if not frame.current_a > 0.0:
            return "current", f"{where}: current {frame.current_a:g} A, must be > 0"
        return None

    def device_record(
        self,
        stamp_ns: int,
        sequence: int,
        voltages_v: np.ndarray,
        flags: np.ndarray | None = None,
        current_a: float | None = None,
    ) -> FrameRecord:
        """:meth:`record` of a board's frame: its layout's used entries (and flags) picked."""
        values = self.protocol.select(voltages_v, f"frame {sequence}")
        if flags is not None and np.size(flags) == self.protocol.frame_size:
            flags = self.protocol.select(flags, f"frame {sequence} flags").astype(np.uint8)
        return self.record(stamp_ns, sequence, values, flags, current_a)

    def record(
        self,
        stamp_ns: int,
        sequence: int,
        voltages_v: np.ndarray,
        flags: np.ndarray | None = None,
        current_a: float | None = None,
    ) -> FrameRecord:
        return FrameRecord(
            stamp_ns=stamp_ns,
            frame_id=self.frame_id,
            patch=self.patch.name,
            layer=self.layer.name,
            n_electrodes=self.layer.n_electrodes,
            drive_pattern=self.pattern,
            current_a=self.layer.current_a if current_a is None else current_a,
            sequence=sequence % 2**32,
            voltages=voltages_v,
            channel_flags=np.zeros(0, np.uint8) if flags is None else flags,
        )


def board_reader(
    protocol: Protocol,
    device: DeviceSpec,
    layer: str,
    current_a: float,
    check: Callable[[DeviceFrame], tuple[str, str] | None],
) -> BoardReader:
    """The reader of a layer's board profile (``cn0565`` has no byte stream: not here).

    ``current_a`` is the layer's current (the Sciospec setup's amplitude); ``check`` the
    layer's test of a wire-protocol frame (:class:`WireReader`).
    """
    if device.profile == "eit_skin":
        return WireReader(protocol, device, layer, check)
    if device.profile == "openeit":
        return OpenEITReader(protocol, device, layer)
    if device.profile == "lines":
        return lines_reader(protocol, device, layer)
    if device.profile == "sciospec":
        return SciospecReader(protocol, device, layer, current_a)
    raise ValueError(f"board profile {device.profile!r} is not read from a serial port")


class SerialSource:
    """One board on a serial port, serving one layer, in the layer's board profile.

    The layer's ``device`` section picks the reader (:func:`board_reader`: eit_skin's wire
    protocol, OpenEIT, a line-printing board, Sciospec); the
    link writes the host commands the reader asks for (on every connect, again when the
    board does not answer) and its farewell on :meth:`stop`. Frames are delivered from the
    link's reader thread to ``sink`` as soon as their last byte is parsed (lowest latency);
    a frame the reader refuses, or that does not belong to the layer (value count,
    electrode count, drive pattern, or a current <= 0: :meth:`LayerFrameFactory.reject`), is
    counted per reason and dropped, never published. Stamps: the board's clock mapped to
    host time where the board sends one (wire protocol, Sciospec), else the host time the
    frame's last byte was read; always increasing (a frame read in the same chunk as the
    one before is stamped 1 us after it).

    Args:
        baud: serial rate, bit/s; 0: the profile's (``device.baud``).
        clock: maps the board's clock to host time (default: a new :class:`DeviceClock`).
    """

    #: Reconnect backoff of the link, s: the first wait and the longest.
    BACKOFF_S = (0.05, 2.0)

    def __init__(
        self,
        factory: LayerFrameFactory,
        port: str,
        baud: int,
        sink: FrameSink,
        clock: DeviceClock | None = None,
    ) -> None:
        layer = factory.layer
        self.factory = factory
        self.sink = sink
        self.clock = clock or DeviceClock()
        self.reader = board_reader(
            factory.protocol, layer.device, layer.name, layer.current_a, factory.reject
        )
        self.profile = layer.device.profile
        self.link = SerialLink(
            port,
            baud or layer.device.baud,
            parser=self.reader,
            backoff_initial_s=self.BACKOFF_S[0],
            backoff_max_s=self.BACKOFF_S[1],
        )
        self.rate = RateMeter()
        self.published = 0
        self._host_sequence = 0
        self._last_stamp = 0
        self._reported = (0, 0)  # (published, refused) at the last status()
        self._lock = threading.Lock()

    @property
    def rejected(self) -> dict[str, int]:
        """Frames refused so far, per reason (the reader's reasons)."""
        return dict(self.reader.stats.refused)

    def start(self) -> None:
        self.link.start(self._on_frames)

    def stop(self) -> None:
        self.link.stop()

    def _on_frames(self, received: list[ReceivedFrame]) -> None:
        timed = [item for item in received if item.frame.device_time_us is not None]
        board_stamps = iter(
            self.clock.update_batch(
                [item.frame.device_time_us for item in timed],
                [item.host_time_ns for item in timed],
            )
        )
        for item in received:
            frame = item.frame
            sequence = frame.sequence
            if sequence is None:
                sequence = self._host_sequence
            self._host_sequence = sequence + 1
            # frames read in one chunk share its host time: each later one 1 us after the
            # one before, so stamps stay unique and increasing
            acquired = item.host_time_ns if frame.device_time_us is None else next(board_stamps)
            stamp = max(acquired, self._last_stamp + 1000)
            self._last_stamp = stamp
            record = self.factory.device_record(
                stamp,
                sequence,
                frame.values,
                frame.flags,
                frame.current_a,
            )
            self.sink(record)
            with self._lock:
                self.published += 1
                self.rate.tick()

    def status(self) -> SourceStatus:
        link = self.link.status()
        stats = link.parser
        with self._lock:
            rate = self.rate.rate_hz()
            refused = sum(stats.refused.values())
            new_frames = self.published - self._reported[0]
            new_refusals = refused - self._reported[1]
            self._reported = (self.published, refused)
            published = self.published
        values = {
            "source": "serial",
            "profile": self.profile,
            "port": link.port,
            "baud": str(self.link.baud),
            "state": link.state.value,
            "frame_rate_hz": f"{rate:.1f}",
            "frames_published": str(published),
            "frames_rejected": str(refused),
            **{f"rejected_{reason}": str(n) for reason, n in stats.refused.items()},
            "discarded_bytes": str(stats.discarded_bytes),
            "board_messages": str(stats.messages),
            "board_restarts": str(stats.restarts),
            "bytes_sent": str(link.bytes_sent),
            "reconnects": str(link.reconnects),
            "failed_attempts": str(link.failed_attempts),
            "clock_drift_ppm": f"{self.clock.drift_ppm:.1f}",
            "last_error": link.last_error,
        }
        wire = getattr(self.reader, "parser", None)
        if wire is not None:  # the wire protocol's framing counters
            values.update(
                crc_errors=str(wire.stats.crc_errors),
                truncated=str(wire.stats.truncated),
                resyncs=str(wire.stats.resyncs),
            )
        where = f"{link.port} ({self.profile})"
        if link.state is LinkState.DISCONNECTED:
            return SourceStatus(
                2, f"device {where} not connected: {link.last_error or 'opening'}", values
            )
        silent = self.reader.unanswered(self.link.clock())
        if silent:
            return SourceStatus(2, f"device {where}: {silent}", values)
        if new_refusals:
            return SourceStatus(1, f"frames rejected: {self.reader.last_refusal}", values)
        if not new_frames:
            return SourceStatus(1, f"connected to {where}, no frames since last report", values)
        return SourceStatus(0, f"{rate:.1f} frames/s from {where}", values)


def board_source(
    factory: LayerFrameFactory, port: str, baud: int, sink: FrameSink
) -> SerialSource | Cn0565Source:
    """The source of a layer's board on ``port``, by the layer's board profile.

    A serial byte stream (:class:`SerialSource`), or a CN0565 asked for every frame through
    pyadi-iio (:class:`~eit_skin.hardware.cn0565.Cn0565Source`).
    """
    if factory.layer.device.profile == "cn0565":
        return Cn0565Source(factory, port, sink)
    return SerialSource(factory, port, baud, sink)


BOARD_SOURCES = (SerialSource, Cn0565Source)
"""The sources that read a board (they have ``stop``), as opposed to the simulator and replay."""


class SimulatedSource:
    """Frames of every simulated layer, produced on the caller's timer.

    ``simulator`` is a :class:`eit_skin.sim.simulator.SkinSimulator`; frame ``k`` of the
    script is published at tick ``k``; with ``loop`` the script restarts after its end,
    otherwise the skin stays untouched (no-load frames) after one pass.
    """

    def __init__(
        self,
        factories: dict[str, LayerFrameFactory],
        simulator: Any,  # SkinSimulator, imported lazily by the caller
        n_script_frames: int,
        loop: bool,
    ) -> None:
        self.factories = factories
        self.simulator = simulator
        self.n_script_frames = max(1, n_script_frames)
        self.loop = loop
        self.index = 0
        self.rate = RateMeter()
        self.published = 0

    @property
    def script_done(self) -> bool:
        """True once one pass of the touch script has been published."""
        return self.index >= self.n_script_frames

    def posture_angle(self) -> float | None:
        """Simulated joint angle of the last published frame, rad (None: no joint)."""
        posture = self.simulator.scenario.posture
        if posture is None or self.index == 0:
            return None
        k = (self.index - 1) % self.n_script_frames if self.loop else self.index - 1
        return float(posture.angle(k / self.simulator.rate_hz))

    def tick(self, now_ns: int, sink: FrameSink) -> None:
        k = self.index % self.n_script_frames if self.loop else self.index
        frames = self.simulator.frame(k)
        for name, factory in self.factories.items():
            sim = frames[name]
            sink(factory.record(now_ns, self.index, sim.voltages_v, sim.flags))
        self.index += 1
        self.published += 1
        self.rate.tick()

    def status(self) -> SourceStatus:
        rate = self.rate.rate_hz()
        values = {
            "source": "simulator",
            "frame_rate_hz": f"{rate:.1f}",
            "frames_published": str(self.published),
            "script_frame": str(self.index % self.n_script_frames),
            "script_frames": str(self.n_script_frames),
        }
        level = 0 if self.published else 1
        return SourceStatus(level, f"simulating {rate:.1f} frames/s", values)


class ReplaySource:
    """Frames of an MCAP recording, with their original spacing or as fast as possible.

    Only topics of the replayed patch's layers are used (``/<ns>/<layer>/frames`` or any
    topic ending in ``/<layer>/frames``); the original header stamps are kept. An unfinished
    recording (its recorder was killed) is replayed up to its last complete chunk and the
    status then reports what was skipped.
    """

    def __init__(self, path: str | Path, layers: list[str], realtime: bool = True) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"replay_path {self.path}: no such file")
        self.layers = set(layers)
        self.realtime = realtime
        self._pending: tuple[int, FrameRecord] | None = None
        self._t0: tuple[int, int] | None = None  # (first log time, host time at start)
        self.published = 0
        self.finished = False
        self.rate = RateMeter()
        self.damage: McapDamage | None = None
        self._iter: Iterator[tuple[int, FrameRecord]] = self._records()

    def _records(self) -> Iterator[tuple[int, FrameRecord]]:
        def note(damage: McapDamage) -> None:
            self.damage = damage

        for topic, log_ns, record in read_mcap_frames(self.path, on_damage=note):
            if record.layer in self.layers and is_frames_topic(topic, record.layer):
                yield log_ns, record

    def tick(self, now_ns: int, sink: FrameSink, max_frames: int = 1000) -> None:
        """Publish every frame that is due (realtime) or up to ``max_frames`` (fast)."""
        for _ in range(max_frames):
            if self._pending is None:
                nxt = next(self._iter, None)
                if nxt is None:
                    self.finished = True
                    return
                self._pending = nxt
            log_ns, record = self._pending
            if self._t0 is None:
                self._t0 = (log_ns, now_ns)
            if self.realtime and log_ns - self._t0[0] > now_ns - self._t0[1]:
                return
            sink(record)
            self._pending = None
            self.published += 1
            self.rate.tick()

    def status(self) -> SourceStatus:
        values = {
            "source": "replay",
            "file": str(self.path),
            "frames_published": str(self.published),
            "finished": str(self.finished).lower(),
            "frame_rate_hz": f"{self.rate.rate_hz():.1f}",
        }
        if self.damage is not None:
            values["skipped"] = "; ".join(self.damage.skipped)
            return SourceStatus(1, f"replay of an unfinished recording: {self.damage}", values)
        if self.finished:
            return SourceStatus(0, f"replay of {self.path.name} finished", values)
        return SourceStatus(0, f"replaying {self.path.name}", values)
