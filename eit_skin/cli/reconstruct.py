"""``eit-skin reconstruct``: offline frames file (npz) -> images (npz), the node's pipeline.

IN.npz: ``reference`` float [M] volts, ``frames`` float [T, M] volts (protocol order, NaN: a
missing value, as ``eit-skin frames export`` writes flagged channels), optional ``t`` [T] s,
optional ``references`` [T, M] volts (per-press references: frame ``k`` is imaged against
``references[k]``, as pyEIT's ``solve(v1, v0)`` and EIDORS' ``inv_solve(imdl, vh, vi)`` with
a reference per frame do; drift tracking is then off, ``--reference`` must be ``file`` and
the first ``--reference-frames`` references give the noise level). A device's own frames are
accepted as the patch's ``protocol`` names them: ``layout: full`` (every pair of every
injection, ``W = n_inj x n`` numbers; the used entries are picked), complex values (real part
or magnitude, ``complex_part``), magnitudes (``values: magnitude``: signs from the model).
OUT.npz: ``images`` float32 [T, H, W] relative conductivity change (delta sigma / sigma0,
positive = more conductive, NaN outside the sheet and in holes), ``physical`` float32
[T, H, W] in the layer's unit (Pa for pressure, strain for stretch) exactly as
``eit_reconstruction`` publishes it, ``imaged`` bool [T] (False: no image, all NaN), ``t`` [T]
the frame times used, s, ``x`` [W] and ``y`` [H] pixel-centre coordinates in metres (patch
frame). The file is read, imaged and written ``--block-frames`` frames at a time (memory does
not grow with T); the output goes to temporary files next to OUT and is renamed into place,
so it is either complete or absent. A frame without a usable channel (e.g. all NaN) is not
imaged (``imaged`` False, all-NaN images); how many were skipped and the first indices go to
stderr, exit status 0, and so do the values left out as no measurement of the sheet (beyond
the layer's ``full_scale_v``, or a one-frame jump of more than ``--jump-k`` times the
channel's noise: docs/faults.md), the first named by frame and channel. Errors: one line
on stderr, exit status 1, nothing written; an unusable reference (all zero, more than half
of the channels 0/NaN/Inf/near zero/of the wrong sign, in another unit than the frames) is
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
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.cli.errors import USER_ERRORS, report_error
from eit_skin.cli.options import add_patch_options, chosen_layer
from eit_skin.inverse.methods import METHODS

if TYPE_CHECKING:
    import numpy as np

    from eit_skin.io.npz import FramesNpzReader
    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.pipeline.processor import LayerImages, LayerProcessor

#: Frame rate assumed for a file without ``t`` when no ``--rate`` is given, Hz (the driver's).
FALLBACK_RATE_HZ = 50.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument("--frames", required=True, type=Path, metavar="IN.npz")
    parser.add_argument("--out", required=True, type=Path, metavar="OUT.npz")
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
    from eit_skin.io.npz import DEFAULT_BLOCK_FRAMES
    from eit_skin.pipeline.processor import (
        DEFAULT_CONTACT_K,
        DEFAULT_DRIFT_TIME_CONSTANT_S,
        DEFAULT_FAULT_CHECK_PERIOD_S,
        DEFAULT_JUMP_K,
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
        "--jump-k",
        type=float,
        default=DEFAULT_JUMP_K,
        metavar="K",
        help="a value that changed by more than K x its channel's noise in one frame is left "
        f"out; 0: no such check (default {DEFAULT_JUMP_K:g}; off for per-press references)",
    )
    group.add_argument(
        "--block-frames",
        type=int,
        default=DEFAULT_BLOCK_FRAMES,
        metavar="N",
        help="frames read, processed and written at a time: memory does not grow with the "
        f"file (default {DEFAULT_BLOCK_FRAMES})",
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
    except USER_ERRORS as exc:
        return report_error("reconstruct", exc)
    h, w = result.image_shape
    print(
        f"wrote {args.out}: {result.n_frames} images {h}x{w}, {result.n_imaged} imaged; "
        f"{result.summary}"
    )
    report_run("eit-skin reconstruct", args.frames, result.run)
    return 0


@dataclass
class OfflineImages:
    """What the offline pipeline wrote for one layer's file (see the module docstring)."""

    n_frames: int
    n_imaged: int
    image_shape: tuple[int, int]
    run: FileRun
    summary: str


@dataclass
class FileRun:
    """What a run over a file met: skipped frames, left-out values and electrodes.

    Skipped: frames without a usable channel after the reference was ready (``count``, the
    ``first`` indices); ``faulty``: electrodes the fault checks left out; ``out_of_range``,
    ``jumped``: values flagged beyond the full scale / as a one-frame jump, the first
    ``implausible`` named (frame, channel description, value V, why);
    ``fault_changes``: ``(frame, t s, electrodes)`` whenever the left-out set changed.
    """

    count: int = 0
    first: list[int] = field(default_factory=list)
    faulty: set[int] = field(default_factory=set)
    out_of_range: int = 0
    jumped: int = 0
    implausible: list[str] = field(default_factory=list)
    fault_changes: list[tuple[int, float, tuple[int, ...]]] = field(default_factory=list)

    #: Frame indices (and values) kept for the report.
    KEEP = 5

    def add(self, index: int) -> None:
        self.count += 1
        if len(self.first) < self.KEEP:
            self.first.append(index)

    def note_frame(
        self, index: int, t_s: float, frame: np.ndarray, processor: LayerProcessor
    ) -> None:
        """Note what ``processor`` did with frame ``index`` (``frame`` [M] V) at ``t_s``."""
        import numpy as np

        from eit_skin.frames import FLAG_JUMP, FLAG_OUT_OF_RANGE
        from eit_skin.inverse.channel_noise import describe_channel

        faulty = tuple(processor.faulty_electrodes.tolist())
        last = self.fault_changes[-1][2] if self.fault_changes else ()
        if faulty != last:
            self.fault_changes.append((index, float(t_s), faulty))
        self.faulty.update(faulty)
        flags = processor.last_flags
        if flags is None:
            return
        self.out_of_range += int(np.count_nonzero(flags & FLAG_OUT_OF_RANGE))
        self.jumped += int(np.count_nonzero(flags & FLAG_JUMP))
        for m in np.flatnonzero(flags)[: self.KEEP - len(self.implausible)]:
            why = "beyond the full scale" if flags[m] & FLAG_OUT_OF_RANGE else "a one-frame jump"
            where = describe_channel(processor.imager.protocol, int(m))
            self.implausible.append(f"frame {index} {where}: {frame[m]:.4g} V, {why}")


def report_run(command: str, path: Path, run: FileRun) -> None:
    """Stderr lines: frames of ``path`` skipped, and values left out (the first named)."""
    if run.count:
        more = ", ..." if run.count > len(run.first) else ""
        print(
            f"{command}: {path}: skipped {run.count} frame(s) without a usable channel "
            f"(frame {', '.join(map(str, run.first))}{more}): not imaged",
            file=sys.stderr,
        )
    n = run.out_of_range + run.jumped
    if n:
        more = "; ..." if n > len(run.implausible) else ""
        print(
            f"{command}: {path}: left out {n} value(s) no sheet can give "
            f"({run.out_of_range} beyond the board's full scale, {run.jumped} one-frame "
            f"jumps): {'; '.join(run.implausible)}{more}",
            file=sys.stderr,
        )


def _reconstruct(args: argparse.Namespace) -> OfflineImages:
    from eit_skin.pipeline.builder import LayerImager, with_method

    patch, layer = chosen_layer(args)
    # the chain the reconstruction node uses (cached by the layer's content), any method
    layer = layer if args.method is None else with_method(layer, args.method)
    imager = LayerImager.build(layer, cache_dir=cache_dir(args))
    if not args.frames.exists():
        raise ValueError(f"{args.frames}: no such file")
    reader = open_frames(imager, args.frames, args.block_frames)
    return run_offline(imager, reader, args.out, args, patch.name)


def open_frames(imager: LayerImager, path: Path, block_frames: int) -> FramesNpzReader:
    """A frames file read in the layer's device conventions (layout, complex, magnitude)."""
    from eit_skin.io.npz import FramesNpzReader

    return FramesNpzReader(path, block_frames=block_frames, convert=imager.protocol.select)


def cache_dir(args: argparse.Namespace) -> str | None:
    """``--cache-dir``: ``"default"``, a directory, or None for ``none``/empty."""
    return None if args.cache_dir in ("", "none") else args.cache_dir


def frame_times(
    t: np.ndarray | None,
    n_frames: int,
    rate_hz: float | None,
    fallback_hz: float,
    start: int = 0,
) -> np.ndarray:
    """Times ``[n_frames]`` s of frames ``start..``: ``k / rate_hz``, else ``t``, else fallback.

    ``t`` is the block's (frames ``start..``), the fallback ``k / fallback_hz``.

    Times that go backwards are kept (the node too just skips drift for such a frame).
    Raises ValueError for a rate that is not > 0.
    """
    import numpy as np

    if rate_hz is not None and not rate_hz > 0:
        raise ValueError(f"--rate: must be > 0 Hz, got {rate_hz:g}")
    if rate_hz is None and t is not None:
        return np.asarray(t, dtype=np.float64)
    return np.arange(start, start + n_frames) / float(rate_hz or fallback_hz)


def make_processor(
    imager: LayerImager, args: argparse.Namespace, patch_name: str, per_press: bool = False
) -> LayerProcessor:
    """The layer's processor with the pipeline options of ``args``, as the node makes it.

    ``patch_name``: the patch's name (the fault checks' phase); ``per_press``: the file has
    a reference per frame; no drift tracking.
    """
    from eit_skin.pipeline.processor import LayerProcessor, fault_check_phase

    if args.reference_frames < 0:
        raise ValueError(f"--reference-frames: must be >= 0, got {args.reference_frames}")
    if per_press and args.reference != "file":
        raise ValueError(
            f"--reference {args.reference}: the file has per-press 'references'; use "
            "--reference file (each frame is imaged against its own reference)"
        )
    return LayerProcessor(
        imager,
        args.reference_frames or None,
        0.0 if per_press else args.drift_time_constant,
        args.contact_k,
        fault_check_period_s=args.fault_check_period,
        fault_check_phase=fault_check_phase(patch_name, imager.layer.name),
        jump_k=0.0 if per_press else args.jump_k,  # per-press frames are no time series
    )


def process_file(
    processor: LayerProcessor,
    reader: FramesNpzReader,
    times: Callable[[int, np.ndarray, np.ndarray | None], np.ndarray],
    mode: str,
    run: FileRun,
) -> Iterator[tuple[np.ndarray, list[LayerImages | None]]]:
    """Run a processor over a file block by block: ``(times [B] s, per-frame results)``.

    ``times(start, frames, t)`` gives a block's frame times. ``mode`` ``"file"``: the
    file's reference is the reference at the first frame time, the first
    ``processor.reference_frames`` frames (those with any value) give the noise;
    ``"capture"``: it is not used. Frames without a usable channel once the reference is
    ready, the electrodes found faulty and the values left out are noted in ``run``.
    Raises ValueError (naming the file) for an unusable reference.

    Per-press ``references`` (``reader.has_references``; the processor made with
    ``per_press``): frame ``v_k`` with reference ``r_k`` is fed as the frame with the same
    relative change against the file's reference ``r``:
    ``r + (v_k - r_k) * s(r) / s(r_k)`` (``s``: :func:`~eit_skin.inverse.one_step.reference_scale`),
    so every later step (flags, faults, units) is the node's.
    """
    import numpy as np

    from eit_skin.inverse.one_step import reference_scale

    for start, frames, t_file, refs in reader.blocks_with_references():
        block_times = times(start, frames, t_file)
        if start == 0 and mode == "file":
            if refs is None:
                noise = reader.head(processor.reference_frames)
            else:
                noise = refs[: processor.reference_frames]
            noise = noise[np.isfinite(noise).any(axis=1)]  # an all-NaN frame has no noise
            processor.set_reference(reader.reference, block_times[0], noise)
        if processor.reference_error is not None:
            raise ValueError(f"{reader.path}: {processor.reference_error}")
        if refs is not None:
            base = reader.reference
            with np.errstate(invalid="ignore", divide="ignore"):
                frames = base + (frames - refs) * (reference_scale(base) / reference_scale(refs))
        results = []
        for k, (frame, t) in enumerate(zip(frames, block_times, strict=True)):
            unusable = processor.frames_unusable
            results.append(processor.step(frame, t))
            run.note_frame(start + k, t, frame, processor)
            if processor.frames_unusable > unusable:
                run.add(start + k)
        if processor.reference_error is not None:  # a captured reference
            raise ValueError(f"{reader.path}: {processor.reference_error}")
        yield block_times, results


def run_offline(
    imager: LayerImager,
    reader: FramesNpzReader,
    out: Path,
    args: argparse.Namespace,
    patch_name: str,
) -> OfflineImages:
    """The node's per-frame pipeline over one file, written block by block to ``out``.

    ``out`` gets relative and physical images ``[T, H, W]`` (see the module docstring).
    """
    import numpy as np

    from eit_skin.io.npz import NpzStreamWriter

    processor = make_processor(imager, args, patch_name, reader.has_references)
    shape = (reader.n_frames, *imager.grid.shape)
    arrays = {
        "images": (shape, np.float32),
        "physical": (shape, np.float32),
        "imaged": (shape[:1], np.bool_),
        "t": (shape[:1], np.float64),
        "x": (imager.grid.x.shape, imager.grid.x.dtype),
        "y": (imager.grid.y.shape, imager.grid.y.dtype),
    }
    run = FileRun()
    n_imaged = 0

    def times(start: int, frames: np.ndarray, t: np.ndarray | None) -> np.ndarray:
        return frame_times(t, len(frames), args.rate, FALLBACK_RATE_HZ, start)

    with NpzStreamWriter(out, arrays) as writer:
        writer.append(x=imager.grid.x, y=imager.grid.y)
        for block_times, results in process_file(processor, reader, times, args.reference, run):
            imaged = np.array([r is not None for r in results], dtype=bool)
            physical = np.full((len(results), *shape[1:]), np.nan, dtype=np.float32)
            images = np.full_like(physical, np.nan)
            if imaged.any():
                done = [r for r in results if r is not None]
                physical[imaged] = np.stack([r.image for r in done])
                images[imaged] = imager.images(np.stack([r.values for r in done]))
            writer.append(images=images, physical=physical, imaged=imaged, t=block_times)
            n_imaged += int(imaged.sum())
    if reader.has_references:
        n = min(processor.reference_frames, reader.n_frames)
        how = f"a reference per frame from the file, noise from the first {n} references"
    elif args.reference == "file":
        n = min(processor.reference_frames, reader.n_frames)
        how = f"reference from the file, noise from the first {n} frames"
    else:
        how = f"reference captured from the first {processor.reference_frames} frames"
    tau = processor.tracker.drift_time_constant_s
    drift = f"drift tracking {tau:g} s: {processor.drift_updates} updates" if tau else "no drift"
    note = f"; left out electrodes {sorted(run.faulty)}" if run.faulty else ""
    if processor.reference_report is not None:
        note += "; " + "; ".join(processor.reference_report.lines())
    return OfflineImages(reader.n_frames, n_imaged, imager.grid.shape, run, f"{how}; {drift}{note}")
