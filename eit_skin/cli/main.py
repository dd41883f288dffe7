"""The ``eit-skin`` command: one sub-command per module in ``eit_skin.cli``.

Each command module defines ``add_arguments(parser)`` and ``run(args) -> int``
and keeps heavy imports (rclpy, matplotlib, the solver) inside ``run`` so that
building the parser stays cheap.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module under eit_skin.cli, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    # "name": ("module", "help"),  one line per command, kept alphabetical
    "calibrate": ("calibrate", "Fit a press localiser from labelled presses; k-fold figures."),
    "capture": (
        "capture",
        "Record a board's frames to an offline frames file (npz), without ROS.",
    ),
    "classify": ("classify", "Detect and label touches in an offline frames file; JSON lines."),
    "design": ("design", "Design a skin in the browser: electrodes, mesh, predicted accuracy."),
    "detect": (
        "detect",
        "Recognise the board on a serial port and the patch that fits its frames.",
    ),
    "fake-device": ("fake_device", "Emulate a skin board on a pseudo-terminal."),
    "fit-device": ("fit_device", "Fit sheet conductance, contact impedance to a no-load frame."),
    "frames": ("frames", "Convert frame recordings between MCAP and the offline npz format."),
    "locate": ("locate", "Press positions, confidence and depth of frames from a calibration."),
    "patch": ("patch", "Validate a patch file, print a summary, optionally draw it."),
    "presses": ("presses", "Make a press session: robot probe CSV, by hand (guide), or simulated."),
    "reconstruct": ("reconstruct", "Reconstruct images from an offline frames file (npz)."),
    "record-postures": ("record_postures", "Record no-load references across a joint sweep."),
    "run": ("run", "Run the skin end to end (simulated arm by default); print touch events."),
    "simulate": (
        "simulate",
        "Simulate a touch scenario on a patch and save frames + ground truth.",
    ),
    "tune": (
        "tune",
        "Choose a layer's regularisation by noise figure and write it into the patch file.",
    ),
}

#: Former command names, still accepted with a deprecation line: "calibrate" is the press
#: localiser's alone (calibration/); a device's model is fitted, postures are recorded.
DEPRECATED: dict[str, str] = {
    "calibrate-device": "fit-device",
    "calibrate-posture": "record-postures",
}


def argument_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="eit-skin", description="EIT robot skin: patches, reconstruction, simulator, bring-up."
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module_name, help_text) in COMMANDS.items():
        module = importlib.import_module(f"eit_skin.cli.{module_name}")
        sub_parser = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(sub_parser)
        sub_parser.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in DEPRECATED:
        new = DEPRECATED[argv[0]]
        print(f"eit-skin: '{argv[0]}' is deprecated, use '{new}'", file=sys.stderr)
        argv[0] = new
    args = argument_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
