"""DeviceClock against synthetic clocks with known drift, jitter and resets."""

from __future__ import annotations

import numpy as np
import pytest

from eit_skin.hardware.device_clock import DeviceClock, DeviceClockConfig

HOST0 = 1_700_000_000_000_000_000
MIN_DELAY_S = 200e-6


def simulate(clock, drift_ppm, seconds=60.0, rate_hz=100.0, seed=0, device0_us=123_456):
    """Acquisition at host times t_k; device stamps run (1 + drift) fast; reception is late."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    device_us = device0_us + np.round(t * (1 + drift_ppm * 1e-6) * 1e6).astype(np.int64)
    delay = MIN_DELAY_S + rng.exponential(500e-6, t.size)
    host_ns = HOST0 + np.round((t + delay) * 1e9).astype(np.int64)
    mapped = np.array(
        [clock.update(int(d), int(h)) for d, h in zip(device_us, host_ns, strict=True)]
    )
    truth = HOST0 + np.round((t + MIN_DELAY_S) * 1e9).astype(np.int64)
    return t, mapped, truth, host_ns


@pytest.mark.parametrize("drift_ppm", [100.0, -100.0])
def test_drift_and_jitter_error_stays_bounded(drift_ppm):
    clock = DeviceClock()
    t, mapped, truth, host_ns = simulate(clock, drift_ppm)
    error_us = (mapped - truth) / 1e3
    settled = t >= 5.0
    assert np.abs(error_us[settled]).max() < 60.0
    # a mapping without drift would be off by drift x elapsed time (6 ms after 60 s)
    naive_us = np.abs(drift_ppm) * 1e-6 * t[-1] * 1e6
    assert naive_us > 50 * np.abs(error_us[-1])
    assert clock.drift_ppm == pytest.approx(-drift_ppm / (1 + drift_ppm * 1e-6), abs=3.0)
    assert np.all(mapped <= host_ns)  # never later than reception


def test_constant_delay_without_drift_is_mapped_exactly():
    clock = DeviceClock()
    for k in range(500):
        mapped = clock.update(5_000 + 10_000 * k, HOST0 + 10_000_000 * k + 300_000)
        assert mapped == HOST0 + 10_000_000 * k + 300_000  # min delay is the only delay
    assert clock.to_host_ns(5_000) == HOST0 + 300_000
    assert clock.drift_ppm == 0.0


def test_counter_reset_reanchors():
    clock = DeviceClock()
    _, mapped, truth, _ = simulate(clock, 100.0, seconds=20.0)
    assert clock.resets == 0
    assert abs(mapped[-1] - truth[-1]) < 60_000
    # the board reboots: its counter restarts near zero 20 s later
    rng = np.random.default_rng(3)
    errors = []
    for k in range(2000):
        t_k = 20.0 + k * 0.01
        d = round((t_k - 20.0) * (1 + 100e-6) * 1e6)
        h = HOST0 + round((t_k + MIN_DELAY_S + rng.exponential(500e-6)) * 1e9)
        errors.append((clock.update(d, h) - (HOST0 + round((t_k + MIN_DELAY_S) * 1e9))) / 1e3)
    assert clock.resets == 1
    errors = np.abs(np.array(errors))
    assert errors.max() < 5_000  # no jump of 20 s: re-anchored at once
    assert errors[500:].max() < 60.0


def test_32_bit_counter_wrap_is_a_reset():
    clock = DeviceClock()
    wrap = 2**32
    d0 = wrap - 50_000  # 50 ms before a 32-bit microsecond counter wraps
    for k in range(20):
        d = (d0 + 10_000 * k) % wrap
        clock.update(d, HOST0 + 10_000_000 * k + 100_000)
    assert clock.resets == 1
    assert clock.to_host_ns((d0 + 10_000 * 19) % wrap) == HOST0 + 190_000_000 + 100_000


def test_forward_jump_beyond_tolerance_is_a_reset():
    clock = DeviceClock(DeviceClockConfig(reset_jump_s=0.5))
    clock.update(0, HOST0)
    clock.update(10_000, HOST0 + 10_000_000)
    clock.update(10_000 + 2_000_000, HOST0 + 20_000_000)  # device leapt 2 s in 10 ms
    assert clock.resets == 1


def test_config_validation():
    with pytest.raises(ValueError):
        DeviceClockConfig(bin_s=1.0, window_s=1.0)
    with pytest.raises(RuntimeError):
        DeviceClock().to_host_ns(0)


def test_frames_read_in_bursts_keep_their_spacing():
    """A loaded host reads frames in bursts; stamps must still follow the device clock."""
    clock = DeviceClock()
    rng = np.random.default_rng(4)
    period_us = 10_000
    stamps, truth = [], []
    k = 0
    t_host = 1_000_000_000_000
    while k < 600:
        burst = int(rng.integers(1, 6))  # 1..5 frames per read
        device = [(k + i) * period_us for i in range(burst)]
        k += burst
        t_host = (
            max(t_host, 1_000_000_000_000 + device[-1] * 1000) + int(rng.integers(2, 40)) * 10**6
        )
        stamps += clock.update_batch(device, [t_host] * burst)
        truth += [1_000_000_000_000 + d * 1000 for d in device]
    stamps, truth = np.array(stamps), np.array(truth)
    assert np.all(np.diff(stamps) > 0)
    late = stamps - truth  # mapped minus true acquisition time; reads lag 2..40 ms
    assert late.min() > -1_000_000  # never (much) before the acquisition
    assert late[100:].max() < 6_000_000  # near the 2 ms minimum delay, not the 40 ms jitter
