"""``eit-skin patch PATH [--png OUT.png] [--predict]``: check, summarise, draw, predict a patch.

Also ``eit-skin patch import OUTLINE.(dxf|svg) --out PATCH.yaml``: a patch file from a CAD
drawing (:mod:`eit_skin.patch.cad_import`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "path",
        help="patch YAML file, or the name of a shipped patch: arm, face, elbow; or 'import'",
    )
    parser.add_argument(
        "drawing", nargs="?", help="with 'import': the outline drawing, OUTLINE.dxf or .svg"
    )
    parser.add_argument(
        "--png",
        type=Path,
        metavar="OUT.png",
        help="draw sheet, holes, electrodes and mesh of every layer into this PNG file "
        "(with --predict: the predicted accuracy maps)",
    )
    predict = parser.add_argument_group("predicted accuracy (--predict)")
    predict.add_argument(
        "--predict",
        action="store_true",
        help="maps of position error, resolution and amplitude response over the sheet "
        "from simulated small targets (no inverse crime); one summary line per layer",
    )
    predict.add_argument(
        "--noise-figure",
        type=float,
        help="regularisation noise figure instead of the layer's solver.noise_figure",
    )
    predict.add_argument("--json", type=Path, metavar="OUT.json", help="the figures as JSON")
    predict.add_argument(
        "--quality",
        choices=("full", "preview"),
        default="full",
        help="full: ~120 targets on a data mesh half the imaging edge (default); preview: "
        "~36 targets, as the browser designer",
    )
    cad = parser.add_argument_group("import a drawing ('import' OUTLINE)")
    cad.add_argument("--electrodes", type=int, metavar="N", help="spread N electrodes evenly")
    cad.add_argument("--layer", help="only contours on this DXF layer / SVG group id")
    cad.add_argument("--units", help="unit of a drawing that states none: mm, cm, m, in, ...")
    cad.add_argument("--out", type=Path, metavar="PATCH.yaml", help="patch file to write")
    cad.add_argument(
        "--tolerance", type=float, default=5e-5, help="curve flattening tolerance, m (5e-5)"
    )
    cad.add_argument("--width", type=float, help="electrode width, m (default: template's)")
    cad.add_argument(
        "--template",
        help="patch (file or shipped name) whose first layer gives material, current, contact "
        "impedance, electrode width, protocol, mesh and solver",
    )
    cad.add_argument("--name", help="patch name (default: the drawing's file name)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.fem.mesh import build_mesh
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.resources import config_path

    if args.path == "import":
        return _import(args)
    if args.drawing is not None:
        print(f"error: unexpected argument {args.drawing!r}", file=sys.stderr)
        return 2
    try:
        patch = load_patch(config_path(args.path))
        meshes = [build_mesh(layer) for layer in patch.layers]
    except PatchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # meshing problems of a valid-looking file
        print(f"error: {args.path}: {exc}", file=sys.stderr)
        return 1

    print(f"patch {patch.name!r} ({patch.source})")
    print(f"  frame_id: {patch.frame_id}")
    print(f"  placement: {patch.placement.describe()}")
    print(f"  content hash: {patch.content_hash[:16]}")
    for layer, mesh in zip(patch.layers, meshes, strict=True):
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        widths = sorted({round(e.width_m * 1e3, 6) for e in layer.electrodes})
        lo, hi = layer.outline.min(axis=0), layer.outline.max(axis=0)
        spec = layer.protocol
        mat = layer.material
        gain = (
            f"pressure scale {mat.pressure_scale_pa:g} Pa"
            if mat.quantity == "pressure"
            else f"gauge factor {mat.gauge_factor:g}"
        )
        print(f"  layer {layer.name!r}:")
        print(
            f"    outline: {layer.outline_kind}, {(hi - lo)[0] * 1e3:.1f} x "
            f"{(hi - lo)[1] * 1e3:.1f} mm, perimeter {layer.perimeter_m * 1e3:.1f} mm, "
            f"area {layer.area_m2 * 1e4:.2f} cm^2"
        )
        print(f"    holes: {len(layer.holes)}")
        z = np.atleast_1d(layer.contact_impedance_ohm_m)
        contact = f"{z[0]:g}" if z.size == 1 else f"{z.min():g}..{z.max():g} (per electrode)"
        print(
            f"    electrodes: {layer.n_electrodes}, width {'/'.join(f'{w:g}' for w in widths)} "
            f"mm, contact impedance {contact} ohm*m, "
            f"current {layer.current_a * 1e3:g} mA"
        )
        print(
            f"    protocol: drive {spec.drive}, measure {spec.measure}, order {spec.order}, "
            f"sign {spec.sign:+d}, first electrode {spec.first_electrode}, "
            f"layout {spec.layout} ({protocol.frame_size} numbers), values {spec.values}: "
            f"{protocol.n_injections} injections, {protocol.n_measurements} measurements per frame"
        )
        print(
            f"    material: {mat.quantity}, sheet conductance {mat.sheet_conductance_s:.3g} S "
            f"({1.0 / mat.sheet_conductance_s:.4g} ohm/sq), {gain}"
        )
        print(
            f"    mesh: {mesh.n_triangles} triangles, {mesh.n_nodes} nodes, min angle "
            f"{mesh.min_angles_deg.min():.1f} deg (max edge {layer.mesh.max_edge_m * 1e3:g} mm, "
            f"electrode edge {layer.mesh.electrode_edge_m * 1e3:g} mm)"
        )
        print(f"    solver: {layer.solver.method}, prior {layer.solver.prior}")
    if args.predict:
        return _predict(patch, args)
    if args.png is not None:
        _draw(patch, meshes, args.png)
        print(f"wrote {args.png}")
    return 0


def _predict(patch, args: argparse.Namespace) -> int:
    """Print one summary line per layer; write the JSON and the maps' PNG if asked."""
    import json

    from eit_skin.pipeline.accuracy_map import predict_accuracy

    maps = []
    for layer in patch.layers:
        try:
            prediction = predict_accuracy(layer, args.noise_figure, args.quality)
        except ValueError as exc:
            print(f"error: {patch.source}: layer {layer.name}: {exc}", file=sys.stderr)
            return 1
        maps.append(prediction)
        t = prediction.timings_s
        print(
            f"  predicted {prediction.line()} [{prediction.layer.solver.method}, noise figure "
            f"{prediction.noise_figure:g}, {prediction.centres.shape[0]} targets, "
            f"{t['total']:.1f} s]"
        )
    if args.json is not None:
        data = {
            "patch": patch.name,
            "source": str(patch.source),
            "content_hash": patch.content_hash,
            "layers": [m.to_json() for m in maps],
        }
        args.json.write_text(json.dumps(data) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")
    if args.png is not None:
        from eit_skin.design.figures import draw_accuracy

        draw_accuracy(patch, maps, args.png)
        print(f"wrote {args.png}")
    return 0


def _import(args: argparse.Namespace) -> int:
    """``patch import OUTLINE --out PATCH.yaml``: drawing -> validated patch file."""
    from eit_skin.patch.cad_import import CadError, describe, read_drawing
    from eit_skin.patch.cad_patch import patch_data
    from eit_skin.patch.loading import patch_from_dict
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.yaml_reader import read_yaml, read_yaml_text
    from eit_skin.patch.yaml_writer import new_text
    from eit_skin.resources import config_path

    if args.drawing is None or args.out is None:
        print("error: patch import needs OUTLINE.(dxf|svg) and --out PATCH.yaml", file=sys.stderr)
        return 2
    drawing_path = Path(args.drawing)
    try:
        template = None
        if args.template is not None:
            template = read_yaml(config_path(args.template), PatchError)
        drawing = read_drawing(drawing_path, args.units, args.layer, args.tolerance)
        name = args.name or drawing_path.stem
        data = patch_data(drawing, name, args.electrodes, args.width, template)
        header = (
            f"Imported by `eit-skin patch import` from {drawing_path.name} ({drawing.units}, "
            f"curves within {args.tolerance * 1e3:g} mm).\n"
            + (
                "Material, contact impedance, width, current, protocol, mesh, solver: from "
                f"{args.template}."
                if template is not None
                else "Material, contact impedance and current are typical values: measure yours "
                "(docs/real-devices.md, eit-skin fit-device)."
            )
            + "\nUnits: metres, siemens, ohm*metre, amperes, pascals. Schema: docs/patch-schema.md."
        )
        text = new_text(data, header)
        patch = patch_from_dict(read_yaml_text(text, str(args.out), PatchError), str(args.out))
    except (CadError, PatchError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    args.out.write_text(text, encoding="utf-8")
    print(describe(drawing))
    layer = patch.layers[0]
    print(
        f"wrote {args.out}: patch {patch.name!r}, {layer.n_electrodes} electrodes, "
        f"{len(layer.holes)} holes, content hash {patch.content_hash[:16]}"
    )
    return 0


def _draw(patch, meshes, out: Path) -> None:
    """One panel per layer: mesh, outline, holes, numbered electrodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n = len(patch.layers)
    fig, axes = plt.subplots(1, n, figsize=(6.0 * n, 6.0), squeeze=False)
    for ax, layer, mesh in zip(axes[0], patch.layers, meshes, strict=True):
        mm = mesh.nodes * 1e3
        ax.triplot(mm[:, 0], mm[:, 1], mesh.triangles, color="0.75", lw=0.3)
        closed = np.vstack([layer.outline, layer.outline[:1]]) * 1e3
        ax.plot(closed[:, 0], closed[:, 1], color="k", lw=1.0)
        for hole in layer.holes:
            h = np.vstack([hole, hole[:1]]) * 1e3
            ax.fill(h[:, 0], h[:, 1], color="white", ec="tab:blue", lw=0.8)
        span = float(np.ptp(layer.outline, axis=0).max()) * 1e3
        for k, edges in enumerate(mesh.electrode_edges):
            chain = mm[np.append(edges[:, 0], edges[-1, 1])]
            ax.plot(chain[:, 0], chain[:, 1], color="tab:red", lw=3.5, solid_capstyle="butt")
            tangent = chain[-1] - chain[0]
            outward = np.array([tangent[1], -tangent[0]]) / (np.linalg.norm(tangent) or 1.0)
            label = layer.electrodes[k].center * 1e3 + 0.04 * span * outward
            ax.text(
                label[0], label[1], str(k), ha="center", va="center", fontsize=9, color="tab:red"
            )
        ax.set_aspect("equal")
        ax.margins(0.12)
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        ax.set_title(
            f"{patch.name} / {layer.name}: {mesh.n_triangles} triangles, "
            f"{layer.n_electrodes} electrodes, {len(layer.holes)} holes",
            fontsize=10,
        )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
