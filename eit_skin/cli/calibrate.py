"""``eit-skin calibrate``: fit a press localiser from a press session; print k-fold figures.

The session (``--presses``, see ``eit_skin.calibration.session``) is checked against the layer
(channel count, every press on the sheet); the k-fold cross-validation shows what to expect
on new presses (median and 90th-percentile position error, per depth band when depths are
given); then the model is fitted on all presses and written to ``--out`` (npz, no pickles).

``--physics-prior N`` (default :data:`DEFAULT_PRIOR_PRESSES`; 0: off) fits the layer's sheet
conductance, contact impedance and the board's input gain ratio to the session's unloaded frame
(as ``fit-device --fit-input-gain`` does), simulates N presses on that model and uses them as
the localiser's prior (``eit_skin.calibration.physics_prior``; leave-one-out keeps it only where
it helps); the cross-validation then includes the prior, refitted per fold. On by default since
the model knows the board's unequal inputs and a press that thins a gel: it helps every
benchmarked skin from 50 presses on, the real hydrogel most at 400 (bench/standing/
press_calibration.md), for a device fit and a simulation (6-14 s). Where the default prior
cannot be built (the model does not fit the unloaded frame at all) it is left out with a note;
an explicit ``--physics-prior N`` fails with the reason instead.
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

DEFAULT_PRIOR_PRESSES = 500
"""Presses simulated for the physics prior unless ``--physics-prior`` says otherwise."""

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
        default=None,
        metavar="N",
        help="simulate N presses on the device-fitted model as the localiser's prior "
        f"(default {DEFAULT_PRIOR_PRESSES}; 0: off)",
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


def physics_prior(args: argparse.Namespace, patch, layer, session):
    """(the prior or None, notes to print) for ``--physics-prior`` (module docstring)."""
    from eit_skin.calibration.physics_prior import PhysicsPrior
    from eit_skin.sim.press_session import calibrated_to_device, simulate_press_session

    n = DEFAULT_PRIOR_PRESSES if args.physics_prior is None else args.physics_prior
    if n < 0:
        raise ValueError(f"--physics-prior: {n} presses, want >= 0")
    if n == 0:
        return None, []
    try:
        device, fit = calibrated_to_device(patch, layer.name, session.reference)
    except ValueError as error:
        if args.physics_prior is not None:
            raise
        return None, [f"physics prior left out: {error}"]
    prior = PhysicsPrior.fit(simulate_press_session(device, n, layer.name, seed=args.seed))
    notes = [
        f"physics prior: {n} presses simulated on layer {layer.name!r} fitted to the "
        f"session's unloaded frame (fit residual {fit.residual:.1%} of its rms, negative "
        f"input gain {fit.negative_input_gain:.3g})"
    ]
    if fit.residual > POOR_FIT:
        notes.append(
            "  the model explains this device's unloaded frame poorly: expect little "
            "from the prior (leave-one-out drops it when it does not help)"
        )
    return prior, notes


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.calibration.localiser import PressLocaliser, cross_validate
    from eit_skin.calibration.physics_prior import PRIOR_MODES, PriorPosition
    from eit_skin.calibration.response_map import ResponseMap
    from eit_skin.calibration.session import load_press_session
    from eit_skin.patch.model import PatchError

    try:
        patch, layer = chosen_layer(args)
        session = load_press_session(args.presses)
        session.check_layer(layer)
        if args.max_touches < 1:
            raise ValueError(f"--max-touches: {args.max_touches}, need >= 1")
        prior, notes = physics_prior(args, patch, layer, session)
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
    if isinstance(model.position, ResponseMap):
        k = model.position.projection.shape[1]
        print(f"  position: response map on {k} principal components (leave-one-out)")
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
