"""``eit-skin reconstruct``: offline frames file (npz) -> images (npz), the node's pipeline.

IN.npz: ``reference`` float [M] volts, ``frames`` float [T, M] volts (protocol order, NaN: a
missing value, as ``eit-skin frames export`` writes flagged channels), optional ``t`` [T] s.
OUT.npz: ``images`` float32 [T, H, W] relative conductivity change (delta sigma / sigma0,
positive = more conductive, NaN outside the sheet and in holes), ``physical`` float32
[T, H, W] in the layer's unit (Pa for pressure, strain for stretch) exactly as
``eit_reconstruction`` publishes it, ``imaged`` bool [T] (False: no image, all NaN), ``t`` [T]
the frame times used, s, ``x`` [W] and ``y`` [H] pixel-centre coordinates in metres (patch
frame). The output is written to a temporary file next to OUT and renamed, so it is either
complete or absent. Errors: one line on stderr, exit status 1, nothing written; an unusable
reference (all zero, more than half of the channels 0/NaN/Inf/near zero/of the wrong sign) is
such an error, single bad reference channels are left out and named in the summary.

Every frame goes through :class:`~eit_skin.pipeline.processor.LayerProcessor`, the code the
reconstruction node runs per frame: drift tracking, flag/NaN handling and fault checks on frame
time. Frame times: ``--rate`` when given, else the file's ``t``, else 50 Hz (the driver's).
The reference (``--reference``):

* ``file`` (default): the file's ``reference`` is the no-load reference at the first frame;
  every frame is imaged; the first ``--reference-frames`` frames (which, as for the node,
  must be untouched) give the noise level that tells drift from touch.
* ``capture``: as the node does after start: the first ``--reference-frames`` frames are
  averaged into the reference and not imaged; the file's ``reference`` is not used. Frames
  recorded from the node's input (``eit-skin frames export``) then give bit-identical
  ``physical`` images to those the node published, with the node's settings
  (``reference_frames``, ``drift_time_constant_s``, ``contact_k``, ``fault_check_period_s``)
  and the same matrix cache.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.inverse.methods import METHODS

if TYPE_CHECKING:
    import numpy as np

    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.pipeline.processor import LayerImages, LayerProcessor

#: Frame rate assumed for a file without ``t`` when no ``--rate`` is given, Hz (the driver's).
FALLBACK_RATE_HZ = 50.0


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
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="HZ",
        help=f"frame rate: frame k at k / HZ s (default: the file's t, else {FALLBACK_RATE_HZ:g})",
    )
    add_pipeline_arguments(parser)


def add_pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    """The reference, drift and fault options of the offline commands (node defaults)."""
    from eit_skin.pipeline.processor import (
        DEFAULT_CONTACT_K,
        DEFAULT_DRIFT_TIME_CONSTANT_S,
        DEFAULT_FAULT_CHECK_PERIOD_S,
    )

    group = parser.add_argument_group("per-frame pipeline (as eit_reconstruction)")
    group.add_argument(
        "--reference",
        choices=("file", "capture"),
        default="file",
        help="file: the file's reference, every frame imaged; capture: averaged from the "
        "first --reference-frames frames like the node, which are not imaged (default: file)",
    )
    group.add_argument(
        "--reference-frames",
        type=int,
        default=0,
        metavar="N",
        help="frames captured (capture) or giving the noise level (file); "
        "0: the layer's solver.reference_frames",
    )
    group.add_argument(
        "--drift-time-constant",
        type=float,
        default=DEFAULT_DRIFT_TIME_CONSTANT_S,
        metavar="S",
        help="drift tracking time constant while untouched, s; 0: off "
        f"(default {DEFAULT_DRIFT_TIME_CONSTANT_S:g})",
    )
    group.add_argument(
        "--contact-k",
        type=float,
        default=DEFAULT_CONTACT_K,
        metavar="K",
        help=f"a change above K x noise is a contact: no drift (default {DEFAULT_CONTACT_K:g})",
    )
    group.add_argument(
        "--fault-check-period",
        type=float,
        default=DEFAULT_FAULT_CHECK_PERIOD_S,
        metavar="S",
        help="frame time between faulty-electrode checks, s; 0: never "
        f"(default {DEFAULT_FAULT_CHECK_PERIOD_S:g})",
    )
    group.add_argument(
        "--cache-dir",
        default="default",
        help="reconstruction matrix cache; 'none': no cache "
        "(default: $EIT_SKIN_CACHE or ~/.cache/eit_skin)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        result = _reconstruct(args)
        from eit_skin.io.npz import write_npz_atomic

        write_npz_atomic(
            args.out,
            images=result.images,
            physical=result.physical,
            imaged=result.imaged,
            t=result.t,
            x=result.x,
            y=result.y,
        )
    except (ValueError, KeyError, OSError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"eit-skin reconstruct: error: {message}", file=sys.stderr)
        return 1
    t, h, w = result.images.shape
    print(
        f"wrote {args.out}: {t} images {h}x{w}, {int(result.imaged.sum())} imaged; {result.summary}"
    )
    return 0


@dataclass
class OfflineImages:
    """What the offline pipeline gives for one layer's file (see the module docstring)."""

    images: np.ndarray
    physical: np.ndarray
    imaged: np.ndarray
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    summary: str


def _reconstruct(args: argparse.Namespace) -> OfflineImages:
    from eit_skin.io.npz import load_frames_npz
    from eit_skin.patch.loading import load_patch
    from eit_skin.pipeline.builder import LayerImager, with_method
    from eit_skin.resources import config_path

    patch = load_patch(config_path(args.patch))
    layer = patch.layers[0] if args.layer is None else patch.layer(args.layer)
    # the chain the reconstruction node uses (cached by the layer's content), any method
    layer = layer if args.method is None else with_method(layer, args.method)
    imager = LayerImager.build(layer, cache_dir=cache_dir(args))
    if not args.frames.exists():
        raise ValueError(f"{args.frames}: no such file")
    reference, frames, t = load_frames_npz(args.frames, imager.n_measurements)
    times = frame_times(t, frames.shape[0], args.rate, FALLBACK_RATE_HZ)
    return run_offline(imager, reference, frames, times, args)


def cache_dir(args: argparse.Namespace) -> str | None:
    """``--cache-dir``: ``"default"``, a directory, or None for ``none``/empty."""
    return None if args.cache_dir in ("", "none") else args.cache_dir


def frame_times(
    t: np.ndarray | None, n_frames: int, rate_hz: float | None, fallback_hz: float
) -> np.ndarray:
    """Frame times ``[T]`` s: ``k / rate_hz`` if given, else ``t``, else ``k / fallback_hz``.

    Times that go backwards are kept (the node too just skips drift for such a frame).
    Raises ValueError for a rate that is not > 0.
    """
    import numpy as np

    if rate_hz is not None and not rate_hz > 0:
        raise ValueError(f"--rate: must be > 0 Hz, got {rate_hz:g}")
    if rate_hz is None and t is not None:
        return np.asarray(t, dtype=np.float64)
    return np.arange(n_frames) / float(rate_hz or fallback_hz)


def make_processor(imager: LayerImager, args: argparse.Namespace) -> LayerProcessor:
    """The layer's processor with the pipeline options of ``args``."""
    from eit_skin.pipeline.processor import LayerProcessor

    if args.reference_frames < 0:
        raise ValueError(f"--reference-frames: must be >= 0, got {args.reference_frames}")
    return LayerProcessor(
        imager,
        args.reference_frames or None,
        args.drift_time_constant,
        args.contact_k,
        fault_check_period_s=args.fault_check_period,
    )


def process_file(
    processor: LayerProcessor,
    reference: np.ndarray,
    frames: np.ndarray,
    times: np.ndarray,
    mode: str,
) -> tuple[list[LayerImages | None], set[int]]:
    """Run a processor over a file's frames: per-frame results, electrodes found faulty.

    ``mode`` ``"file"``: ``reference`` is the reference at ``times[0]``, the first
    ``processor.reference_frames`` frames give the noise; ``"capture"``: it is not used.
    """
    if mode == "file":
        processor.set_reference(reference, times[0], frames[: processor.reference_frames])
    faulty: set[int] = set()
    results = []
    for frame, t in zip(frames, times, strict=True):
        results.append(processor.step(frame, t))
        faulty.update(processor.faulty_electrodes.tolist())
    return results, faulty


def run_offline(
    imager: LayerImager,
    reference: np.ndarray,
    frames: np.ndarray,
    times: np.ndarray,
    args: argparse.Namespace,
) -> OfflineImages:
    """The node's per-frame pipeline over one file: relative and physical images ``[T, H, W]``."""
    import numpy as np

    processor = make_processor(imager, args)
    results, faulty = process_file(processor, reference, frames, times, args.reference)
    if processor.reference_error is not None:
        raise ValueError(f"{args.frames}: {processor.reference_error}")
    imaged = np.array([r is not None for r in results], dtype=bool)
    shape = (len(results), *imager.grid.shape)
    physical = np.full(shape, np.nan, dtype=np.float32)
    images = np.full(shape, np.nan, dtype=np.float32)
    if imaged.any():
        done = [r for r in results if r is not None]
        physical[imaged] = np.stack([r.image for r in done])
        images[imaged] = imager.images(np.stack([r.values for r in done]))
    if args.reference == "file":
        n = min(processor.reference_frames, len(results))
        how = f"reference from the file, noise from the first {n} frames"
    else:
        how = f"reference captured from the first {processor.reference_frames} frames"
    tau = processor.tracker.drift_time_constant_s
    drift = f"drift tracking {tau:g} s: {processor.drift_updates} updates" if tau else "no drift"
    note = f"; left out electrodes {sorted(faulty)}" if faulty else ""
    if processor.reference_report is not None:
        note += "; " + "; ".join(processor.reference_report.lines())
    return OfflineImages(
        images, physical, imaged, times, imager.grid.x, imager.grid.y, f"{how}; {drift}{note}"
    )
