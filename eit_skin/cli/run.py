"""``eit-skin run``: the whole skin, end to end, without ros2 launch.

Starts, for one patch (default: the simulated arm) or all of them, the same nodes as
``launch/skin_patch.launch.py`` / ``robot_skin.launch.py`` (from
:mod:`eit_skin.ros.node_graph`): reconstruction and classifier first, the driver once the
reconstruction matrices are ready (so the no-load reference is taken from untouched
frames). It prints the touch events as they happen and writes PNG snapshots of the
pressure and stretch images at every touch, an animated GIF per patch and the node logs
to ``--out``. With the simulator it stops after one pass of the touch script (or after
``--duration`` seconds) and exits 0; with ``--port`` (a one-layer patch) or ``--ports`` /
``--ports-file`` (one board per layer) it runs until ``--duration`` or Ctrl-C.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from eit_skin.cli.options import add_patch_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser, default="arm", layer=False)
    parser.add_argument("--all", action="store_true", help="run arm, face and elbow at once")
    parser.add_argument(
        "--port", default="", help="serial device of the board of a one-layer patch (no simulator)"
    )
    parser.add_argument(
        "--ports",
        default="",
        help="one board per layer: LAYER=DEVICE,..., e.g. pressure=/dev/ttyA,stretch=/dev/ttyB",
    )
    parser.add_argument(
        "--ports-file",
        default="",
        help="the boards from a ports YAML (patch -> layer -> device), e.g. config/ports.yaml",
    )
    parser.add_argument(
        "--duration", type=float, default=None, help="stop after SECONDS (default: one script pass)"
    )
    parser.add_argument("--out", type=Path, default=Path("eit_skin_run"), help="output folder")
    parser.add_argument("--rate", type=float, default=50.0, help="simulator frame rate, Hz")
    parser.add_argument("--scenario", default="demo", help="simulator touch script (name or YAML)")
    parser.add_argument("--seed", type=int, default=0, help="simulator random seed")
    parser.add_argument(
        "--calibration",
        default="",
        help="press calibration npz (eit-skin calibrate): calibrated contacts and positions",
    )


def run(args: argparse.Namespace) -> int:
    from eit_skin.ros.node_graph import ROBOT_PATCHES, parse_ports, patch_nodes, read_ports_file

    if args.all and args.calibration:
        print("eit-skin run: a calibration belongs to one patch; not with --all", file=sys.stderr)
        return 2
    serial = bool(args.port or args.ports or args.ports_file)
    if args.all and serial:
        print("eit-skin run: --all simulates every patch; --port(s) serve one", file=sys.stderr)
        return 2
    patches = list(ROBOT_PATCHES) if args.all else [args.patch]
    try:
        if args.ports and args.ports_file:
            raise ValueError("--ports and --ports-file given; choose one")
        ports = parse_ports(args.ports)
        if args.ports_file:
            ports = read_ports_file(args.ports_file, Path(args.patch).stem)
        specs = []
        for patch in patches:
            specs += patch_nodes(
                patch,
                namespace=Path(patch).stem if args.all else "",
                port=args.port,
                sim=not serial,
                rate_hz=args.rate,
                scenario=args.scenario,
                loop=False,
                ports=ports,
            )
        script_frames = {} if serial or args.duration else _script_frames(args, specs)
        specs = [waiting_for_readers(spec, specs) for spec in specs]
        if args.calibration:
            specs = [_calibrated(spec, args.calibration) for spec in specs]
    except (ValueError, OSError) as error:
        print(f"eit-skin run: {error}", file=sys.stderr)
        return 2
    from eit_skin.ros.skin_monitor import run_skin

    return run_skin(
        specs,
        args.out,
        duration_s=args.duration,
        script_frames=script_frames,
        first_frame_timeout_s=None if serial else 120.0,  # a board may be plugged in later
    )


def _calibrated(spec, calibration: str):
    """The reconstruction with the ``calibration`` parameter; other nodes unchanged."""
    from dataclasses import replace

    if spec.executable != "eit_reconstruction":
        return spec
    return replace(spec, parameters={**spec.parameters, "calibration": calibration})


#: Nodes of a patch's graph that subscribe to its raw frames (besides the run's monitor).
FRAME_READERS = ("eit_reconstruction", "eit_classifier")


def waiting_for_readers(spec, specs):
    """A simulated driver that holds its script until every reader of its frames listens.

    The patch's reconstruction reads every layer's frames, its classifier the pressure
    layer's (``shape_z`` and the START filter), and the run's monitor all of them: the
    driver starts once one of its publishers (the pressure layer's) has them all. Waiting
    for fewer let two of them start the script without the third: the reconstruction then
    took its reference during the first push (no first touch), or the monitor's clock
    started a second late. One participant's subscriptions are discovered together, so the
    other layers' readers are there too.
    """
    from dataclasses import replace

    if spec.executable != "eit_driver" or spec.parameters.get("port"):
        return spec
    readers = sum(s.namespace == spec.namespace and s.executable in FRAME_READERS for s in specs)
    return replace(spec, parameters={**spec.parameters, "wait_for_subscribers": readers + 1})


def _script_frames(args: argparse.Namespace, specs) -> dict[str, int]:
    """Frames in one pass of each simulated patch's touch script, by namespace."""
    from eit_skin.patch.loading import load_patch
    from eit_skin.sim.scripts import resolve_scenario

    frames = {}
    for spec in specs:
        if spec.executable == "eit_driver":
            patch = load_patch(str(spec.parameters["patch_config"]))
            scenario = resolve_scenario(args.scenario, patch, args.seed, None)
            frames[spec.namespace] = math.ceil(scenario.duration_s * args.rate)
    return frames
