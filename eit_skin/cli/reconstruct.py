"""``eit-skin reconstruct``: offline frames file (npz) -> relative conductivity images (npz).

IN.npz: ``reference`` float [M] volts, ``frames`` float [T, M] volts (protocol order).
OUT.npz: ``images`` float32 [T, H, W] relative conductivity change (delta sigma / sigma0,
positive = more conductive, NaN outside the sheet and in holes), ``x`` [W] and ``y`` [H]
pixel-centre coordinates in metres (patch frame). The output is written to a temporary
file next to OUT and renamed, so it is either complete or absent. Errors: one line on
stderr, exit status 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eit_skin.inverse.methods import METHODS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--patch", required=True, help="patch YAML file (or a shipped name)")
    parser.add_argument("--frames", required=True, type=Path, metavar="IN.npz")
    parser.add_argument("--out", required=True, type=Path, metavar="OUT.npz")
    parser.add_argument("--layer", default=None, help="layer name (default: the first layer)")
    parser.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="reconstruction method (default: the layer's solver.method; switching to or from "
        "greit re-chooses the hyperparameter for the new method's default noise figure)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        images, x, y, faulty = _reconstruct(args)
        from eit_skin.io.recording import write_npz_atomic

        write_npz_atomic(args.out, images=images, x=x, y=y)
    except (ValueError, KeyError, OSError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"eit-skin reconstruct: error: {message}", file=sys.stderr)
        return 1
    note = f", left out electrodes {faulty.tolist()}" if faulty.size else ""
    print(f"wrote {args.out}: {images.shape[0]} images {images.shape[1]}x{images.shape[2]}{note}")
    return 0


def _reconstruct(args: argparse.Namespace):
    from eit_skin.io.recording import load_frames_npz
    from eit_skin.patch.model import load_patch
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.pipeline.builder import LayerImager, with_method
    from eit_skin.resources import config_path

    patch = load_patch(config_path(args.patch))
    layer = patch.layers[0] if args.layer is None else patch.layer(args.layer)
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    if not args.frames.exists():
        raise ValueError(f"{args.frames}: no such file")
    reference, frames, _ = load_frames_npz(args.frames, protocol.n_measurements)

    # the chain the reconstruction node uses (cached by the layer's content), any method
    imager = LayerImager.build(layer if args.method is None else with_method(layer, args.method))
    reconstructor = imager.fault_tolerant()
    values = reconstructor.reconstruct(frames, reference)
    images = imager.images(values)
    return images, imager.grid.x, imager.grid.y, reconstructor.last_faulty
