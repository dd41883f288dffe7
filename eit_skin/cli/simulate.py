"""``eit-skin simulate``: run a touch scenario on a patch; write frames (npz) + ground truth.

Writes ``OUT/<layer>.npz`` per layer (``reference`` [M] V, ``frames`` [T, M] V, ``t`` [T] s; the
input format of ``eit-skin reconstruct`` and ``eit-skin classify``) and ``OUT/truth.json``
(touches with label, times, centroid track, contacts; posture track; ADC and noise figures).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from eit_skin.cli.errors import USER_ERRORS, report_error
from eit_skin.cli.options import add_patch_options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from eit_skin.sim.faults import fault_help

    add_patch_options(parser, default="arm", layer=False)
    parser.add_argument(
        "--scenario",
        default="demo",
        help="built-in script (demo, push, rub, pinch, grab, idle, elbow_bend, random) "
        "or a scenario YAML path",
    )
    parser.add_argument("--rate", type=float, default=50.0, help="frame rate, Hz (default 50)")
    parser.add_argument("--seed", type=int, default=0, help="noise/drift/random-script seed")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="seconds to simulate (default: one pass of the script; random: 30)",
    )
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND:INDEX[@LAYER]",
        help=f"a hardware fault, repeatable: {fault_help(' --fault ')}",
    )
    parser.add_argument("--no-drift", action="store_true", help="switch the baseline drift off")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR")


def run(args: argparse.Namespace) -> int:
    from eit_skin.patch.loading import load_patch
    from eit_skin.resources import config_path
    from eit_skin.sim.drift import NO_DRIFT
    from eit_skin.sim.simulator import SkinSimulator

    try:
        if args.rate <= 0:
            raise ValueError(f"--rate must be > 0, got {args.rate}")
        if args.duration is not None and args.duration <= 0:
            raise ValueError(f"--duration must be > 0, got {args.duration}")
        patch = load_patch(config_path(args.patch))
        start = time.perf_counter()
        sim = SkinSimulator(
            patch,
            args.scenario,
            rate_hz=args.rate,
            seed=args.seed,
            faults=args.fault,
            drift=NO_DRIFT if args.no_drift else None,
            duration_s=args.duration,
        )
        recording = sim.run(duration_s=args.duration)
        paths = recording.save(args.out)
        elapsed = time.perf_counter() - start
    except USER_ERRORS as exc:
        return report_error("simulate", exc)
    n = len(recording.t)
    print(
        f"{patch.name}: scenario {sim.scenario.name!r}, {n} frames at {args.rate:g} Hz "
        f"({n / args.rate:.1f} s) in {elapsed:.1f} s"
    )
    for truth in recording.truth:
        x, y = truth.track[len(truth.track) // 2][1:]
        print(
            f"  {truth.label:5s} {truth.t_start_s:6.2f}-{truth.t_end_s:6.2f} s at "
            f"({1000 * x:+.1f}, {1000 * y:+.1f}) mm, {len(truth.contacts)} contact(s), "
            f"{truth.force_n:.1f} N, peak {truth.peak_pressure_pa / 1000:.0f} kPa"
        )
    for name, info in recording.meta["layers"].items():
        sat = int(recording.layers[name].flags.astype(bool).sum())
        print(
            f"  layer {name}: gain {info['adc_gain']:g}, full scale +-{info['full_scale_v']:.3f} V,"
            f" noise {1e6 * info['noise_v']:.1f} uV rms, SNR median {info['snr_db_median']:.0f}"
            f" dB, saturated values {sat}"
        )
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0
