"""Per-triangle cost of meshing a layer and assembling its forward model (the mesh budget).

Measures, on a 50 mm disc (16 electrodes, 4 mm wide, adjacent protocol: 208 measurements),
for a range of ``max_edge``: the triangle count against the loader's estimate, CPU time of
``build_mesh`` and of the forward assembly the pipeline does first (``ForwardModel``,
voltages, Jacobian, relative Jacobian), and the peak resident memory they add. Every case
runs in a fresh process (``ru_maxrss`` is a high-water mark). The constants of
:mod:`eit_skin.patch.mesh_budget` come from this table (docs/patch-schema.md).

Usage: ``.venv/bin/python -m bench.studies.bench_mesh_budget [--out report.md]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

#: (electrodes, max_edge m): the 16-electrode sweep, then the measurement count varied.
CASES = (
    *((16, h) for h in (1e-3, 5e-4, 3e-4, 2e-4, 1.5e-4, 1.25e-4)),
    (8, 2e-4),
    (32, 2e-4),
)


def disc(n_electrodes: int, max_edge_m: float) -> dict:
    return {
        "name": "disc50",
        "frame_id": "disc_link",
        "layers": [
            {
                "name": "sheet",
                "outline": {"type": "circle", "radius": 0.025},
                "electrodes": {
                    "count": n_electrodes,
                    "width": min(0.004, 0.064 / n_electrodes),
                    "contact_impedance": 4.0,
                },
                "material": {
                    "quantity": "pressure",
                    "sheet_conductance": 1e-4,
                    "pressure_scale": 3e4,
                },
                "mesh": {"max_edge": max_edge_m, "electrode_edge": min(max_edge_m, 1e-3)},
            }
        ],
    }


def peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def one_case(n_electrodes: int, max_edge_m: float) -> dict:
    """Run in a fresh process: mesh + forward assembly of the disc at ``max_edge_m``."""
    import numpy as np

    from eit_skin.fem.forward import ForwardModel
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.inverse.one_step import relative_jacobian
    from eit_skin.patch.loading import patch_from_dict
    from eit_skin.patch.mesh_budget import estimate_layer
    from eit_skin.patch.protocol import build_protocol

    layer = patch_from_dict(disc(n_electrodes, max_edge_m), check_budget=False).layers[0]
    protocol = build_protocol(layer.protocol, layer.n_electrodes)
    base = peak_mib()
    t0 = time.process_time()
    mesh = build_mesh(layer)
    t1 = time.process_time()
    mesh_mib = peak_mib() - base
    forward = ForwardModel(mesh, protocol, layer.contact_impedance_ohm_m, layer.current_a)
    sigma = np.full(mesh.n_triangles, layer.material.sheet_conductance_s)
    j = relative_jacobian(forward.jacobian(sigma), forward.voltages(sigma), sigma)
    t2 = time.process_time()
    assert j.shape == (protocol.n_measurements, mesh.n_triangles)
    estimate = estimate_layer(layer)
    return {
        "measurements": protocol.n_measurements,
        "estimate": estimate.triangles,
        "estimate_mib": estimate.peak_bytes / 2**20,
        "estimate_s": estimate.seconds,
        "triangles": mesh.n_triangles,
        "mesh_s": t1 - t0,
        "forward_s": t2 - t1,
        "mesh_mib": mesh_mib,
        "total_mib": peak_mib() - base,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, help="also write the table to this file")
    parser.add_argument("--case", nargs=2, type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case is not None:
        print(json.dumps(one_case(int(args.case[0]), args.case[1])))
        return 0
    lines = [
        "Mesh budget: 50 mm disc, adjacent protocol, electrodes min(4, 64/n) mm wide, "
        "electrode_edge min(max_edge, 1 mm); CPU s; peak RSS added, MiB; estimates of "
        "eit_skin.patch.mesh_budget; one fresh process per row",
        "",
        "| electrodes | M | max_edge mm | triangles | estimate | mesh s | forward s | "
        "estimate s | mesh MiB | total MiB | estimate MiB | B/triangle |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n_el, h in CASES:
        out = subprocess.run(
            [sys.executable, "-m", __spec__.name, "--case", str(n_el), repr(h)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        r = json.loads(out)
        n = r["triangles"]
        lines.append(
            f"| {n_el} | {r['measurements']} | {h * 1e3:g} | {n} | {r['estimate']} | "
            f"{r['mesh_s']:.2f} | {r['forward_s']:.2f} | {r['estimate_s']:.2f} | "
            f"{r['mesh_mib']:.0f} | {r['total_mib']:.0f} | {r['estimate_mib']:.0f} | "
            f"{r['total_mib'] * 2**20 / n:.0f} |"
        )
        print(lines[-1], flush=True)
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
