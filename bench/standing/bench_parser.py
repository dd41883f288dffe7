"""Parser throughput (frames/s, one core): the wire protocol and every board profile's reader.

Run: .venv/bin/python -m bench.standing.bench_parser  (prints the tables, writes parser.md)
Targets: wire protocol >= 20,000 frames/s (issue 5); each board profile's reader >= 20x the
fastest frame rate its link can carry (issue 34).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.header import run_header
from eit_skin.frames import FrameRecord
from eit_skin.hardware.device_clock import DeviceClock
from eit_skin.hardware.sciospec import message
from eit_skin.hardware.sources import board_reader
from eit_skin.hardware.wire import DeviceFrame, FrameParser, PatternId, ValueEncoding, encode_frame
from eit_skin.io.cdr import encode_eit_frame_cdr
from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.protocol import build_protocol

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


def frames_per_s(data: bytes, good: int, chunk: int, make_parser=FrameParser) -> float:
    """Best of 3: frames per second of a fresh ``make_parser()`` fed ``chunk`` bytes at a time."""
    best = 0.0
    for _ in range(3):
        parser = make_parser()
        t0 = time.perf_counter()
        n = 0
        for i in range(0, len(data), chunk):
            n += len(parser.feed(data[i : i + chunk]))
        dt = time.perf_counter() - t0
        assert n == good, (n, good)
        best = max(best, n / dt)
    return best


def board_layer(n: int, protocol: dict, device: dict):
    """A circular layer of ``n`` electrodes read by ``device`` (no mesh is built)."""
    layer = {
        "name": "bench",
        "outline": {"type": "circle", "radius": 0.1},
        "electrodes": {"count": n, "width": 0.005, "contact_impedance": 0.01},
        "material": {"quantity": "pressure", "sheet_conductance": 1.0, "pressure_scale": 1.0},
        "current": 1e-3,
        "protocol": protocol,
        "device": device,
    }
    data = {"name": "bench", "frame_id": "bench_link", "layers": [layer]}
    layer = patch_from_dict(data, check_budget=False).layers[0]
    return layer, build_protocol(layer.protocol, n)


def fixed_28_4(values: np.ndarray) -> bytes:
    full = np.round(values * 16).astype(np.int64)
    return b"".join(b"%8d.%04d," % (f >> 4, (f & 15) * 625) for f in full)


def board_streams() -> list[tuple[str, object, object, bytes, int, float]]:
    """(name, layer, protocol, 20 frames of bytes, frames, link-bound frames/s) per board."""
    rng = np.random.default_rng(0)
    opposite = {"drive": "opposite", "measure": "adjacent", "values": "magnitude"}
    out = []
    for n in (16, 32):
        layer, protocol = board_layer(n, opposite, {"profile": "openeit"})
        lines = b"".join(
            b"magnitudes: " + fixed_28_4(rng.uniform(0, 5e4, n * (n - 4))) + b"\r\n"
            for _ in range(20)
        )
        # 115200 bit/s, 8N1: 11,520 bytes/s
        out.append(
            (f"openeit, {n} electrodes", layer, protocol, lines, 20, 11_520 / (len(lines) / 20))
        )
    full = {"drive": "adjacent", "measure": "adjacent", "layout": "full"}
    layer, protocol = board_layer(32, full, {"profile": "lines"})
    text = b"".join(
        (", ".join(f"{v:.4f}" for v in rng.uniform(0, 3, 1024)) + ", \n").encode()
        for _ in range(20)
    )
    # a Teensy's USB serial: USB full speed, ~1 MB/s of payload
    out.append(("lines, 32 x 32 full layout", layer, protocol, text, 20, 1e6 / (len(text) / 20)))
    layer, protocol = board_layer(
        32, {"drive": "adjacent", "measure": "adjacent"}, {"profile": "sciospec"}
    )
    stages = []
    for k, (a, b) in enumerate(protocol.injections):
        for group in (1, 2):
            data = rng.normal(size=32).astype(">f4").tobytes()
            payload = bytes((group, a + 1, b + 1, 0, 0)) + (1000 + k).to_bytes(4, "big") + data
            stages.append(message(0xB4, payload))
    cycle = b"".join(stages)
    # USB full speed (12 Mbit/s): ~1 MB/s of payload at best
    out.append(("sciospec, 32 electrodes", layer, protocol, cycle * 20, 20, 1e6 / len(cycle)))
    return out


def board_reader_of(layer, protocol):
    """A profile's reader, as after a connect whose commands the board answered."""
    reader = board_reader(protocol, layer.device, layer.name, layer.current_a, lambda f: None)
    reader.acknowledged = True  # (the Sciospec's data counts only after its setup)
    return reader


def board_rows() -> list[str]:
    rows = []
    for name, layer, protocol, data, frames, link_fps in board_streams():
        fps = frames_per_s(
            data, frames, 4096, lambda layer=layer, p=protocol: board_reader_of(layer, p)
        )
        rows.append(
            f"| {name} | {len(data) // frames:,} | {link_fps:,.1f} | {fps:,.0f} | "
            f"{fps / link_fps:,.0f}x |"
        )
    return rows


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
        "# Parser benchmark (`bench/standing/bench_parser.py`)",
        "",
        f"{run_header()} {N_FRAMES} frames of {M} values ({frame_bytes} bytes each), best of"
        " 3, one core. Target >= 20,000 frames/s.",
        "",
        "| encoding | stream | feed size | frames/s |",
        "|---|---|---|---:|",
        *(f"| {e} | {s} | {c} | {fps:,.0f} |" for e, s, c, fps in rows),
        "",
        f"DeviceClock.update: {clock_us:.1f} us per frame; "
        f"EitFrame CDR encoding (208 values): {cdr_us:.1f} us per frame.",
        "",
        "## Board profiles (issue 34)",
        "",
        "Each reader fed 20 frames in 4096-byte reads, best of 3. Link-bound rate: the most",
        "frames per second the board's link can carry (OpenEIT: 115200 bit/s 8N1; a line-",
        "printing Teensy and a Sciospec on USB full speed: ~1 MB/s of payload, an upper bound",
        "of what those boards measure). Target: >= 20x the link-bound rate.",
        "",
        "| board | bytes per frame | link-bound frames/s | reader frames/s | margin |",
        "|---|---:|---:|---:|---:|",
        *board_rows(),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    (Path(__file__).parent / "parser.md").write_text(text)


if __name__ == "__main__":
    main()
