"""``eit-skin fake-device``: emulate a skin board on a pseudo-terminal."""

from __future__ import annotations

import argparse
import signal
import sys
import threading


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--link", metavar="PATH", help="also create a symlink PATH -> the pty (e.g. /tmp/eit_skin)"
    )
    parser.add_argument("--rate", type=float, default=50.0, metavar="HZ", help="frames per second")
    parser.add_argument(
        "--frames",
        metavar="IN.npz",
        help="offline frames file (reference [M], frames [T,M] volts), looped; "
        "default: the physics simulator (--patch, --layer, --scenario)",
    )
    parser.add_argument("--patch", default="arm", help="simulated patch (name or YAML path)")
    parser.add_argument("--layer", default="", help="simulated layer (default: the first)")
    parser.add_argument("--scenario", default="demo", help="simulator touch script, looped")
    parser.add_argument("--seed", type=int, default=0, help="simulator random seed")
    parser.add_argument(
        "--count", type=int, default=0, metavar="N", help="stop after N frames (0 = run forever)"
    )
    parser.add_argument(
        "--encoding",
        choices=("volts", "counts"),
        default="volts",
        help="values as float32 volts or int32 ADC counts (default volts)",
    )
    parser.add_argument(
        "--electrodes", type=int, default=16, help="n_electrodes header field (with --frames)"
    )
    parser.add_argument(
        "--current", type=float, default=1e-3, metavar="A", help="current_a field (with --frames)"
    )
    parser.add_argument(
        "--linger",
        type=float,
        default=1.0,
        metavar="S",
        help="with --count, keep the pty open S seconds after the last frame so readers drain it",
    )


def run(args: argparse.Namespace) -> int:
    try:
        device, label = _device(args)
    except (ValueError, KeyError, OSError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"eit-skin fake-device: error: {message}", file=sys.stderr)
        return 1
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


def _device(args: argparse.Namespace):
    """``(the fake board args ask for, not yet opened; its source's label)``.

    Raises ValueError for a bad option.
    """
    from eit_skin.hardware.fake_device import FakeDevice, npz_frame_source
    from eit_skin.hardware.wire import ValueEncoding

    if not args.rate > 0:
        raise ValueError(f"--rate: must be > 0 Hz, got {args.rate:g}")
    if args.count < 0:
        raise ValueError(f"--count: must be >= 0, got {args.count}")
    pattern = {}
    if args.frames:
        source, n_values = npz_frame_source(args.frames)
        label = f"frames from {args.frames} ({n_values} values, looped)"
    else:
        source, label, pattern = _simulated_source(args)
        args.electrodes, args.current = pattern.pop("n_electrodes"), pattern.pop("current_a")
    encoding = (
        ValueEncoding.FLOAT32_VOLTS if args.encoding == "volts" else ValueEncoding.INT32_COUNTS
    )
    device = FakeDevice(
        source,
        args.rate,
        n_electrodes=args.electrodes,
        current_a=args.current,
        value_encoding=encoding,
        **pattern,
    )
    return device, label


def _simulated_source(args: argparse.Namespace):
    """Frame source of one simulated layer (looped script) and the header fields it implies."""
    from eit_skin.hardware.sources import pattern_id
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.resources import config_path
    from eit_skin.sim.simulator import SkinSimulator

    patch = load_patch(config_path(args.patch))
    layer = patch.layer(args.layer) if args.layer else patch.layers[0]
    simulator = SkinSimulator(patch, args.scenario, rate_hz=args.rate, seed=args.seed)
    n = simulator.n_frames
    protocol = build_protocol(layer.protocol, layer.n_electrodes)

    def source(index: int):  # in the board's conventions: layout, magnitudes
        return protocol.device_frame(simulator.frame(index % n)[layer.name].voltages_v)

    fields = {
        "n_electrodes": layer.n_electrodes,
        "current_a": layer.current_a,
        "pattern_id": pattern_id(layer),
        "pattern_param": layer.protocol.drive_skip,
    }
    label = f"simulator: patch {patch.name}, layer {layer.name}, scenario {args.scenario} (looped)"
    return source, label, fields
