"""``eit-skin frames``: convert recordings between MCAP (ROS 2 bags) and the offline npz format.

``export REC.mcap OUT.npz``: one EitFrame topic -> ``reference`` (mean of the first
``--reference-frames``), ``frames`` [T, M] volts, ``t`` [T] header stamps in seconds. A
recording whose recorder was killed (no footer) or that was cut is recovered: every complete
record is exported and what was skipped is reported on stderr with byte offsets.
``import IN.npz OUT.mcap --patch P``: frames -> EitFrame messages on ``/<patch>/<layer>/frames``
with the layer's electrode count, pattern, current and frame_id, as the driver records them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eit_skin.cli.options import add_patch_options, chosen_layer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="direction", required=True, metavar="export|import")
    export = sub.add_parser("export", help="MCAP -> npz")
    export.add_argument("mcap", type=Path, metavar="REC.mcap")
    export.add_argument("npz", type=Path, metavar="OUT.npz")
    export.add_argument("--topic", default=None, help="EitFrame topic (needed if several)")
    export.add_argument("--reference-frames", type=int, default=20, help="frames in the reference")
    imp = sub.add_parser("import", help="npz -> MCAP")
    imp.add_argument("npz", type=Path, metavar="IN.npz")
    imp.add_argument("mcap", type=Path, metavar="OUT.mcap")
    add_patch_options(imp)
    imp.add_argument("--rate", type=float, default=50.0, help="frame rate if the file has no t")


def run(args: argparse.Namespace) -> int:
    from eit_skin.io.conversion import FrameStream, mcap_to_npz, npz_to_mcap
    from eit_skin.io.mcap import McapDamage

    try:
        if args.direction == "export":
            damage: list[McapDamage] = []
            n = mcap_to_npz(
                args.mcap, args.npz, args.topic, args.reference_frames, on_damage=damage.append
            )
            print(f"wrote {args.npz}: {n} frames" + (" (recovered)" if damage else ""))
            for found in damage:
                print(f"eit-skin frames export: skipped: {found}", file=sys.stderr)
            return 0
        from eit_skin.hardware.sources import pattern_name
        from eit_skin.ros.topics import patch_topics

        patch, layer = chosen_layer(args)
        topic = patch_topics(patch, patch.name).layers[layer.name].frames
        stream = FrameStream(
            topic,
            patch=patch.name,
            layer=layer.name,
            n_electrodes=layer.n_electrodes,
            drive_pattern=pattern_name(layer),
            current_a=layer.current_a,
            frame_id=patch.frame_id,
        )
        n = npz_to_mcap(args.npz, args.mcap, stream, rate_hz=args.rate)
        print(f"wrote {args.mcap}: {n} frames on {topic}")
        return 0
    except (ValueError, KeyError, OSError) as error:
        print(f"eit-skin frames {args.direction}: {error}", file=sys.stderr)
        return 1
