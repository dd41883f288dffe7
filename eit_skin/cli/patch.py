"""``eit-skin patch PATH [--png OUT.png]``: validate a patch file, summarise it, draw it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "path", help="patch YAML file, or the name of a shipped patch: arm, face, elbow"
    )
    parser.add_argument(
        "--png",
        type=Path,
        metavar="OUT.png",
        help="draw sheet, holes, electrodes and mesh of every layer into this PNG file",
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from eit_skin.fem.mesh import build_mesh
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.protocol import build_protocol
    from eit_skin.resources import config_path

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
    if args.png is not None:
        _draw(patch, meshes, args.png)
        print(f"wrote {args.png}")
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
