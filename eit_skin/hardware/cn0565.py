"""Analog Devices EVAL-CN0565 (AD5940 + ADG2128) through ``pyadi-iio``: an optional extra.

The board is host-driven: every measurement is requested by the host. ``adi.cn0565``
(pyadi-iio, ``adi/cn0565.py``) sets the electrode count, the force (drive) and sense
(measure) distances and the excitation frequency, and its ``all_voltages`` property returns
``[M, 2]`` (real, imaginary) for, per drive ``f+ = i, f- = i + force_distance``, every
``s+ = j`` with ``s- = j + sense_distance``, pairs touching a drive electrode left out: the
layer's protocol for ``drive/measure: adjacent|skip|opposite`` in increasing order (the
patch loader refuses other protocols for this profile). The values go through the
protocol's ``complex_part`` like any complex frame. ``pyadi-iio`` is imported only when a
layer uses this profile; without it the source refuses to start naming the package.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from eit_skin.hardware.source_status import RateMeter, SourceStatus
from eit_skin.patch.protocol import build_protocol, pattern_offset

PACKAGE = "pyadi-iio"
DEFAULT_BAUD = 230_400
"""The CN0565's serial IIO link rate (pyadi-iio's examples)."""


def open_board(layer: Any, port: str) -> Any:
    """An ``adi.cn0565`` set up for the layer (electrodes, distances, frequency).

    Raises:
        RuntimeError: pyadi-iio is not installed (the message names the package).
    """
    try:
        import adi
    except ImportError as error:
        raise RuntimeError(
            f"layer {layer.name!r}: device profile cn0565 needs the Python package "
            f"{PACKAGE!r} (pip install {PACKAGE}), which is not installed"
        ) from error
    device = layer.device
    spec = layer.protocol
    uri = str(device.get("uri")) or f"serial:{port},{DEFAULT_BAUD},8n1"
    board = adi.cn0565(uri=uri)
    board.excitation_frequency = float(device.get("excitation_hz"))
    board.electrode_count = layer.n_electrodes
    board.force_distance = pattern_offset(spec.drive, spec.drive_skip, layer.n_electrodes)
    board.sense_distance = pattern_offset(spec.measure, spec.measure_skip, layer.n_electrodes)
    return board


class Cn0565Source:
    """Frames of a CN0565 board read on a thread, one ``all_voltages`` call per frame.

    Stamps: the host time when the call returned (the board sends no clock). A failing call
    (board unplugged) closes the board and opens it again after ``retry_s``.
    """

    def __init__(self, factory: Any, port: str, sink: Any, retry_s: float = 1.0) -> None:
        self.factory = factory
        self.port = port
        self.sink = sink
        self.retry_s = retry_s
        self.protocol = build_protocol(factory.layer.protocol, factory.layer.n_electrodes)
        self.rate = RateMeter()
        self.published = 0
        self.reconnects = 0
        self.last_error = ""
        self.rejected: dict[str, int] = {"values": 0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.board: Any = open_board(factory.layer, port)  # refuse to start without pyadi-iio

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="Cn0565Source", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                if self.board is None:
                    self.board = open_board(self.factory.layer, self.port)
                raw = np.asarray(self.board.all_voltages, dtype=np.float64)
            except Exception as error:  # a lost board surfaces as many error types
                with self._lock:
                    self.last_error = f"{type(error).__name__}: {error}"
                    self.reconnects += self.board is not None
                self.board = None
                self._stop.wait(self.retry_s)
                continue
            self.publish(raw, time.time_ns())

    def publish(self, raw: np.ndarray, stamp_ns: int) -> None:
        """One ``all_voltages`` result ``[M, 2]`` (re, im) -> the layer's frame."""
        if raw.shape != (self.protocol.n_measurements, 2):
            with self._lock:
                self.rejected["values"] += 1
                self.last_error = (
                    f"all_voltages gave shape {raw.shape}, layer {self.factory.layer.name!r} "
                    f"expects [{self.protocol.n_measurements}, 2]"
                )
            return
        record = self.factory.device_record(stamp_ns, self.published, raw[:, 0] + 1j * raw[:, 1])
        self.sink(record)
        with self._lock:
            self.published += 1
            self.rate.tick()

    def status(self) -> SourceStatus:
        with self._lock:
            values = {
                "source": "cn0565",
                "profile": "cn0565",
                "port": self.port,
                "frame_rate_hz": f"{self.rate.rate_hz():.1f}",
                "frames_published": str(self.published),
                "rejected_values": str(self.rejected["values"]),
                "reconnects": str(self.reconnects),
                "last_error": self.last_error,
            }
            connected = self.board is not None
        if not connected and self.last_error:
            return SourceStatus(2, f"CN0565 on {self.port}: {self.last_error}", values)
        return SourceStatus(0, f"{values['frame_rate_hz']} frames/s from CN0565", values)
