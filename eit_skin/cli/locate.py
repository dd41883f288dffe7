"""``eit-skin locate``: press positions, confidence and depth of frames from a calibration.

Input ``--frames``: ``reference`` [M] + ``frames`` [T, M] (+ optional ``references`` [T, M],
each frame's own unloaded baseline), in the patch's device conventions as ``reconstruct`` reads
them (``layout: full`` frames of W numbers, complex frames). Output ``--out`` (npz): ``xy``
[T, 2] m in the sheet frame, ``confidence`` [T] in [0, 1] (share of calibration presses spaced
at least as far from their neighbours as this frame is from the nearest one: near 0 = unlike
any calibration press), ``depth`` [T] m when calibrated. With ``--max-touches K`` > 1 (a
calibration made with ``eit-skin calibrate --max-touches``): ``count`` [T] touches per frame,
``xy`` [T, K, 2], ``confidence`` and ``depth`` [T, K], NaN beyond each frame's count.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eit_skin.cli.options import add_max_touches_option, add_patch_options, chosen_layer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument("--calibration", type=Path, required=True, help="calibration npz")
    parser.add_argument("--frames", type=Path, required=True, help="frames npz")
    parser.add_argument("--out", type=Path, required=True, help="output npz")
    add_max_touches_option(
        parser, "up to K touches per frame (needs a calibration made with --max-touches)"
    )


def load_located_frames(path: Path, protocol, m: int | None = None):
    """(reference [M], frames [T, M], references [T, M] | None, t [T] | None) of a frames file.

    Read in the layer's device conventions, as ``eit-skin reconstruct`` reads it
    (:meth:`~eit_skin.patch.protocol.Protocol.select`: ``layout: full`` frames keep the
    protocol's entries, complex frames their ``complex_part``); ``m``: the M a calibration
    expects (checked). Every problem raises ValueError naming the file and key.
    """
    import numpy as np

    from eit_skin.io.npz import FramesNpzReader

    reader = FramesNpzReader(path, convert=protocol.select)
    if m is not None and reader.n_measurements != m:
        raise ValueError(
            f"{path}: 'reference' has {reader.n_measurements} measurements, the calibration "
            f"expects {m}"
        )
    parts = list(reader.blocks_with_references())
    frames = np.concatenate([f for _, f, _, _ in parts])
    t = np.concatenate([b for _, _, b, _ in parts]) if reader.has_t else None
    references = np.concatenate([r for _, _, _, r in parts]) if reader.has_references else None
    for key, values in (("frames", frames), ("references", references)):
        if values is not None and not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
            raise ValueError(f"{path}: key '{key}' row {row}: not finite")
    return reader.reference, frames, references, t


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.calibration.localiser import PressLocaliser
    from eit_skin.io.npz import write_npz_atomic
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.protocol import build_protocol

    try:
        _, layer = chosen_layer(args)
        model = PressLocaliser.load(args.calibration, layer)
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        reference, frames, references, _ = load_located_frames(
            args.frames, protocol, model.n_measurements
        )
        if args.max_touches < 1:
            raise ValueError(f"--max-touches: {args.max_touches}, need >= 1")
        if args.max_touches > 1:
            out = several_touches(model, frames, reference, references, args.max_touches)
        else:
            located = model.locate(frames, reference, references)
            out = {"xy": located.xy, "confidence": located.confidence}
            if located.depth is not None:
                out["depth"] = located.depth
        write_npz_atomic(args.out, **out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        print(f"eit-skin locate: {error}", file=sys.stderr)
        return 2
    if args.max_touches > 1:
        counts = np.bincount(out["count"], minlength=args.max_touches + 1)[1:]
        print(f"  touches per frame 1..{args.max_touches}: {counts.tolist()}")
    print(
        f"wrote {args.out}: {len(frames)} frames, median confidence "
        f"{np.nanmedian(out['confidence']):.2f}"
    )
    return 0


def several_touches(model, frames, reference, references, k: int) -> dict:
    """``count`` [T], ``xy`` [T, k, 2], ``confidence`` and ``depth`` [T, k] (NaN padded)."""
    import numpy as np

    t = len(frames)
    out = {
        "count": np.zeros(t, dtype=np.int64),
        "xy": np.full((t, k, 2), np.nan),
        "confidence": np.full((t, k), np.nan),
        "depth": np.full((t, k), np.nan),
    }
    for i in range(t):  # one frame at a time, as online (the pair search is per frame)
        baseline = reference if references is None else references[i]
        touches = model.locate_touches(frames[i], baseline, k)
        n = len(touches.xy)
        out["count"][i] = n
        out["xy"][i, :n] = touches.xy
        out["confidence"][i, :n] = touches.confidence
        if touches.depth is not None:
            out["depth"][i, :n] = touches.depth
    if model.depth_model is None:
        del out["depth"]
    return out
