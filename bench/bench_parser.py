"""Wire-protocol parser throughput (frames/s, one core) for 208-value frames.

Run: .venv/bin/python bench/bench_parser.py   (prints a table, writes bench/parser.md)
Target (issue 5): >= 20,000 frames/s.
"""

from __future__ import annotations

import platform
import time
from pathlib import Path

import numpy as np

from eit_skin.frames import FrameRecord
from eit_skin.hardware.device_clock import DeviceClock
from eit_skin.hardware.wire import DeviceFrame, FrameParser, PatternId, ValueEncoding, encode_frame
from eit_skin.io.cdr import encode_eit_frame_cdr

N_FRAMES = 20_000
M = 208


def stream(encoding: ValueEncoding, corrupt_every: int = 0) -> tuple[bytes, int]:
    rng = np.random.default_rng(0)
    scale = float(np.float32(3.3 / 4096 / 1000))
    base = [
        encode_frame(
            DeviceFrame(
                i,
                10_000 * i,
                16,
                PatternId.ADJACENT,
                1e-3,
                rng.integers(-4_000_000, 4_000_000, M) * scale,
                value_encoding=encoding,
                volts_per_count=scale,
            )
        )
        for i in range(64)
    ]
    chunks, good = [], 0
    for i in range(N_FRAMES):
        raw = bytearray(base[i % 64])
        if corrupt_every and i % corrupt_every == 0:
            raw[100] ^= 0x01
        else:
            good += 1
        chunks.append(bytes(raw))
    return b"".join(chunks), good


def frames_per_s(data: bytes, good: int, chunk: int) -> float:
    best = 0.0
    for _ in range(3):
        parser = FrameParser()
        t0 = time.perf_counter()
        n = 0
        for i in range(0, len(data), chunk):
            n += len(parser.feed(data[i : i + chunk]))
        dt = time.perf_counter() - t0
        assert n == good, (n, good)
        best = max(best, n / dt)
    return best


def main() -> None:
    rows = []
    for encoding in ValueEncoding:
        for corrupt_every, label in ((0, "clean"), (100, "1% CRC errors")):
            data, good = stream(encoding, corrupt_every)
            for chunk in (len(data), 4096, 256):
                chunk_label = "whole stream" if chunk == len(data) else f"{chunk} B reads"
                rows.append((encoding.name, label, chunk_label, frames_per_s(data, good, chunk)))
    clock = DeviceClock()
    t0 = time.perf_counter()
    for k in range(N_FRAMES):
        clock.update(10_000 * k, 1_700_000_000_000_000_000 + 10_000_000 * k + (k * 7919) % 500_000)
    clock_us = (time.perf_counter() - t0) / N_FRAMES * 1e6
    rec = FrameRecord(0, "arm", "arm", "pressure", 16, "adjacent", 1e-3, 0, np.zeros(M), [])
    t0 = time.perf_counter()
    for _ in range(N_FRAMES):
        encode_eit_frame_cdr(rec)
    cdr_us = (time.perf_counter() - t0) / N_FRAMES * 1e6

    frame_bytes = len(encode_frame(DeviceFrame(0, 0, 16, 0, 0.0, np.zeros(M))))
    lines = [
        "# Parser benchmark (`bench/bench_parser.py`)",
        "",
        f"{N_FRAMES} frames of {M} values ({frame_bytes} bytes each), best of 3, one core;"
        f" {platform.machine()},"
        f" Python {platform.python_version()}, numpy {np.__version__}. Target >= 20,000 frames/s.",
        "",
        "| encoding | stream | feed size | frames/s |",
        "|---|---|---|---:|",
        *(f"| {e} | {s} | {c} | {fps:,.0f} |" for e, s, c, fps in rows),
        "",
        f"DeviceClock.update: {clock_us:.1f} us per frame; "
        f"EitFrame CDR encoding (208 values): {cdr_us:.1f} us per frame.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    (Path(__file__).parent / "parser.md").write_text(text)


if __name__ == "__main__":
    main()
