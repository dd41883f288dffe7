"""``eit-skin classify``: detect and label touches in an offline frames file; JSON lines.

Reads the pressure layer's frames (the patch's first layer, ``eit-skin reconstruct`` input
format: ``reference`` [M] V, ``frames`` [T, M] V, optional ``t`` [T] s), reconstructs them,
runs :class:`~eit_skin.touch.classifier.TouchClassifier` and prints one JSON object per
FINISHED touch: ``label``, ``t_start``, ``t_end`` (s from the first frame), ``confidence``,
``centroid`` ([x, y] m, patch frame). The first ``calibration_s`` (0.5 s) of the file must be
free of touch: they give the noise level. Errors: one line on stderr, exit status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--patch", required=True, help="patch YAML file (or a shipped name)")
    parser.add_argument(
        "--frames",
        required=True,
        type=Path,
        metavar="IN.npz",
        help="frames of the patch's first (pressure) layer, eit-skin reconstruct format",
    )
    parser.add_argument("--rate", required=True, type=float, metavar="HZ", help="frame rate, Hz")
    parser.add_argument(
        "--stretch-frames",
        type=Path,
        default=None,
        metavar="IN2.npz",
        help="frames of the patch's layer named 'stretch' (same format, same T); optional, "
        "sharpens rub/pinch on patches that have a stretch layer",
    )
    parser.add_argument(
        "--cache-dir",
        default="default",
        help="reconstruction matrix cache (default: $EIT_SKIN_CACHE or ~/.cache/eit_skin)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        for event in classify_file(args):
            print(json.dumps(event.to_dict()), flush=True)
    except (ValueError, KeyError, OSError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"eit-skin classify: error: {message}", file=sys.stderr)
        return 1
    return 0


def classify_file(args: argparse.Namespace):
    """Finished touch events (END) of the files named in ``args``."""
    from eit_skin.io.npz import load_frames_npz
    from eit_skin.patch.model import load_patch
    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.resources import config_path
    from eit_skin.touch.classifier import TouchClassifier
    from eit_skin.touch.shapes import single_contact_spread

    if not args.rate > 0:
        raise ValueError(f"--rate: must be > 0 Hz, got {args.rate:g}")
    patch_path = args.patch if Path(args.patch).exists() else config_path(args.patch)
    patch = load_patch(patch_path)
    cache = None if args.cache_dir in ("", "none") else args.cache_dir
    imager = LayerImager.build(patch.layers[0], cache_dir=cache)
    pressure = _images(imager, args.frames, load_frames_npz)
    stretch = None
    if args.stretch_frames is not None:
        names = [ly.name for ly in patch.layers]
        if "stretch" not in names:
            raise ValueError(
                f"--stretch-frames: patch {patch.name!r} has no layer 'stretch' ({names})"
            )
        stretch_imager = LayerImager.build(patch.layer("stretch"), cache_dir=cache)
        stretch = _images(stretch_imager, args.stretch_frames, load_frames_npz)
        if stretch.shape[0] != pressure.shape[0]:
            raise ValueError(
                f"{args.stretch_frames}: {stretch.shape[0]} frames, but {args.frames} has "
                f"{pressure.shape[0]}"
            )
    spread = single_contact_spread(imager)  # one fingertip's blur at every pixel, m
    classifier = TouchClassifier(imager.grid.x, imager.grid.y, contact_spread_m=spread)
    for k in range(pressure.shape[0]):
        t = k / args.rate
        for event in classifier.step(t, pressure[k], None if stretch is None else stretch[k]):
            if event.state == "end":
                yield event
    yield from classifier.finish()


def _images(imager, path: Path, load_frames_npz):
    """Physical images ``[T, H, W]`` of one layer's frames file."""
    if not Path(path).is_file():
        raise ValueError(f"{path}: no such file")
    reference, frames, _ = load_frames_npz(path, imager.n_measurements)
    if frames.shape[0] == 0:
        raise ValueError(f"{path}: no frames")
    return imager.physical(imager.images(imager.relative_change(frames, reference)))
