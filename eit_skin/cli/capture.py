"""``eit-skin capture``: record a board's frames to the offline frames format, without ROS.

For calibration sessions and bug reports: the layer's board profile reads the port exactly as
the driver node does (:class:`~eit_skin.hardware.sources.SerialSource`: host commands,
refusals, reconnects, stamps), and the frames go to an npz that ``reconstruct``, ``classify``,
``tune --frames`` and ``fit-device`` read: ``reference`` (the mean of the first
``--reference-seconds`` of frames), ``frames`` [T, M] volts in protocol order, ``t`` [T]
seconds since the first frame (the frames' acquisition stamps), ``reference_frames`` (the
frames averaged into the reference). Nothing is written when no frame came.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import warnings

from eit_skin.cli.options import add_board_link_options, add_patch_options, chosen_layer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument("--port", required=True, help="serial device of the board")
    add_board_link_options(parser)
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="how long to record, after the first frame"
    )
    parser.add_argument(
        "--reference-seconds",
        type=float,
        default=1.0,
        help="the first S seconds of frames are averaged into the reference (default 1)",
    )
    parser.add_argument("--out", required=True, metavar="FRAMES.npz", help="output file")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.hardware.sources import LayerFrameFactory, board_source
    from eit_skin.io.npz import write_npz_atomic
    from eit_skin.patch.model import PatchError

    for name in ("seconds", "reference_seconds", "wait"):
        if not getattr(args, name) > 0:
            print(f"eit-skin capture: --{name.replace('_', '-')} must be > 0", file=sys.stderr)
            return 2
    try:
        patch, layer = chosen_layer(args)
    except (PatchError, KeyError, FileNotFoundError) as error:
        print(f"eit-skin capture: {error}", file=sys.stderr)
        return 2
    records = []
    done = threading.Event()
    lock = threading.Lock()

    def sink(record) -> None:
        with lock:
            records.append(record)
            if (record.stamp_ns - records[0].stamp_ns) * 1e-9 >= args.seconds:
                done.set()

    source = board_source(
        LayerFrameFactory(patch, layer, patch.frame_id), args.port, args.baud, sink
    )
    print(
        f"capturing {layer.name!r} of {patch.name!r} from {args.port} "
        f"(profile {layer.device.profile}, {args.baud or layer.device.baud} bit/s)",
        file=sys.stderr,
        flush=True,
    )
    source.start()
    started = time.monotonic()
    try:
        while not done.wait(0.2):
            with lock:
                empty = not records
            if empty and time.monotonic() - started > args.wait:
                break
    except KeyboardInterrupt:
        pass
    finally:
        source.stop()
    status = source.status()
    with lock:
        kept = list(records)
    if not kept:
        print(
            f"eit-skin capture: no frame from {args.port} within {args.wait:g} s: "
            f"{status.message}; nothing written",
            file=sys.stderr,
        )
        return 1
    frames = np.stack([r.voltages for r in kept]).astype(np.float64)
    for row, record in zip(frames, kept, strict=True):
        if np.size(record.channel_flags) == row.size:  # flagged: missing in the offline format
            row[np.asarray(record.channel_flags) != 0] = np.nan
    t = np.array([(r.stamp_ns - kept[0].stamp_ns) * 1e-9 for r in kept])
    first = frames[t < args.reference_seconds]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a channel missing in every frame
        reference = np.nanmean(first, axis=0)
    write_npz_atomic(args.out, reference=reference, frames=frames, t=t, reference_frames=first)
    refused = ", ".join(f"{k} {v}" for k, v in source.rejected.items() if v) or "none"
    print(
        f"wrote {args.out}: {len(kept)} frames x {frames.shape[1]} values over {t[-1]:.2f} s "
        f"({len(first)} in the reference); refused frames: {refused}",
        file=sys.stderr,
    )
    return 0
