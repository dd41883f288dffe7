"""``eit-skin fake-device``: emulate a skin board on a pseudo-terminal."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from eit_skin.cli.options import LAYER_HELP, chosen_layer

DEVICES = ("wire", "openeit", "lines", "sciospec")

#: ``--separator`` names -> what the board prints after every value
SEPARATORS = {"comma-space": ", ", "comma": ",", "semicolon": ";", "space": " ", "tab": "\t"}

#: serial rate of the real board's link, bit/s (8N1): the frame rate it can carry
LINK_BAUD = {"openeit": 115_200, "sciospec": 921_600}

#: option -> the devices it applies to (given for another device: refused)
DEVICE_OPTIONS = {
    "encoding": ("wire",),
    "electrodes": ("wire",),
    "current": ("wire",),
    "scale": ("openeit", "lines"),
    "separator": ("lines",),
    "label": ("lines",),
    "line_ending": ("lines",),
    "drop_zeros": ("lines",),
    "channels": ("sciospec",),
    "first_channel": ("sciospec",),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--device",
        choices=DEVICES,
        default="wire",
        help="which board to emulate: eit_skin's wire protocol (default), an OpenEIT board, "
        "a line-printing board or a Sciospec device, byte for byte",
    )
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
    parser.add_argument(
        "--patch",
        default="arm",
        help="patch (name or YAML path): the simulated patch, and the protocol of an "
        "emulated board (with --frames too)",
    )
    parser.add_argument("--layer", default="", help=LAYER_HELP)
    parser.add_argument("--scenario", default="demo", help="simulator touch script, looped")
    parser.add_argument("--seed", type=int, default=0, help="simulator random seed")
    parser.add_argument(
        "--count", type=int, default=0, metavar="N", help="stop after N frames (0 = run forever)"
    )
    _add_board_options(parser)
    parser.add_argument(
        "--linger",
        type=float,
        default=1.0,
        metavar="S",
        help="with --count, keep the pty open S seconds after the last frame so readers drain it",
    )


def _add_board_options(parser: argparse.ArgumentParser) -> None:
    """The options of one emulated board each (:data:`DEVICE_OPTIONS`)."""
    parser.add_argument(
        "--encoding",
        choices=("volts", "counts"),
        default=None,
        help="wire: values as float32 volts or int32 ADC counts (default volts)",
    )
    parser.add_argument(
        "--electrodes", type=int, default=None, help="wire: n_electrodes field (with --frames)"
    )
    parser.add_argument(
        "--current", type=float, default=None, metavar="A", help="wire: current_a (with --frames)"
    )
    parser.add_argument(
        "--scale",
        type=float,
        default=None,
        help="openeit, lines: board units per volt (default 1; openeit on the simulator: "
        "1 / the layer's current, the firmware's transfer impedance in ohms)",
    )
    parser.add_argument(
        "--separator",
        choices=tuple(SEPARATORS),
        default=None,
        help="lines: what follows every value (default comma-space)",
    )
    parser.add_argument("--label", default=None, help="lines: a 'LABEL: ' prefix on every line")
    parser.add_argument(
        "--line-ending", choices=("lf", "crlf"), default=None, help="lines: default lf"
    )
    parser.add_argument(
        "--drop-zeros",
        action="store_true",
        default=None,
        help="lines: print only the used entries of a full layout",
    )
    parser.add_argument(
        "--channels",
        type=int,
        default=None,
        help="sciospec: device channels, 16/32/48/64 (default 32, 64 above 32 electrodes)",
    )
    parser.add_argument(
        "--first-channel",
        type=int,
        default=None,
        help="sciospec: the channel (1-based) the layer's board electrode 0 is wired to "
        "(default 1)",
    )


def argument_error(args: argparse.Namespace) -> str | None:
    """The first invalid argument as a one-line message, or None."""
    checks = (
        (args.rate > 0, "--rate must be > 0"),
        (args.count >= 0, "--count must be >= 0"),
        (args.linger >= 0, "--linger must be >= 0"),
        (args.electrodes is None or args.electrodes >= 3, "--electrodes must be >= 3"),
        (args.current is None or args.current > 0, "--current must be > 0"),
        (args.scale is None or args.scale > 0, "--scale must be > 0"),
        (
            args.channels is None or args.channels in (16, 32, 48, 64),
            "--channels must be 16, 32, 48 or 64",
        ),
        (args.first_channel is None or args.first_channel >= 1, "--first-channel must be >= 1"),
    )
    for ok, message in checks:
        if not ok:
            return message
    for option, devices in DEVICE_OPTIONS.items():
        if getattr(args, option) is not None and args.device not in devices:
            flag = "--" + option.replace("_", "-")
            return f"{flag} applies to --device {' / '.join(devices)}, not {args.device}"
    return None


def run(args: argparse.Namespace) -> int:
    error = argument_error(args)
    if error is None:
        try:
            device, label = _wire_device(args) if args.device == "wire" else _board(args)
        except (OSError, ValueError, KeyError) as failure:
            error = failure.args[0] if isinstance(failure, KeyError) else str(failure)
    if error is not None:
        print(f"eit-skin fake-device: {error}", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    path = device.open()
    try:
        if args.link:
            device.link(args.link)
            print(f"fake device on {path} (link {args.link} -> {path})", flush=True)
        else:
            print(f"fake device on {path}", flush=True)
        print(f"source: {label}; {args.rate:g} Hz", flush=True)
        if args.device in LINK_BAUD:
            frame_bytes = len(
                device.frame_line(0)
                if args.device == "openeit"
                else device.data_frames(0, 0.0, 1000.0 / args.rate)
            )
            most = LINK_BAUD[args.device] / 10 / frame_bytes  # 8N1: 10 bits a byte
            if args.rate > most:
                print(
                    f"note: {frame_bytes} bytes a frame: the real board's "
                    f"{LINK_BAUD[args.device]} baud link carries at most {most:.3g} frames/s",
                    flush=True,
                )
        try:
            sent = device.run(count=args.count or None, stop=stop)
            if args.count and not stop.is_set():
                stop.wait(args.linger)
        except KeyboardInterrupt:
            sent = device.frames_sent
        print(f"sent {sent} frames ({device.frames_dropped} dropped, nobody reading)", flush=True)
    finally:
        device.unplug()
        signal.signal(signal.SIGTERM, previous)
    return 0


def _wire_device(args: argparse.Namespace):
    """eit_skin's own wire protocol: the FakeDevice of today."""
    from eit_skin.hardware.fake_device import FakeDevice, WireHeader, npz_frame_source
    from eit_skin.hardware.wire import ValueEncoding

    pattern = {}
    electrodes, current = args.electrodes or 16, args.current or 1e-3
    if args.frames:
        source, n_values = npz_frame_source(args.frames)
        label = f"frames from {args.frames} ({n_values} values, looped)"
    else:
        layer, protocol, measurements, label = _simulated_layer(args)
        pattern = _wire_pattern(layer)
        electrodes, current = layer.n_electrodes, layer.current_a

        def source(index: int):  # in the board's conventions: layout, magnitudes
            return protocol.device_frame(measurements(index))

    encoding = args.encoding or "volts"
    header = WireHeader(
        n_electrodes=electrodes,
        current_a=current,
        value_encoding=(
            ValueEncoding.FLOAT32_VOLTS if encoding == "volts" else ValueEncoding.INT32_COUNTS
        ),
        **pattern,
    )
    device = FakeDevice(source, args.rate, header=header)
    return device, f"{label}; wire protocol, {encoding}"


def _wire_pattern(layer) -> dict:
    from eit_skin.hardware.sources import pattern_id

    return {"pattern_id": pattern_id(layer), "pattern_param": layer.protocol.drive_skip}


def _board(args: argparse.Namespace):
    """An emulated OpenEIT, line-printing or Sciospec board speaking the layer's protocol."""
    from eit_skin.hardware import board_emulators, sciospec_emulator

    if args.frames:
        _, layer, protocol = _layer_protocol(args)
        measurements, label = _recording(args.frames, protocol)
        scale = args.scale or 1.0
    else:
        layer, protocol, measurements, label = _simulated_layer(args)
        scale = args.scale or (1.0 / layer.current_a if args.device == "openeit" else 1.0)
    if args.device == "openeit":
        device = board_emulators.OpenEITEmulator(measurements, protocol, args.rate, scale=scale)
        what = f"OpenEIT, {protocol.frame_size} magnitudes x {scale:g}"
    elif args.device == "lines":
        separator = SEPARATORS[args.separator or "comma-space"]
        line_format = board_emulators.LineFormat(
            separator=separator,
            label=args.label or "",
            line_ending="\r\n" if args.line_ending == "crlf" else "\n",
            drop_zeros=bool(
                args.drop_zeros
                or (layer.device.profile == "lines" and layer.device.get("drop_zeros"))
            ),
            scale=scale,
        )
        device = board_emulators.LinesEmulator(measurements, protocol, args.rate, line_format)
        what = f"lines, {protocol.frame_size} values x {scale:g}, separator {separator!r}"
    else:
        first = args.first_channel or (
            int(layer.device.get("first_channel")) if layer.device.profile == "sciospec" else 1
        )  # default: the wiring the patch's device section states
        device = sciospec_emulator.SciospecEmulator(
            measurements,
            protocol,
            args.rate,
            wiring=sciospec_emulator.SciospecWiring(
                args.channels, tuple(protocol.board_to_config.tolist()), first
            ),
        )
        what = f"Sciospec, {device.channels} channels, waiting for start"
    return device, f"{label}; {what}"


def _layer_protocol(args: argparse.Namespace):
    from eit_skin.patch.protocol import build_protocol

    patch, layer = chosen_layer(args)
    return patch, layer, build_protocol(layer.protocol, layer.n_electrodes)


def _recording(path: str, protocol):
    """Frame source looping a recording's frames, in the protocol's order."""
    from eit_skin.io.npz import load_frames_npz

    _, frames, _ = load_frames_npz(path)
    frames = protocol.select(frames, source=f"{path}: frames")
    return (lambda i: frames[i % frames.shape[0]]), f"frames from {path} ({len(frames)}, looped)"


def _simulated_layer(args: argparse.Namespace):
    """One simulated layer: (layer, protocol, index -> measurements [M] looped, label)."""
    from eit_skin.sim.simulator import SkinSimulator

    patch, layer, protocol = _layer_protocol(args)
    simulator = SkinSimulator(patch, args.scenario, rate_hz=args.rate, seed=args.seed)
    n = simulator.n_frames

    def measurements(index: int):
        return simulator.frame(index % n)[layer.name].voltages_v

    label = f"simulator: patch {patch.name}, layer {layer.name}, scenario {args.scenario} (looped)"
    return layer, protocol, measurements, label
