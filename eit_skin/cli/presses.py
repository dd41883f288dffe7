"""``eit-skin presses``: make a press session file (the input of ``eit-skin calibrate``).

``record --frames REC.npz --probe PROBE.csv --out S.npz``: pair a frame recording that has
times ``t`` (``eit-skin frames export`` of the driver's MCAP gives header stamps; a device's
own frames are read in the patch's conventions, e.g. ``layout: full``, as ``reconstruct`` reads
them) with the robot's probe log, one CSV row per press at full depth: ``time_s, x_m,
y_m[, depth_m]`` in the patch frame, on the same clock. ``--baseline-offset S``: each press's own
baseline is the frame ``S`` seconds before it (probe lifted). ``--patch`` checks M and that
every press lies on the sheet before anything is written.

``simulate --patch P --count N --out S.npz``: N random presses simulated on the patch.

``guide --patch P (--frames F.npz | --port PORT) --targets N --out S.npz``: calibration by
hand. Writes the printable 1:1 template (``--template``, default ``S.svg`` and ``S.pdf``
beside the session: sheet, electrodes, N numbered targets, 10 mm scale bar), then prompts
for each target in turn, finds each press and release in the patch's pressure-layer frames
(the touch classifier's START/END, as ``eit-skin classify``), refuses a press too short, too
weak or on two targets with the reason (the next press redoes the target) and asks after
each accepted one: ``ok`` or ``redo`` (``--answers FILE``: one answer a line; default all
``ok``; live, ``--port``: Enter or ``r`` at the terminal). The session is written only when
every target has its press. docs/press-calibration.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.cli.options import add_board_link_options, add_patch_options, chosen_layer

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np

    from eit_skin.calibration.guide import DetectedPress, GuidedSession, GuideRules
    from eit_skin.patch.model import Layer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="mode", required=True, metavar="record|simulate|guide")
    record = sub.add_parser("record", help="pair a frame recording with a probe CSV")
    record.add_argument("--frames", type=Path, required=True, help="frames npz with 't'")
    record.add_argument("--probe", type=Path, required=True, help="CSV: time, x, y[, depth]")
    record.add_argument("--baseline-offset", type=float, default=None, help="seconds")
    simulate = sub.add_parser("simulate", help="simulate random presses on a patch")
    simulate.add_argument("--count", type=int, default=400, help="presses")
    simulate.add_argument("--seed", type=int, default=0, help="seed")
    simulate.add_argument("--no-drift", action="store_true", help="no sigma0 drift")
    for p in (record, simulate):
        add_patch_options(p)
        p.add_argument("--out", type=Path, required=True, help="press session npz to write")
    add_guide_arguments(sub.add_parser("guide", help="calibrate by hand on a printed template"))


def run(args: argparse.Namespace) -> int:
    if args.mode == "guide":
        return run_guide(args)
    from eit_skin.calibration.session import pair_probe_csv
    from eit_skin.cli.locate import load_located_frames
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.protocol import build_protocol

    try:
        patch, layer = chosen_layer(args)
        if args.mode == "record":
            protocol = build_protocol(layer.protocol, layer.n_electrodes)
            reference, frames, _, t = load_located_frames(args.frames, protocol)
            if t is None:
                raise ValueError(f"{args.frames}: missing key 't' (frame times to pair with)")
            session = pair_probe_csv(
                reference, frames, t, args.probe, args.baseline_offset, str(args.frames)
            )
        else:
            from eit_skin.sim.press_session import PressDraw, simulate_press_session

            draw = PressDraw(drift=not args.no_drift)
            session = simulate_press_session(patch, args.count, layer.name, args.seed, draw)
        session.check_layer(layer)
        session.save(args.out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        print(f"eit-skin presses {args.mode}: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {session.n_presses} presses, M = {session.n_measurements}")
    return 0


def add_guide_arguments(guide: argparse.ArgumentParser) -> None:
    """The options of ``presses guide`` (the press rules' defaults are :class:`GuideRules`'s)."""
    from eit_skin.calibration.guide import GuideRules
    from eit_skin.cli.reconstruct import add_pipeline_arguments

    add_patch_options(guide, layer=False)
    source = guide.add_mutually_exclusive_group(required=True)
    source.add_argument("--frames", type=Path, help="recording of the session (frames npz)")
    source.add_argument("--port", help="serial device of the board (live session)")
    add_board_link_options(guide)
    guide.add_argument("--targets", type=int, default=25, help="targets to press (default 25)")
    guide.add_argument("--out", type=Path, required=True, help="press session npz to write")
    guide.add_argument(
        "--template",
        type=Path,
        default=None,
        help="template to write (.svg or .pdf; default: the session's name with .svg and .pdf)",
    )
    guide.add_argument(
        "--margin",
        type=float,
        default=None,
        metavar="MM",
        help="targets this far inside the outline, holes and electrodes (default: a finger's "
        "width, 12 mm)",
    )
    guide.add_argument(
        "--answers", type=Path, default=None, help="file: ok|redo per accepted press"
    )
    guide.add_argument(
        "--rate", type=float, default=None, metavar="HZ", help="frame rate (default: the file's t)"
    )
    rules = GuideRules()  # the defaults live in one place: the rules' own
    guide.add_argument(
        "--min-hold", type=float, default=rules.min_hold_s, metavar="S", help="shortest press"
    )
    guide.add_argument(
        "--min-snr", type=float, default=rules.min_snr, help="weakest press, x the frames' noise"
    )
    guide.add_argument(
        "--min-relative",
        type=float,
        default=rules.min_relative,
        help="weakest press, x the median accepted press",
    )
    guide.add_argument(
        "--max-offset",
        type=float,
        default=None,
        metavar="MM",
        help="refuse a press the image places farther than this from its target and nearer "
        "another (default: the targets' median spacing; 0: off, for images that do not localise)",
    )
    add_pipeline_arguments(guide)


def read_answers(path: Path) -> list[str]:
    """The scripted replies of a guided session: ``ok`` or ``redo``, one a line (``#``: note)."""
    from eit_skin.calibration.guide import ANSWERS

    out = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        word = line.split("#", 1)[0].strip().lower()
        if not word:
            continue
        if word not in ANSWERS:
            raise ValueError(f"{path}: line {line_no}: {word!r}: want one of {', '.join(ANSWERS)}")
        out.append(word)
    return out


def run_guide(args: argparse.Namespace) -> int:
    """``presses guide``: template, prompts, presses judged and paired, session written."""
    from eit_skin.calibration.guide import GuidedSession, PressDetector
    from eit_skin.calibration.session import MIN_PRESSES
    from eit_skin.calibration.template import FINGER_WIDTH_M, spread_targets
    from eit_skin.cli.classify import classified_frames
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.resources import config_path
    from eit_skin.touch.classifier import classifier_layers

    def fail(message) -> int:
        print(f"eit-skin presses guide: {message}", file=sys.stderr)
        return 2

    if args.template is not None and args.template.suffix.lower() not in (".svg", ".pdf"):
        return fail(f"--template {args.template}: want a .svg or .pdf file name")
    if args.targets < MIN_PRESSES:
        return fail(f"--targets: {args.targets}, calibrate needs at least {MIN_PRESSES}")
    try:
        patch = load_patch(config_path(args.patch))
        layer = classifier_layers(patch)[0]
        margin = FINGER_WIDTH_M if args.margin is None else args.margin * 1e-3
        targets = spread_targets(layer, args.targets, margin)
        rules = _guide_rules(args, targets)
        answers = read_answers(args.answers) if args.answers is not None else []
        answers.reverse()  # popped from the end

        def ask() -> str:  # scripted, else at the terminal when live, else "ok"
            if answers:
                return answers.pop()
            return ask_person() if args.port is not None else "ok"

        _write_templates(args, f"{patch.name} / {layer.name}", layer, targets)
        guide = GuidedSession(targets, rules, str(args.frames or args.port))
        detector = PressDetector(rules)
        args.stretch_frames = None
        _prompt(guide)
        if args.frames is not None:
            stream = classified_frames(args, patch)
        else:
            stream = live_frames(args, patch, layer)
        for t, images, events in stream:
            frame = None if images is None else images.frame_v
            for press in detector.step(t, frame, events):
                if guide.done:
                    break
                _take_press(guide, press, ask)
            if guide.done:
                break
        session = guide.session()
        session.check_layer(layer)
        session.save(args.out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        return fail(error)
    refused = sum(not v.accepted for v in guide.log)
    print(
        f"wrote {args.out}: {session.n_presses} presses ({refused} refused, "
        f"{len(guide.log) - refused - session.n_presses} redone), M = {session.n_measurements}"
    )
    return 0


def _guide_rules(args: argparse.Namespace, targets: np.ndarray) -> GuideRules:
    """The press rules from the options; ``--max-offset`` defaults to the targets' spacing.

    ``targets`` ``[N, 2]`` m; the spacing is the median distance to the nearest other target.
    """
    import numpy as np

    from eit_skin.calibration.guide import GuideRules

    gaps = np.linalg.norm(targets[:, None] - targets[None], axis=2)
    np.fill_diagonal(gaps, np.inf)
    spacing = float(np.median(gaps.min(axis=1)))
    return GuideRules(
        min_hold_s=args.min_hold,
        min_snr=args.min_snr,
        min_relative=args.min_relative,
        max_offset_m=spacing if args.max_offset is None else args.max_offset * 1e-3,
    )


def _write_templates(
    args: argparse.Namespace, title: str, layer: Layer, targets: np.ndarray
) -> None:
    """Write the printable targets to ``--template``, else next to ``--out`` as SVG and PDF."""
    from eit_skin.calibration.template import template_drawing, write_template

    drawing = template_drawing(layer, targets, f"{title}: {len(targets)} calibration targets")
    templates = (
        [args.template]
        if args.template
        else [args.out.with_suffix(".svg"), args.out.with_suffix(".pdf")]
    )
    for path in templates:
        write_template(path, drawing)
    print(f"wrote {', '.join(map(str, templates))}: print at 100 %, check the 10 mm bar")


def _prompt(guide: GuidedSession) -> None:
    """Tell the person which target to press next (nothing once every target is done)."""
    if not guide.done:
        x, y = guide.targets[guide.current] * 1e3
        print(
            f"target {guide.current + 1}/{len(guide.targets)} at ({x:+.1f}, {y:+.1f}) mm: "
            "press it, hold, release"
        )


def _take_press(guide: GuidedSession, press: DetectedPress, ask: Callable[[], str]) -> None:
    """Judge one detected press, ask about an accepted one, then prompt for the next target."""
    import numpy as np

    verdict = guide.judge(press)
    off = np.linalg.norm(press.image_xy - guide.targets[verdict.target]) * 1e3
    span = f"{press.t_start_s:.2f}-{press.t_end_s:.2f} s"
    if not verdict.accepted:
        print(f"  press {span}: refused, {verdict.reason}; press target {verdict.target + 1} again")
        return
    print(
        f"  press {span}: accepted ({press.snr:.0f} x noise, image {off:.1f} mm from the mark)",
        end="",
        flush=True,
    )
    reply = ask()
    print(f"; answer: {reply}")
    guide.answer(verdict, reply)
    _prompt(guide)


def ask_person() -> str:
    """Ask at the terminal after an accepted press: Enter keeps it, ``r`` redoes the target."""
    while True:
        word = input(" -- Enter: next target, r: redo it > ").strip().lower()
        if word in ("", "ok", "y", "n", "next"):
            return "ok"
        if word in ("r", "redo"):
            return "redo"


def live_frames(args: argparse.Namespace, patch, layer):
    """``(t s, LayerImages, touch events)`` per imaged frame of the board on ``args.port``.

    The board read as ``eit-skin capture`` reads it, imaged by the reconstruction node's
    per-frame pipeline (the reference captured from the first frames: keep the sheet
    untouched at first) and classified as ``eit-skin classify`` does. Ends on Ctrl-C or
    when no frame came for ``args.wait`` seconds (an error).
    """
    import queue

    from eit_skin.cli.classify import build_classifier
    from eit_skin.cli.reconstruct import cache_dir, make_processor
    from eit_skin.hardware.sources import LayerFrameFactory, board_source
    from eit_skin.pipeline.builder import LayerImager

    imager = LayerImager.build(layer, cache_dir=cache_dir(args))
    args.reference = "capture"
    processor = make_processor(imager, args, patch.name)
    classifier = build_classifier(layer, imager)
    records: queue.Queue = queue.Queue()
    source = board_source(
        LayerFrameFactory(patch, layer, patch.frame_id), args.port, args.baud, records.put
    )
    print(
        f"reading {layer.name!r} from {args.port}: keep the sheet untouched for the first second",
        flush=True,
    )
    source.start()
    first_ns = None
    t = 0.0
    try:
        while True:
            try:
                record = records.get(timeout=args.wait)
            except queue.Empty:
                raise ValueError(
                    f"{args.port}: no frame for {args.wait:g} s: {source.status().message}"
                ) from None
            first_ns = record.stamp_ns if first_ns is None else first_ns
            t = (record.stamp_ns - first_ns) * 1e-9
            flags = record.channel_flags if len(record.channel_flags) else None
            images = processor.step(record.voltages, t, flags)
            if images is None:
                continue
            classifier.set_faulty_electrodes(images.faulty_electrodes)
            yield t, images, classifier.step(t, images.image, None, images.frame_v)
    except KeyboardInterrupt:
        yield t, None, classifier.finish()
    finally:
        source.stop()
