"""A serial port that never gives up: reads wire frames, reconnects with exponential backoff.

Two ways to use it (the driver node picks one):

* ``poll()`` from a timer: ``link.poll(timeout_s=0.0)`` reads what is waiting, returns the
  completed frames, and, while disconnected, retries the port when its backoff delay has
  passed. It never raises; ``link.status()`` tells the state, counters and the last error.
* ``start(on_frames, on_state)`` runs ``poll`` on a daemon thread and calls
  ``on_frames(list[ReceivedFrame])`` for every non-empty batch and ``on_state(LinkStatus)`` on
  every connect/disconnect. ``stop()`` joins it. Callbacks run on that thread.

An unplugged device shows up as a read error (pyserial ``SerialException``/``OSError``); an
absent port as an open error. Both close the port, record the error and schedule a retry
after ``backoff_initial_s``, doubling up to ``backoff_max_s``; the delay resets once a
reconnected port delivers bytes. pyserial discards bytes pending in the OS buffer when it
opens the port, and the parser is reset on every (re)connect.

Boards that need the host to speak (a mode line, a setup, a start command) get it from the
parser: a parser with ``commands(now_s) -> bytes`` (a board profile's reader,
:mod:`eit_skin.hardware.boards`) is asked on every poll and what it returns is written, and
its ``farewell()`` bytes are written before the port is closed by :meth:`SerialLink.stop`.
"""

from __future__ import annotations

import contextlib
import copy
import enum
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from eit_skin.hardware.wire import FrameParser


class LinkState(enum.Enum):
    """Whether the port is open."""

    CONNECTED = "connected"
    DISCONNECTED = "disconnected"


@dataclass(frozen=True)
class ReceivedFrame:
    """A parsed frame and the host time its last chunk was read, ns (``time.time_ns()``).

    The frame is a DeviceFrame (wire protocol) or a board profile's BoardFrame.
    """

    frame: Any
    host_time_ns: int


@dataclass(frozen=True)
class LinkStatus:
    """Snapshot of a SerialLink for diagnostics.

    Attributes:
        state: connected or disconnected.
        port: the configured device path.
        connects: successful opens so far.
        reconnects: successful opens after the first one.
        failed_attempts: opens that failed.
        disconnects: connections lost by a read error.
        last_error: text of the most recent error ('' if none).
        retry_in_s: seconds until the next open attempt (0 while connected).
        bytes_received: bytes read from the port, all connections.
        bytes_sent: bytes the host wrote to the board (commands), all connections.
        parser: a copy of the parser's counters.
    """

    state: LinkState
    port: str
    connects: int
    reconnects: int
    failed_attempts: int
    disconnects: int
    last_error: str
    retry_in_s: float
    bytes_received: int
    parser: Any  # ParserStats, or a board reader's ReaderStats
    bytes_sent: int = 0


def _open_serial(port: str, baud: int) -> Any:
    import serial  # pyserial; imported lazily so the module loads without it

    return serial.Serial(port=port, baudrate=baud, timeout=0.0, exclusive=True)


class SerialLink:
    """A reconnecting serial port feeding a FrameParser.

    Args:
        port: device path, e.g. ``/dev/eit_skin_arm`` (a udev symlink).
        baud: baud rate (ignored by USB CDC-ACM and ptys).
        parser: parser to feed (a new wire-protocol FrameParser by default; or a board
            profile's reader); it is reset on every (re)connect.
        backoff_initial_s: first retry delay after a failure, seconds.
        backoff_max_s: upper bound of the doubling retry delay, seconds.
        read_size: maximum bytes per read call.
        opener: ``opener(port, baud)`` returns an object with pyserial's ``read``,
            ``in_waiting``, ``timeout`` and ``close``; the default opens pyserial.
        clock: monotonic seconds, for the backoff schedule.
    """

    def __init__(
        self,
        port: str,
        baud: int = 921_600,
        *,
        parser: Any = None,
        backoff_initial_s: float = 0.1,
        backoff_max_s: float = 5.0,
        read_size: int = 65_536,
        opener: Callable[[str, int], Any] = _open_serial,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0 < backoff_initial_s <= backoff_max_s:
            raise ValueError("SerialLink needs 0 < backoff_initial_s <= backoff_max_s")
        self.port = port
        self.baud = baud
        self.parser = parser or FrameParser()
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.read_size = read_size
        self._opener = opener
        self.clock = clock
        self._serial: Any = None
        self._backoff = backoff_initial_s
        self._next_attempt = clock()
        self._data_since_connect = False
        self._connects = 0
        self._failed = 0
        self._disconnects = 0
        self._bytes = 0
        self._sent = 0
        self._last_error = ""
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._on_state: Callable[[LinkStatus], None] | None = None

    @property
    def connected(self) -> bool:
        return self._serial is not None

    def status(self) -> LinkStatus:
        """A consistent snapshot of state and counters (thread-safe)."""
        with self._lock:
            return LinkStatus(
                state=LinkState.CONNECTED if self._serial is not None else LinkState.DISCONNECTED,
                port=self.port,
                connects=self._connects,
                reconnects=max(0, self._connects - 1),
                failed_attempts=self._failed,
                disconnects=self._disconnects,
                last_error=self._last_error,
                retry_in_s=0.0
                if self._serial is not None
                else max(0.0, self._next_attempt - self.clock()),
                bytes_received=self._bytes,
                parser=copy.deepcopy(self.parser.stats),
                bytes_sent=self._sent,
            )

    def _notify(self) -> None:
        if self._on_state is not None:
            self._on_state(self.status())

    def _fail(self, error: BaseException, *, lost: bool) -> None:
        with self._lock:
            if self._serial is not None:
                with contextlib.suppress(Exception):  # closing a dead port may fail
                    self._serial.close()
                self._serial = None
            if lost:
                self._disconnects += 1
            else:
                self._failed += 1
            self._last_error = f"{type(error).__name__}: {error}"
            self._next_attempt = self.clock() + self._backoff
            self._backoff = min(2.0 * self._backoff, self.backoff_max_s)
        if lost:
            self._notify()

    def _try_open(self) -> bool:
        if self.clock() < self._next_attempt:
            return False
        try:
            port = self._opener(self.port, self.baud)
        except Exception as error:
            self._fail(error, lost=False)
            return False
        with self._lock:
            self._serial = port
            self._connects += 1
            self._data_since_connect = False
            self.parser.reset()
        self._notify()
        return True

    def poll(self, timeout_s: float = 0.0) -> list[ReceivedFrame]:
        """Read what the port has and return the frames it completed. Never raises.

        Waits up to ``timeout_s`` for the first byte. While disconnected, reopens the port when
        the backoff delay has passed (otherwise sleeps up to ``timeout_s`` and returns []).
        """
        if self._serial is None and not self._try_open():
            if timeout_s > 0:
                delay = max(0.0, self._next_attempt - self.clock())
                self._stop.wait(min(timeout_s, delay))
            return []
        port = self._serial
        try:
            self._write_commands(port)
            if port.timeout != timeout_s:
                port.timeout = timeout_s
            waiting = port.in_waiting
            data = port.read(min(max(1, waiting), self.read_size))
            if data and port.in_waiting:
                data += port.read(min(port.in_waiting, self.read_size))
        except Exception as error:  # unplug surfaces as several error types
            self._fail(error, lost=True)
            return []
        if not data:
            return []
        host_ns = time.time_ns()
        with self._lock:
            self._bytes += len(data)
            if not self._data_since_connect:
                self._data_since_connect = True
                self._backoff = self.backoff_initial_s
            frames = self.parser.feed(data)
        return [ReceivedFrame(f, host_ns) for f in frames]

    def _write_commands(self, port: Any) -> None:
        """Write what the parser asks the host to say now (nothing for a plain parser)."""
        commands = getattr(self.parser, "commands", None)
        if commands is None:
            return
        with self._lock:
            data = commands(self.clock())
        if data:
            port.write(data)
            self._sent += len(data)

    def start(
        self,
        on_frames: Callable[[list[ReceivedFrame]], None],
        on_state: Callable[[LinkStatus], None] | None = None,
        poll_timeout_s: float = 0.05,
    ) -> None:
        """Run ``poll`` on a daemon thread, delivering frames and state changes by callback."""
        if self._thread is not None:
            raise RuntimeError("SerialLink.start called twice")
        self._on_state = on_state
        self._stop.clear()

        def loop() -> None:
            while not self._stop.is_set():
                frames = self.poll(poll_timeout_s)
                if frames:
                    on_frames(frames)

        self._thread = threading.Thread(target=loop, name=f"SerialLink({self.port})", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread started by ``start``, say the parser's farewell, close the port.

        The farewell is e.g. a stop command (a board profile's reader).
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        farewell = getattr(self.parser, "farewell", lambda: b"")()
        if farewell and self._serial is not None:
            with contextlib.suppress(Exception):  # a dead port cannot be told anything
                self._serial.write(farewell)
                self._serial.flush()
        self.close()

    def close(self) -> None:
        """Close the port; a later ``poll`` reopens it."""
        with self._lock:
            if self._serial is not None:
                with contextlib.suppress(Exception):  # closing a dead port may fail
                    self._serial.close()
                self._serial = None

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
