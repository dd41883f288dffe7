"""``eit-skin presses``: make a press session file (the input of ``eit-skin calibrate``).

``record --frames REC.npz --probe PROBE.csv --out S.npz``: pair a frame recording that has
times ``t`` (``eit-skin frames export`` of the driver's MCAP gives header stamps; a device's
own frames are read in the patch's conventions, e.g. ``layout: full``, as ``reconstruct`` reads
them) with the robot's probe log, one CSV row per press at full depth: ``time_s, x_m,
y_m[, depth_m]`` in the patch frame, on the same clock. ``--baseline-offset S``: each press's own
baseline is the frame ``S`` seconds before it (probe lifted). ``--patch`` checks M and that
every press lies on the sheet before anything is written.

``simulate --patch P --count N --out S.npz``: N random presses simulated on the patch.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="mode", required=True, metavar="record|simulate")
    record = sub.add_parser("record", help="pair a frame recording with a probe CSV")
    record.add_argument("--frames", type=Path, required=True, help="frames npz with 't'")
    record.add_argument("--probe", type=Path, required=True, help="CSV: time, x, y[, depth]")
    record.add_argument("--baseline-offset", type=float, default=None, help="seconds")
    simulate = sub.add_parser("simulate", help="simulate random presses on a patch")
    simulate.add_argument("--count", type=int, default=400, help="presses")
    simulate.add_argument("--seed", type=int, default=0, help="seed")
    simulate.add_argument("--no-drift", action="store_true", help="no sigma0 drift")
    for p in (record, simulate):
        p.add_argument("--patch", required=True, help="patch name or YAML path")
        p.add_argument("--layer", default="", help="layer (default: the first)")
        p.add_argument("--out", type=Path, required=True, help="press session npz to write")


def run(args: argparse.Namespace) -> int:
    from eit_skin.calibration.session import pair_probe_csv
    from eit_skin.cli.locate import load_located_frames
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.resources import config_path

    try:
        patch = load_patch(config_path(args.patch))
        layer = patch.layer(args.layer) if args.layer else patch.layers[0]
        if args.mode == "record":
            protocol = build_protocol(layer.protocol, layer.n_electrodes)
            reference, frames, _, t = load_located_frames(args.frames, protocol)
            if t is None:
                raise ValueError(f"{args.frames}: missing key 't' (frame times to pair with)")
            session = pair_probe_csv(
                reference, frames, t, args.probe, args.baseline_offset, str(args.frames)
            )
        else:
            from eit_skin.sim.press_session import simulate_press_session

            session = simulate_press_session(
                patch, args.count, layer.name, args.seed, drift=not args.no_drift
            )
        session.check_layer(layer)
        session.save(args.out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        print(f"eit-skin presses {args.mode}: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {session.n_presses} presses, M = {session.n_measurements}")
    return 0
