"""``eit-skin classify``: detect and label touches in an offline frames file; JSON lines.

Reads the pressure layer's frames (the patch's first layer measuring pressure, chosen like
the node does: :func:`~eit_skin.touch.classifier.classifier_layers`; ``eit-skin reconstruct``
input format: ``reference`` [M] V, ``frames`` [T, M] V, optional ``t`` [T] s), images them with the
reconstruction node's per-frame pipeline (:class:`~eit_skin.pipeline.processor.LayerProcessor`:
reference, drift tracking, fault checks; the same options as ``eit-skin reconstruct``), runs
:class:`~eit_skin.touch.classifier.TouchClassifier` on the images and prints one JSON object
per FINISHED touch: ``label``, ``t_start``, ``t_end`` (s from the first frame),
``confidence``, ``centroid`` ([x, y] m, patch frame), ``position`` and ``normal`` (the
centroid on the patch's placed surface and its outward normal, patch frame). The electrodes
the pipeline's fault checks leave out go to the classifier with every image
(:meth:`~eit_skin.touch.classifier.TouchClassifier.set_faulty_electrodes`), and so does
each imaged frame itself (its raw channels tell a close pinch from a push). Frame times:
``--rate`` when given, else the file's ``t``. The first ``calibration_s`` (0.5 s) of images
must be free of touch: they give the noise level; a file too short for it is an error.
Errors: one line on stderr, exit status 1.

Faults are reported, never silent. Whenever the electrodes left out change, a JSON line
``{"kind": "fault", "t": s, "faulty_electrodes": [...]}`` (and a line on stderr); every
touch line says whether it overlapped a fault: ``fault`` (bool: an electrode or a value was
left out in one of its frames), ``faulty_electrodes`` (those left out meanwhile) and
``channels_left_out`` (the most channels left out of one of its frames, of M). The values
left out as no measurement of the sheet (beyond the full scale, one-frame jumps) and the
frames skipped are named on stderr at the end, as ``eit-skin reconstruct`` does.

A changed sheet is no touch: a "touch" the classifier withdraws (it went on for longer than
``sheet_change_taus`` baseline time constants: docs/classifier.md, "Changed sheet") gives
no touch line but ``{"kind": "sheet_changed", "t": s, "reason": ...}`` (and the reason on
stderr).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.cli.errors import USER_ERRORS, report_error

if TYPE_CHECKING:
    from eit_skin.cli.reconstruct import FileRun
    from eit_skin.patch.placement import Placement

from eit_skin.cli.options import add_patch_options
from eit_skin.cli.reconstruct import add_pipeline_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser, layer=False)
    parser.add_argument(
        "--frames",
        required=True,
        type=Path,
        metavar="IN.npz",
        help="frames of the patch's (first) pressure layer, eit-skin reconstruct format",
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="HZ",
        help="frame rate: frame k at k / HZ s (default: the file's t)",
    )
    parser.add_argument(
        "--stretch-frames",
        type=Path,
        default=None,
        metavar="IN2.npz",
        help="frames of the patch's (first) stretch layer (same format, same T); optional, "
        "sharpens rub/pinch on patches that have a stretch layer",
    )
    add_pipeline_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from eit_skin.cli.reconstruct import report_run

    runs: dict[Path, FileRun] = {}
    try:
        for line in classify_file(args, runs):
            if line.get("kind") == "fault":
                left_out = line["faulty_electrodes"] or "none any more"
                print(
                    f"eit-skin classify: {args.frames}: t = {line['t']:g} s: faulty electrodes "
                    f"left out: {left_out}",
                    file=sys.stderr,
                )
            if line.get("kind") == "sheet_changed":
                print(
                    f"eit-skin classify: {args.frames}: t = {line['t']:g} s: {line['reason']}",
                    file=sys.stderr,
                )
            print(json.dumps(line), flush=True)
    except USER_ERRORS as exc:
        return report_error("classify", exc)
    for path, file_run in runs.items():
        report_run("eit-skin classify", path, file_run)
    return 0


class FaultSpans:
    """When faults were on (times s), to mark the touches that overlapped one.

    One span per run of consecutive frames with a fault (an electrode or a value left
    out): ``[t_first, t_last, electrodes, most channels left out]``.
    """

    def __init__(self) -> None:
        self.spans: list[list] = []
        self._open = False

    def add(self, t_s: float, electrodes: tuple[int, ...], left_out: int) -> None:
        """One imaged frame at ``t_s`` with its left-out electrodes and channel count."""
        if not electrodes and not left_out:
            self._open = False
            return
        if not self._open:
            self.spans.append([t_s, t_s, set(), 0])
            self._open = True
        span = self.spans[-1]
        span[1] = t_s
        span[2].update(electrodes)
        span[3] = max(span[3], left_out)

    def during(self, t_start_s: float, t_end_s: float) -> dict:
        """The fault fields of a touch from ``t_start_s`` to ``t_end_s``."""
        electrodes: set[int] = set()
        left_out = 0
        for first, last, names, most in self.spans:
            if first <= t_end_s and last >= t_start_s:
                electrodes |= names
                left_out = max(left_out, most)
        return {
            "fault": bool(electrodes or left_out),
            "faulty_electrodes": sorted(electrodes),
            "channels_left_out": left_out,
        }


def classify_file(args: argparse.Namespace, runs: dict[Path, FileRun] | None = None):
    """JSON-ready lines: finished touches (END) and fault changes, read block by block.

    ``runs`` (if given) receives, per file, the frames skipped and values and electrodes
    left out. Raises ValueError for a file too short for the classifier's calibration.
    """
    from eit_skin.patch.loading import load_patch
    from eit_skin.resources import config_path

    patch = load_patch(args.patch if Path(args.patch).exists() else config_path(args.patch))
    faults = FaultSpans()
    faulty: tuple[int, ...] = ()
    for t_rel, images, events in classified_frames(args, patch, runs):
        if images is not None:
            if images.faulty_electrodes != faulty:
                faulty = images.faulty_electrodes
                yield {"kind": "fault", "t": round(t_rel, 4), "faulty_electrodes": list(faulty)}
            faults.add(t_rel, faulty, images.frame_v.size - images.channels_used)
        for event in events:
            if event.state == "end" and event.withdrawn:  # no touch: the sheet changed
                yield {"kind": "sheet_changed", "t": round(event.t_s, 4), "reason": event.withdrawn}
            elif event.state == "end":
                yield _touch_line(event, faults, patch.placement)


def classified_frames(args: argparse.Namespace, patch, runs: dict[Path, FileRun] | None = None):
    """``(t s from the first imaged frame, LayerImages, touch events)`` per imaged frame.

    The pressure layer's frames of ``args.frames`` (and ``args.stretch_frames``) imaged and
    classified; last, ``(t, None, events)`` with the END of a touch still going on. Raises
    ValueError for a file too short for the classifier's calibration.
    """
    from eit_skin.cli.reconstruct import cache_dir
    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.touch.classifier import classifier_layers

    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"--rate: must be > 0 Hz, got {args.rate:g}")
    runs = {} if runs is None else runs
    pressure_layer, stretch_layer = classifier_layers(patch)
    cache = cache_dir(args)
    imager = LayerImager.build(pressure_layer, cache_dir=cache)
    reader = _reader(imager, args.frames, args)
    stretch = None
    if args.stretch_frames is not None:
        if stretch_layer is None:
            names = [ly.name for ly in patch.layers]
            raise ValueError(
                f"--stretch-frames: patch {patch.name!r} has no layer measuring stretch ({names})"
            )
        stretch_imager = LayerImager.build(stretch_layer, cache_dir=cache)
        stretch_reader = _reader(stretch_imager, args.stretch_frames, args)
        if stretch_reader.n_frames != reader.n_frames:
            raise ValueError(
                f"{args.stretch_frames}: {stretch_reader.n_frames} frames, but {args.frames} has "
                f"{reader.n_frames}"
            )
        stretch = _images(stretch_imager, stretch_reader, args, runs, patch.name)
    classifier = build_classifier(pressure_layer, imager)
    t0 = None
    t_rel = 0.0
    n_imaged = 0
    for times, pressure in _images(imager, reader, args, runs, patch.name):
        extras = [None] * len(times) if stretch is None else next(stretch)[1]
        t0 = times[0] if t0 is None else t0
        for t, images, extra in zip(times, pressure, extras, strict=True):
            if images is None:  # reference capture (--reference capture) or no usable channel
                continue
            n_imaged += 1
            t_rel = float(t - t0)
            image = None if extra is None else extra.image
            # the electrodes the imaging left out: less confidence near them
            classifier.set_faulty_electrodes(images.faulty_electrodes)
            yield t_rel, images, classifier.step(t_rel, images.image, image, images.frame_v)
    if not classifier.calibrated and classifier.sheet_changed is None:
        raise ValueError(
            f"{args.frames}: {n_imaged} imaged frame(s) do not cover the classifier's "
            f"calibration ({classifier.config.calibration_s:g} s of untouched frames): "
            "nothing classified"
        )
    yield t_rel, None, classifier.finish()


def build_classifier(layer, imager):
    """The touch classifier of a pressure ``layer`` imaged by ``imager``, as the node builds it.

    With one fingertip's blur at every pixel and the raw frames' START filter.
    """
    import numpy as np

    from eit_skin.touch.classifier import TouchClassifier
    from eit_skin.touch.frame_evidence import channel_electrodes
    from eit_skin.touch.shapes import raw_patterns, single_contact_spread

    spread = single_contact_spread(imager)
    disc, contact = raw_patterns(layer, imager)
    electrodes = np.array([e.center for e in layer.electrodes], dtype=np.float64)
    return TouchClassifier(
        imager.grid.x,
        imager.grid.y,
        contact_spread_m=spread,
        electrodes_m=electrodes,
        channel_electrodes=channel_electrodes(imager.protocol),
        disc_rel=disc,
        contact_rel=contact,
    )


def _touch_line(event, faults: FaultSpans, placement: Placement) -> dict:
    """A finished touch's JSON line: its fields, its surface point and its faults.

    ``position`` (m) and ``normal``: the centroid on the placed surface, patch frame, as in
    ``TouchEvent``; the faults it overlapped: :meth:`FaultSpans.during`.
    """
    xy = [event.centroid_m]
    surface = {
        "position": [round(float(v), 5) for v in placement.to_3d(xy)[0]],
        "normal": [round(float(v), 5) for v in placement.normals(xy)[0]],
    }
    return {**event.to_dict(), **surface, **faults.during(event.t_start_s, event.t_end_s)}


def _reader(imager, path: Path, args: argparse.Namespace):
    """The block reader of one layer's frames file, checked against the layer and ``--rate``."""
    from eit_skin.cli.reconstruct import open_frames

    if not Path(path).is_file():
        raise ValueError(f"{path}: no such file")
    reader = open_frames(imager, Path(path), args.block_frames)
    if not reader.has_t and args.rate is None:
        raise ValueError(f"{path}: no 't' (frame times) in the file: give --rate")
    return reader


def _images(imager, reader, args: argparse.Namespace, runs: dict, patch_name: str):
    """``(times [B] s, per-frame results)`` per block of one layer's frames file."""
    from eit_skin.cli.reconstruct import FileRun, frame_times, make_processor, process_file

    def times(start, frames, t):
        return frame_times(t, len(frames), args.rate, 0.0, start)

    run = runs.setdefault(reader.path, FileRun())
    processor = make_processor(imager, args, patch_name, reader.has_references)
    return process_file(processor, reader, times, args.reference, run)
