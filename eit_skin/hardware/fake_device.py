"""An emulated skin board: speaks the wire protocol on a pseudo-terminal.

``PtyBoard`` is the pty half every emulated board shares (plug, unplug, symlink, write
queue, host bytes, a paced sending thread); ``FakeDevice`` speaks eit_skin's wire protocol
on it, the boards of ``board_emulators`` speak theirs.

``FakeDevice(frame_source, rate_hz)`` opens a pty, optionally puts a symlink (like the udev
``/dev/eit_skin_*`` link) at a path of choice, and writes one encoded frame per period.
``frame_source(i)`` returns frame i's voltages, volts [M]; any callable works (a looped npz
recording, the physics simulator). ``unplug()`` closes the pty like a pulled USB cable; a
later ``open()`` (+ ``link``) plugs in a fresh one.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.hardware.wire import DeviceFrame, PatternId, ValueEncoding, encode_frame

FrameSource = Callable[[int], np.ndarray]
"""frame index -> voltages, volts, float [M]."""

DEFAULT_VOLTS_PER_COUNT = 3.3 / 4096 / 1000
"""A 3.3 V 12-bit ADC summed over 1000 oversamples: volts per summed count."""


def npz_frame_source(path: str | Path) -> tuple[FrameSource, int]:
    """Loop the ``frames`` [T, M] volts of an offline npz file; returns (source, M)."""
    from eit_skin.io.npz import load_frames_npz

    _, frames, _ = load_frames_npz(path)
    return (lambda i: frames[i % frames.shape[0]]), int(frames.shape[1])


class PtyBoard:
    """A board on a pseudo-terminal: plug, unplug, a symlink, a write queue, host bytes.

    The shared half of every emulated board. A subclass says what one frame is
    (:meth:`emit_frame`), whether it is streaming (:attr:`streaming`) and what it does with
    the bytes the host writes (:meth:`on_host_bytes`); :meth:`run` paces the frames at
    ``rate_hz`` and hands host bytes over between frames.

    Args:
        rate_hz: frames per second.
        max_pending_bytes: bytes queued while nobody reads before frames are dropped.
    """

    def __init__(self, rate_hz: float, *, max_pending_bytes: int = 1 << 20) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.max_pending_bytes = max_pending_bytes
        self.frames_sent = 0
        self.frames_dropped = 0
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_path = ""
        self._link: Path | None = None
        self._pending = bytearray()
        self._cut: int | None = None
        self._t0_ns = time.monotonic_ns()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()

    @property
    def pending_bytes(self) -> int:
        """Bytes queued for the pty that the reader has not made room for yet."""
        with self._lock:
            return len(self._pending)

    @property
    def slave_path(self) -> str:
        """Path a serial reader opens (``/dev/pts/N``), '' while unplugged."""
        return self._slave_path

    @property
    def streaming(self) -> bool:
        """True while :meth:`run` should emit frames (a board waiting for a start: False)."""
        return True

    def open(self) -> str:
        """Plug in: create a raw pty and return its slave path."""
        with self._lock:
            if self._master is not None:
                return self._slave_path
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no CR/LF translation: a binary line from the start
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self._slave_path = os.ttyname(slave)
            self._pending.clear()
        if self._link is not None:
            self.link(self._link)
        self.on_power_up()
        return self._slave_path

    def on_power_up(self) -> None:
        """Called by :meth:`open` once the pty exists (a boot banner goes here)."""

    def link(self, path: str | Path) -> None:
        """Point a symlink at ``path`` to the slave (replacing an existing symlink only)."""
        path = Path(path)
        if path.exists() and not path.is_symlink():
            raise FileExistsError(f"{path} exists and is not a symlink; not replacing it")
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(self._slave_path)
        tmp.replace(path)
        self._link = path

    def unplug(self) -> None:
        """Close the pty (readers get an I/O error) and remove the symlink."""
        with self._lock:
            if self._link is not None:
                with contextlib.suppress(FileNotFoundError):
                    self._link.unlink()
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            self._slave_path = ""
            self._pending.clear()

    def write_frame(self, data: bytes) -> bool:
        """Queue and write one frame's bytes; False if unplugged or dropped (nobody reading)."""
        with self._lock:
            if self._master is None:
                return False
            if len(self._pending) > self.max_pending_bytes:
                self.frames_dropped += 1
                self._flush()
                return False
            if self._cut is not None:
                data, self._cut = data[: self._cut], None
            self._pending += data
            self.frames_sent += 1
            self._flush()
            return True

    def write_raw(self, data: bytes) -> bool:
        """Queue and write bytes that are not a frame (banners, acknowledgements, garbage)."""
        with self._lock:
            if self._master is None:
                return False
            self._pending += data
            self._flush()
            return True

    def _flush(self) -> None:
        try:
            while self._pending:
                written = os.write(self._master, self._pending)  # type: ignore[arg-type]
                del self._pending[:written]
        except BlockingIOError:
            pass

    def read_host(self) -> bytes:
        """Bytes the host has written since the last call (b'' when none or unplugged)."""
        with self._lock:
            if self._master is None:
                return b""
            chunks = []
            try:
                while chunk := os.read(self._master, 65536):
                    chunks.append(chunk)
            except (BlockingIOError, OSError):  # nothing more / the host side is closed
                pass
        return b"".join(chunks)

    def on_host_bytes(self, data: bytes) -> None:
        """Bytes from the host (maybe none), handed over by :meth:`run` between frames.

        Called at least every 50 ms while running (timeouts go here); default: ignore them.
        """

    def emit_frame(self, index: int, device_time_us: int) -> None:
        """Write frame ``index`` (``device_time_us``: its scheduled time on the board clock)."""
        raise NotImplementedError

    def board_time_us(self) -> int:
        """Now on the clock :meth:`run` stamps frames with, microseconds."""
        return (time.monotonic_ns() - self._t0_ns) // 1000

    def cut_next_frame(self, n_bytes: int) -> None:
        """Write only the first ``n_bytes`` of the next frame (a frame cut short)."""
        self._cut = int(n_bytes)

    def run(self, count: int | None = None, stop: threading.Event | None = None) -> int:
        """Emit frames 0, 1, ... at ``rate_hz`` until ``count`` or ``stop``; return the count.

        Frames go out only while :attr:`streaming`; host bytes reach :meth:`on_host_bytes`
        between frames.
        """
        stop = stop or self._stop
        next_ns = time.monotonic_ns()
        index = 0
        while (count is None or index < count) and not stop.is_set():
            self.on_host_bytes(self.read_host())
            now = time.monotonic_ns()
            if not self.streaming:
                next_ns = now  # the schedule starts when streaming does
            elif now >= next_ns:
                # stamped with the scheduled acquisition time, like a timer-driven firmware
                self.emit_frame(index, (next_ns - self._t0_ns) // 1000)
                index += 1
                next_ns += round(1e9 / self.rate_hz)
                now = time.monotonic_ns()
                if next_ns < now - 1_000_000_000:  # more than 1 s behind: drop the backlog
                    next_ns = now
            self._wait(stop, max(0, next_ns - now) / 1e9 if self.streaming else 0.05)
        self._drain(stop)
        return index

    def _wait(self, stop: threading.Event, timeout_s: float) -> None:
        """Sleep up to ``timeout_s``; wake early when the host writes or ``stop`` is set."""
        with self._lock:
            master = self._master
        if master is None:
            stop.wait(timeout_s)
            return
        try:
            select.select([master], [], [], min(timeout_s, 0.05))
        except (OSError, ValueError):  # unplugged meanwhile
            stop.wait(min(timeout_s, 0.05))

    def _drain(self, stop: threading.Event) -> None:
        """Write what is still queued as the reader makes room, until ``stop`` or unplug.

        A finite run ends with its last frames queued when the reader lags (the pty holds a
        few kB): without this they were never written (a loaded test read 23 of 40 frames).
        """
        while not stop.is_set():
            with self._lock:
                if self._master is None:
                    return
                self._flush()
                if not self._pending:
                    return
                master = self._master
            try:
                select.select([], [master], [], 0.05)
            except (OSError, ValueError):  # unplugged meanwhile
                return

    def start(self, count: int | None = None) -> None:
        """Run ``run(count)`` on a daemon thread; an error there is raised by :meth:`stop`."""
        self._stop.clear()
        self._error = None
        self._thread = threading.Thread(target=self._run_keeping_error, args=(count,), daemon=True)
        self._thread.start()

    def _run_keeping_error(self, count: int | None) -> None:
        try:
            self.run(count)
        except BaseException as error:  # kept for stop(): a dead board must not look idle
            self._error = error

    @property
    def failed(self) -> BaseException | None:
        """The error that ended the thread started by ``start`` (None while it is fine)."""
        return self._error

    def stop(self) -> None:
        """Stop the thread started by ``start``; raise what ended it early, if anything.

        Raises:
            RuntimeError: the frame source or the pty failed (the cause is chained).
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            error, self._error = self._error, None
            raise RuntimeError(
                f"fake device stopped after {self.frames_sent} frames: {error!r}"
            ) from error

    def close(self) -> None:
        """Stop sending and unplug (unplugged even when :meth:`stop` raises)."""
        try:
            self.stop()
        finally:
            self.unplug()

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class WireHeader:
    """The header fields and value encoding of every frame a :class:`FakeDevice` sends.

    Attributes:
        n_electrodes: electrodes on the driven layer.
        pattern_id: drive pattern the board runs.
        pattern_param: k of the SKIP pattern, else 0.
        current_a: injected current amplitude, amperes.
        value_encoding: FLOAT32_VOLTS, or INT32_COUNTS with ``volts_per_count``.
        volts_per_count: volts per ADC count (stored as float32, as on the wire).
    """

    n_electrodes: int = 16
    pattern_id: PatternId = PatternId.ADJACENT
    pattern_param: int = 0
    current_a: float = 1e-3
    value_encoding: ValueEncoding = ValueEncoding.FLOAT32_VOLTS
    volts_per_count: float = DEFAULT_VOLTS_PER_COUNT

    def __post_init__(self) -> None:
        object.__setattr__(self, "pattern_id", PatternId(self.pattern_id))
        object.__setattr__(self, "value_encoding", ValueEncoding(self.value_encoding))
        object.__setattr__(self, "volts_per_count", float(np.float32(self.volts_per_count)))


class FakeDevice(PtyBoard):
    """A pty that emits wire frames at ``rate_hz``.

    Args:
        frame_source: frame index -> voltages, volts [M] (M fixed).
        rate_hz: frames per second.
        header: header fields and value encoding of every frame.
        max_pending_bytes: bytes queued while nobody reads before frames are dropped.
    """

    def __init__(
        self,
        frame_source: FrameSource,
        rate_hz: float = 50.0,
        *,
        header: WireHeader = WireHeader(),
        max_pending_bytes: int = 1 << 20,
    ) -> None:
        super().__init__(rate_hz, max_pending_bytes=max_pending_bytes)
        self.frame_source = frame_source
        self.header = header
        self.n_electrodes = header.n_electrodes
        self.pattern_id = header.pattern_id
        self.pattern_param = header.pattern_param
        self.current_a = header.current_a
        self.value_encoding = header.value_encoding
        self.volts_per_count = header.volts_per_count

    def frame(self, index: int, device_time_us: int | None = None) -> DeviceFrame:
        """Frame ``index`` exactly as a parser will decode it (values rounded to the wire)."""
        volts = np.asarray(self.frame_source(index), dtype=np.float64)
        if self.value_encoding is ValueEncoding.FLOAT32_VOLTS:
            volts = volts.astype(np.float32).astype(np.float64)
        else:
            volts = np.rint(volts / self.volts_per_count) * self.volts_per_count
        if device_time_us is None:
            device_time_us = (time.monotonic_ns() - self._t0_ns) // 1000
        return DeviceFrame(
            sequence=index % 2**32,
            device_time_us=device_time_us,
            n_electrodes=self.n_electrodes,
            pattern_id=self.pattern_id,
            pattern_param=self.pattern_param,
            current_a=self.current_a,
            voltages_v=volts,
            flags=np.where(np.isfinite(volts), 0, 2).astype(np.uint8),
            value_encoding=self.value_encoding,
            volts_per_count=self.volts_per_count,
        )

    def send(self, frame: DeviceFrame) -> bool:
        """Queue and write one frame; False if unplugged or dropped (nobody reading)."""
        return self.write_frame(encode_frame(frame))

    def emit_frame(self, index: int, device_time_us: int) -> None:
        """Send wire frame ``index`` stamped ``device_time_us``."""
        self.send(self.frame(index, device_time_us=device_time_us))
