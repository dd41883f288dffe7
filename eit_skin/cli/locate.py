"""``eit-skin locate``: press positions, confidence and depth of frames from a calibration.

Input ``--frames``: ``reference`` [M] + ``frames`` [T, M] (+ optional ``references`` [T, M],
each frame's own unloaded baseline). Output ``--out`` (npz): ``xy`` [T, 2] m in the sheet
frame, ``confidence`` [T] in [0, 1] (share of calibration presses spaced at least as far
from their neighbours as this frame is from the nearest one: near 0 = unlike any calibration
press), ``depth`` [T] m when calibrated.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--patch", required=True, help="patch name or YAML path")
    parser.add_argument("--layer", default="", help="layer (default: the first)")
    parser.add_argument("--calibration", type=Path, required=True, help="calibration npz")
    parser.add_argument("--frames", type=Path, required=True, help="frames npz")
    parser.add_argument("--out", type=Path, required=True, help="output npz")


def load_located_frames(path: Path, m: int):
    """(reference [M], frames [T, M], references [T, M] | None) of a frames file, validated."""
    import numpy as np

    from eit_skin.io.npz import load_frames_npz

    reference, frames, _ = load_frames_npz(path, m)
    with np.load(path, allow_pickle=False) as data:
        references = data["references"].astype(float) if "references" in data.files else None
    if references is not None and references.shape != frames.shape:
        raise ValueError(
            f"{path}: key 'references': shape {references.shape}, want {list(frames.shape)}"
        )
    for key, values in (("frames", frames), ("references", references)):
        if values is not None and not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
            raise ValueError(f"{path}: key '{key}' row {row}: not finite")
    return reference, frames, references


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.calibration.localiser import PressLocaliser
    from eit_skin.io.npz import write_npz_atomic
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.resources import config_path

    try:
        patch = load_patch(config_path(args.patch))
        layer = patch.layer(args.layer) if args.layer else patch.layers[0]
        model = PressLocaliser.load(args.calibration, layer)
        reference, frames, references = load_located_frames(args.frames, model.n_measurements)
        located = model.locate(frames, reference, references)
        out = {"xy": located.xy, "confidence": located.confidence}
        if located.depth is not None:
            out["depth"] = located.depth
        write_npz_atomic(args.out, **out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        print(f"eit-skin locate: {error}", file=sys.stderr)
        return 2
    print(
        f"wrote {args.out}: {len(frames)} frames, median confidence "
        f"{np.median(located.confidence):.2f}"
    )
    return 0
