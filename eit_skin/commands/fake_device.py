"""``eit-skin fake-device``: emulate a skin board on a pseudo-terminal."""

from __future__ import annotations

import argparse
import signal
import threading


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--link", metavar="PATH", help="also create a symlink PATH -> the pty (e.g. /tmp/eit_skin)"
    )
    parser.add_argument("--rate", type=float, default=50.0, metavar="HZ", help="frames per second")
    parser.add_argument(
        "--frames",
        metavar="IN.npz",
        help="offline frames file (reference [M], frames [T,M] volts), looped. Without it the "
        "device sends a TEST PATTERN: constant 208 zeros, not physics",
    )
    parser.add_argument(
        "--count", type=int, default=0, metavar="N", help="stop after N frames (0 = run forever)"
    )
    parser.add_argument(
        "--encoding",
        choices=("volts", "counts"),
        default="volts",
        help="values as float32 volts or int32 ADC counts (default volts)",
    )
    parser.add_argument("--electrodes", type=int, default=16, help="n_electrodes header field")
    parser.add_argument(
        "--current", type=float, default=1e-3, metavar="A", help="current_a header field, amperes"
    )
    parser.add_argument(
        "--linger",
        type=float,
        default=1.0,
        metavar="S",
        help="with --count, keep the pty open S seconds after the last frame so readers drain it",
    )


def run(args: argparse.Namespace) -> int:
    from eit_skin.fake_device import (
        TEST_PATTERN_LABEL,
        FakeDevice,
        constant_test_pattern,
        npz_frame_source,
    )
    from eit_skin.wire import ValueEncoding

    if args.frames:
        source, n_values = npz_frame_source(args.frames)
        label = f"frames from {args.frames} ({n_values} values, looped)"
    else:
        source, label = constant_test_pattern(208), TEST_PATTERN_LABEL
    encoding = (
        ValueEncoding.FLOAT32_VOLTS if args.encoding == "volts" else ValueEncoding.INT32_COUNTS
    )
    device = FakeDevice(
        source,
        args.rate,
        n_electrodes=args.electrodes,
        current_a=args.current,
        value_encoding=encoding,
    )
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    path = device.open()
    try:
        if args.link:
            device.link(args.link)
            print(f"fake device on {path} (link {args.link} -> {path})", flush=True)
        else:
            print(f"fake device on {path}", flush=True)
        print(f"source: {label}; {args.rate:g} Hz, {args.encoding}", flush=True)
        try:
            sent = device.run(count=args.count or None, stop=stop)
            if args.count and not stop.is_set():
                stop.wait(args.linger)
        except KeyboardInterrupt:
            sent = device.frames_sent
        print(f"sent {sent} frames ({device.frames_dropped} dropped, nobody reading)", flush=True)
    finally:
        device.unplug()
    return 0
