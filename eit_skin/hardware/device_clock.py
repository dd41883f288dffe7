"""Map the board's microsecond clock to host time, with offset, drift and counter resets.

Each received frame gives a pair (device time d of acquisition, host time h of reception);
``h - d`` is the clock offset plus a non-negative transport delay (USB/UART latency, OS
scheduling). The smallest ``h - d`` seen in a time bin is the best offset sample of that bin;
a least-squares line through the bin minima of the recent window gives the offset and the
drift (device clock rate error, ppm). The mapping therefore includes the minimum transport
delay, which is unobservable from one-way timestamps. A device time that runs backwards or
jumps away from host time (board reset, counter wrap) re-anchors the estimator.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DeviceClockConfig:
    """Estimator settings.

    Attributes:
        bin_s: host-time width of one minimum-delay bin, seconds.
        window_s: host-time span of bins used for the fit, seconds.
        reset_jump_s: a device-time step differing from the host-time step by more than this
            (seconds) is a reset/wrap and re-anchors the mapping.
        max_drift_ppm: drift estimates are clamped to +- this, parts per million.
    """

    bin_s: float = 1.0
    window_s: float = 30.0
    reset_jump_s: float = 1.0
    max_drift_ppm: float = 1000.0

    def __post_init__(self) -> None:
        if not (self.bin_s > 0 and self.window_s >= 2 * self.bin_s and self.reset_jump_s > 0):
            raise ValueError(
                "DeviceClockConfig needs bin_s > 0, window_s >= 2*bin_s, reset_jump_s > 0"
            )
        if not self.max_drift_ppm >= 0:
            raise ValueError("DeviceClockConfig.max_drift_ppm must be >= 0")


class DeviceClock:
    """Online device-microseconds -> host-nanoseconds mapping.

    Call ``update(device_time_us, host_time_ns)`` once per received frame (host time of the
    reception, e.g. ``time.time_ns()`` or ROS time in ns); it returns the frame's acquisition
    time in host nanoseconds, never later than ``host_time_ns``.
    """

    def __init__(self, config: DeviceClockConfig | None = None) -> None:
        self.config = config or DeviceClockConfig()
        self.resets = 0
        """Times the device clock was re-anchored after the first sample."""
        self._anchor: tuple[int, int] | None = None  # (device_us, host_ns)
        self._last: tuple[int, int] | None = None
        self._bins: deque[tuple[float, float]] = deque()  # (x_ns, y_ns) minima of closed bins
        self._bin_start_ns = 0
        self._cur: tuple[float, float] | None = None
        self._offset_ns = 0.0  # y at x = 0
        self._drift = 0.0  # dimensionless slope of y over x
        self._last_stamp_ns: int | None = None  # last stamp update_batch returned

    @property
    def drift_ppm(self) -> float:
        """Estimated device clock rate error: host seconds per device second - 1, in ppm."""
        return self._drift * 1e6

    @property
    def anchored(self) -> bool:
        return self._anchor is not None

    def _reanchor(self, device_us: int, host_ns: int) -> None:
        if self._anchor is not None:
            self.resets += 1
        self._anchor = (device_us, host_ns)
        self._bins.clear()
        self._bin_start_ns = host_ns
        self._cur = None
        self._offset_ns = 0.0
        self._drift = 0.0

    def update(self, device_time_us: int, host_time_ns: int) -> int:
        """Add one (device, host) observation and return the mapped acquisition time, ns."""
        d, h = int(device_time_us), int(host_time_ns)
        if self._last is None:
            self._reanchor(d, h)
        else:
            dd_ns = (d - self._last[0]) * 1000
            dh_ns = h - self._last[1]
            if dd_ns < 0 or abs(dd_ns - dh_ns) > self.config.reset_jump_s * 1e9:
                self._reanchor(d, h)
        self._last = (d, h)
        d0, h0 = self._anchor  # type: ignore[misc]
        x = float((d - d0) * 1000)
        y = float(h - h0) - x
        if h - self._bin_start_ns >= self.config.bin_s * 1e9 and self._cur is not None:
            # close the bin; the new observation opens the next one (refit below)
            self._bins.append(self._cur)
            self._cur = None
            self._bin_start_ns = h
            max_bins = int(self.config.window_s / self.config.bin_s)
            while len(self._bins) > max_bins:
                self._bins.popleft()
        changed = self._cur is None
        if self._cur is None or y < self._cur[1]:
            self._cur = (x, y)
            changed = True
        if changed:
            self._fit()
        return min(h, h0 + round(x + self._offset_ns + self._drift * x))

    def update_batch(self, device_times_us: list[int], host_times_ns: list[int]) -> list[int]:
        """``update`` for frames that arrived in one read, mapped after all were observed.

        Frames read together share (nearly) one host time, so mapping each as it is added
        clamps the later ones to that host time and several frames get the same stamp.
        Observing the whole batch first puts the envelope under its least-delayed frame;
        the frames then keep their device-time spacing. After a device reset inside the
        batch, each frame keeps its own ``update`` result.
        """
        resets = self.resets
        anchored = self._anchor
        single = [self.update(d, h) for d, h in zip(device_times_us, host_times_ns, strict=True)]
        if self.resets != resets or (anchored is not None and self._anchor != anchored):
            self._last_stamp_ns = None
            return single
        stamps = []
        for d, h in zip(device_times_us, host_times_ns, strict=True):
            stamp = min(h, self.to_host_ns(d))
            # never backwards: when a less delayed frame lowers the envelope, the first frames
            # after it are held just after the last stamp instead of jumping back
            if self._last_stamp_ns is not None and stamp <= self._last_stamp_ns:
                stamp = self._last_stamp_ns + 1
            stamps.append(stamp)
            self._last_stamp_ns = stamp
        return stamps

    def to_host_ns(self, device_time_us: int) -> int:
        """Map a device time with the current estimate (no update, no clamping)."""
        if self._anchor is None:
            raise RuntimeError("DeviceClock.to_host_ns before the first update()")
        d0, h0 = self._anchor
        x = float((int(device_time_us) - d0) * 1000)
        return h0 + round(x + self._offset_ns + self._drift * x)

    def _fit(self) -> None:
        # slope from closed bins only: a freshly opened bin's minimum is still high
        closed = np.asarray(self._bins, dtype=np.float64).reshape(-1, 2)
        if len(closed) >= 3 and np.ptp(closed[:, 0]) > 0:
            xc = closed[:, 0] - closed[:, 0].mean()
            slope = float(xc @ (closed[:, 1] - closed[:, 1].mean()) / (xc @ xc))
            limit = self.config.max_drift_ppm * 1e-6
            self._drift = min(max(slope, -limit), limit)
        else:
            self._drift = 0.0
        points = [*self._bins, self._cur] if self._cur is not None else list(self._bins)
        xy = np.asarray(points, dtype=np.float64)
        # lower envelope: the line with this slope touching the lowest bin minimum
        self._offset_ns = float(np.min(xy[:, 1] - self._drift * xy[:, 0]))
