"""``eit-skin reconstruct``: offline frames file (npz) -> relative conductivity images (npz).

IN.npz: ``reference`` float [M] volts, ``frames`` float [T, M] volts (protocol order).
OUT.npz: ``images`` float32 [T, H, W] relative conductivity change (delta sigma / sigma0,
positive = more conductive, NaN outside the sheet and in holes), ``x`` [W] and ``y`` [H]
pixel-centre coordinates in metres (patch frame). The output is written to a temporary
file next to OUT and renamed, so it is either complete or absent. Errors: one line on
stderr, exit status 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: Gauss-Newton regularisation when the layer's stored one belongs to another method.
GN_HYPERPARAMETER = 0.03


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--patch", required=True, help="patch YAML file (or a shipped name)")
    parser.add_argument("--frames", required=True, type=Path, metavar="IN.npz")
    parser.add_argument("--out", required=True, type=Path, metavar="OUT.npz")
    parser.add_argument("--layer", default=None, help="layer name (default: the first layer)")
    parser.add_argument(
        "--method",
        choices=("one_step", "gauss_newton"),
        default=None,
        help="reconstruction method (default: the layer's solver.method)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        images, x, y, faulty = _reconstruct(args)
        from eit_skin.io.npz import write_npz_atomic

        write_npz_atomic(args.out, images=images, x=x, y=y)
    except (ValueError, KeyError, OSError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"eit-skin reconstruct: error: {message}", file=sys.stderr)
        return 1
    note = f", left out electrodes {faulty.tolist()}" if faulty.size else ""
    print(f"wrote {args.out}: {images.shape[0]} images {images.shape[1]}x{images.shape[2]}{note}")
    return 0


def _reconstruct(args: argparse.Namespace):
    import numpy as np

    from eit_skin.fem.forward import ForwardModel
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.inverse.gauss_newton import GaussNewtonSolver
    from eit_skin.io.npz import load_frames_npz
    from eit_skin.patch.model import load_patch
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.resources import config_path

    patch = load_patch(config_path(args.patch))
    layer = patch.layers[0] if args.layer is None else patch.layer(args.layer)
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    if not args.frames.exists():
        raise ValueError(f"{args.frames}: no such file")
    reference, frames, _ = load_frames_npz(args.frames, protocol.n_measurements)

    solver = layer.solver
    method = args.method or solver.method
    # the chain the reconstruction node uses (matrix cached by the layer's content)
    imager = LayerImager.build(layer)
    if method == "one_step":
        reconstructor = imager.fault_tolerant()
        values = reconstructor.reconstruct(frames, reference)
        faulty = reconstructor.last_faulty
    else:
        # One solver per layer (prior, parameter map and first step prepared once), the fine
        # forward mesh for the physics, the inverse mesh for the unknowns. The trained (GREIT)
        # matrix is one-step only, and its stored h does not suit another prior, so
        # Gauss-Newton then uses the Laplace prior with its default h.
        mesh = build_mesh(layer)
        forward = ForwardModel(mesh, protocol, layer.contact_impedance_ohm_m, layer.current_a)
        greit = solver.method == "greit"
        solver_gn = GaussNewtonSolver(
            forward,
            layer.material.sheet_conductance_s,
            prior="laplace" if greit else solver.prior,
            hyperparameter=GN_HYPERPARAMETER
            if greit or solver.hyperparameter is None
            else solver.hyperparameter,
            parameter_mesh=None if layer.mesh.inverse_max_edge_m is None else imager.mesh,
        )
        values = np.stack(
            [
                solver_gn.difference(
                    f, reference, max_iterations=solver.max_iterations
                ).parameter_change
                for f in frames
            ]
        )
        faulty = np.zeros(0, dtype=np.int64)
    images = imager.images(values)
    return images, imager.grid.x, imager.grid.y, faulty
