"""``eit-skin calibrate``: fit a press localiser from a press session; print k-fold figures.

The session (``--presses``, see ``eit_skin.calibration.session``) is checked against the layer
(channel count, every press on the sheet); the k-fold cross-validation shows what to expect
on new presses (median and 90th-percentile position error, per depth band when depths are
given); then the model is fitted on all presses and written to ``--out`` (npz, no pickles).

``--physics-prior N`` (default 0: off) fits the layer's sheet conductance and contact impedance
to the session's unloaded frame (as ``fit-device`` does), simulates N presses on that model and
uses them as the localiser's prior (``eit_skin.calibration.physics_prior``); the
cross-validation then includes the prior, refitted per fold. It is off by default: on the one
real skin benchmarked (bench/standing/press_calibration.md) the model's presses do not resemble the
real ones and leave-one-out switches the prior off, at the cost of a simulation.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from eit_skin.cli.options import add_max_touches_option, add_patch_options, chosen_layer

if TYPE_CHECKING:
    import numpy as np

POOR_FIT = 0.1
"""Device fit residual (share of the unloaded frame's rms) above which the model is called poor."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument("--presses", type=Path, required=True, help="press session npz")
    parser.add_argument("--out", type=Path, required=True, help="calibration npz to write")
    parser.add_argument("--folds", type=int, default=5, help="folds of the cross-validation")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fold shuffle")
    add_max_touches_option(
        parser,
        "also fit the several-touches model (up to K touches at once, from the same single "
        "presses); default 1: one touch at a time",
    )
    parser.add_argument(
        "--physics-prior",
        type=int,
        default=0,
        metavar="N",
        help="simulate N presses on the device-fitted model as the localiser's prior (0: off)",
    )
    parser.add_argument(
        "--prior-mode",
        choices=("auto", "mean", "features"),
        default="auto",
        help="how the prior enters (auto: the better by leave-one-out)",
    )


def depth_bands(depth_m, n_bands: int = 3):
    """Band edges, m: the distinct depths if there are few, else equal-count quantiles."""
    import numpy as np

    values = np.unique(depth_m)
    if values.size <= n_bands:
        return [(float(v), float(v)) for v in values]
    edges = np.quantile(depth_m, np.linspace(0, 1, n_bands + 1))
    return [(float(a), float(b)) for a, b in itertools.pairwise(edges)]


def _print_depth_errors(
    depth_m: np.ndarray, error_mm: np.ndarray, depth_error_m: np.ndarray
) -> None:
    """Print the held-out depth error, then position and depth errors per depth band.

    ``depth_m`` ``[n]`` the presses' depths, ``error_mm`` ``[n]`` their position errors.
    """
    import numpy as np

    print(f"  depth error median {np.median(depth_error_m) * 1e3:.2f} mm")
    for lo, hi in depth_bands(depth_m):
        rows = (depth_m >= lo) & (depth_m <= hi)
        band = f"{lo * 1e3:.1f} mm" if lo == hi else f"{lo * 1e3:.1f}-{hi * 1e3:.1f} mm"
        print(
            f"  depth {band} ({int(rows.sum())} presses): position median "
            f"{np.median(error_mm[rows]):.1f} mm, p90 {np.percentile(error_mm[rows], 90):.1f} mm; "
            f"depth median {np.median(depth_error_m[rows]) * 1e3:.2f} mm"
        )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.calibration.localiser import PressLocaliser, cross_validate
    from eit_skin.calibration.physics_prior import PRIOR_MODES, PhysicsPrior, PriorPosition
    from eit_skin.calibration.session import load_press_session
    from eit_skin.patch.model import PatchError

    try:
        patch, layer = chosen_layer(args)
        session = load_press_session(args.presses)
        session.check_layer(layer)
        if args.max_touches < 1:
            raise ValueError(f"--max-touches: {args.max_touches}, need >= 1")
        prior, notes = None, []
        if args.physics_prior < 0:
            raise ValueError(f"--physics-prior: {args.physics_prior} presses, want >= 0")
        if args.physics_prior > 0:
            from eit_skin.sim.press_session import calibrated_to_device, simulate_press_session

            device, fit = calibrated_to_device(patch, layer.name, session.reference)
            simulated = simulate_press_session(
                device, args.physics_prior, layer.name, seed=args.seed
            )
            prior = PhysicsPrior.fit(simulated)
            notes.append(
                f"physics prior: {args.physics_prior} presses simulated on layer {layer.name!r} "
                f"fitted to the session's unloaded frame (fit residual {fit.residual:.1%} of "
                "its rms)"
            )
            if fit.residual > POOR_FIT:
                notes.append(
                    "  the model explains this device's unloaded frame poorly: expect little "
                    "from the prior (leave-one-out drops it when it does not help)"
                )
        modes = PRIOR_MODES if args.prior_mode == "auto" else (args.prior_mode,)
        cv = cross_validate(
            session, layer, folds=args.folds, seed=args.seed, prior=prior, prior_modes=modes
        )
        model = PressLocaliser.fit(session, layer, args.max_touches, prior=prior, prior_modes=modes)
        model.save(args.out)
    except (PatchError, OSError, KeyError, ValueError) as error:
        print(f"eit-skin calibrate: {error}", file=sys.stderr)
        return 2
    e = cv.xy_error * 1e3
    for note in notes:
        print(note)
    if prior is not None:
        position = model.position
        print(
            f"  kept: {position.mode}, weight {position.weight:g} (leave-one-out error "
            f"{position.loo_error * 1e3:.1f} mm)"
            if isinstance(position, PriorPosition)
            else "  not kept: no better than without it by leave-one-out (one standard error)"
        )
    print(
        f"{session.n_presses} presses, {args.folds}-fold: position error median "
        f"{np.median(e):.1f} mm, p90 {np.percentile(e, 90):.1f} mm"
    )
    if cv.depth_error is not None:
        _print_depth_errors(session.depth, e, cv.depth_error)
    if model.multi_touch is not None:
        mt = model.multi_touch
        print(
            f"  several touches: up to {args.max_touches}, touches closer than "
            f"{mt.min_separation_m * 1e3:.0f} mm count as one; {mt.false_split_rate:.0%} of "
            "held-out single presses are split in two"
        )
    print(f"wrote {args.out} (layer {layer.name!r}, M = {model.n_measurements})")
    return 0
