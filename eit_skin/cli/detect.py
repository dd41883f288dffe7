"""``eit-skin detect PORT``: which board is on a port, at what rate, and which patch fits it.

Listens at each board profile's rate (the port's bytes, nothing written), then, when nothing
was recognised, asks whether a Sciospec is there (a stop command it acknowledges). Prints
the profile, frames per second, numbers per frame, the patch layers whose protocol takes
that many numbers (the shipped patches, or ``--patch``), and how one frame correlates with
that layer's homogeneous model: the answer to "connected, but no image". With ``--patch``
whose layer names a Sciospec device, the layer's setup is sent and its frames are checked.
Exit 0 when a board was recognised, 1 when not.
"""

from __future__ import annotations

import argparse
import sys
import time

SHIPPED = ("arm", "face", "elbow")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="serial device, e.g. /dev/ttyUSB0")
    parser.add_argument("--patch", default="", help="patch to check the frames against")
    parser.add_argument("--layer", default="", help="its layer (default: the first)")
    parser.add_argument(
        "--listen", type=float, default=3.0, metavar="S", help="seconds per rate (default 3)"
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.hardware.detect import SCIOSPEC_PROBE, is_sciospec_answer, recognise
    from eit_skin.patch.device import PROFILES, DeviceSpec
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.resources import config_path

    if not args.listen > 0:
        print("eit-skin detect: --listen must be > 0", file=sys.stderr)
        return 2
    try:
        patches = [load_patch(config_path(args.patch))] if args.patch else []
        patches = patches or [load_patch(config_path(name)) for name in SHIPPED]
        chosen = patches[0].layer(args.layer) if args.patch and args.layer else None
    except (PatchError, KeyError, FileNotFoundError) as error:
        print(f"eit-skin detect: {error}", file=sys.stderr)
        return 2
    bauds = sorted({DeviceSpec(profile).baud for profile in PROFILES} - {0})
    found = None
    for baud in bauds:
        data = _read(args.port, baud, args.listen)
        if data is None:
            return 2
        found = recognise(data, args.listen)
        if found is not None:
            break
        print(f"{args.port} at {baud} bit/s: {len(data)} bytes, no known format", flush=True)
    if found is None:
        answer = _read(args.port, DeviceSpec("sciospec").baud, 1.0, SCIOSPEC_PROBE)
        if answer is not None and is_sciospec_answer(answer):
            print(f"{args.port}: a Sciospec device answered (profile sciospec)")
            return _sciospec(args, patches, chosen)
        print(f"{args.port}: no board profile recognised in {args.listen:g} s per rate")
        return 1
    print(
        f"{args.port}: profile {found.profile} at {baud} bit/s, {found.frames_per_s:.2f} "
        f"frames/s, {found.values_per_frame} numbers per frame ({found.detail})"
    )
    fits = fitting_layers(patches, found.values_per_frame)
    print(
        "fits: "
        + (
            ", ".join(_fit_name(p, la, found.profile) for p, la in fits)
            or ("no layer of " + _names(patches))
        )
    )
    layer = chosen or (fits[0][1] if fits else None)
    if layer is not None:
        r = model_correlation(layer, np.asarray(found.last_frame))
        print(_verdict(layer.name, r))
    return 0


def _read(port: str, baud: int, seconds: float, send: bytes = b"") -> bytes | None:
    import serial

    try:
        with serial.Serial(port, baud, timeout=0.05) as link:
            if send:
                link.write(send)
            data = bytearray()
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                data += link.read(65536)
            return bytes(data)
    except (serial.SerialException, OSError) as error:
        print(f"eit-skin detect: {port}: {error}", file=sys.stderr)
        return None


def _names(patches) -> str:
    return ", ".join(p.name for p in patches)


def fitting_layers(patches, values_per_frame: int) -> list:
    """``(patch, layer)`` of the layers that take ``values_per_frame`` numbers per frame.

    A layer takes its device frame size or its measurement count.
    """
    from eit_skin.patch.protocol import build_protocol

    out = []
    for patch in patches:
        for layer in patch.layers:
            protocol = build_protocol(layer.protocol, layer.n_electrodes)
            if values_per_frame in (protocol.frame_size, protocol.n_measurements):
                out.append((patch, layer))
    return out


def _fit_name(patch, layer, profile: str) -> str:
    """``patch/layer``, naming the board profile its ``device`` section needs if another."""
    if layer.device.profile == profile:
        return f"{patch.name}/{layer.name}"
    return (
        f"{patch.name}/{layer.name} (needs device: {{profile: {profile}}}; "
        f"it says {layer.device.profile})"
    )


def model_correlation(layer, numbers) -> float:
    """Correlation of one frame (device layout or protocol order) with the homogeneous model.

    Magnitudes (``values: magnitude``) are compared as magnitudes. Near 1: this layer's
    measurements in its order; near 0 or negative: another order, numbering, drive or sheet.
    """
    import numpy as np

    from eit_skin.patch.protocol import build_protocol
    from eit_skin.pipeline.builder import forward_model

    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    expected = forward_model(layer).voltages(layer.material.sheet_conductance_s)
    measured = protocol.select(np.asarray(numbers))
    if protocol.magnitude:
        expected, measured = np.abs(expected), np.abs(measured)
    ok = np.isfinite(measured)
    if ok.sum() < 3 or np.std(measured[ok]) == 0:
        return float("nan")
    return float(np.corrcoef(expected[ok], measured[ok])[0, 1])


def _verdict(name: str, r: float) -> str:
    if r == r and r >= 0.9:
        return f"one-frame check against {name}'s model: correlation {r:.3f}, looks right"
    return (
        f"one-frame check against {name}'s model: correlation {r:.3f}: not this layer's "
        "measurements in this order (check electrode numbering, drive pattern, layout; "
        "docs/boards.md)"
    )


def _sciospec(args, patches, chosen) -> int:
    """Run a Sciospec layer's setup and check its frames (needs ``--patch``)."""
    from eit_skin.hardware.sources import LayerFrameFactory, SerialSource

    layer = chosen or next(
        (la for p in patches for la in p.layers if la.device.profile == "sciospec"), None
    )
    if layer is None or not args.patch:
        print("give --patch with a layer whose device is sciospec to run its setup")
        return 0
    patch = patches[0]
    records = []
    source = SerialSource(
        LayerFrameFactory(patch, layer, patch.frame_id), args.port, 0, records.append
    )
    source.start()
    time.sleep(args.listen)  # listening for a fixed time is the point here
    source.stop()
    status = source.status()
    print(f"{len(records) / args.listen:.2f} frames/s after the setup ({status.message})")
    if records:
        print(_verdict(layer.name, model_correlation(layer, records[-1].voltages)))
    return 0
