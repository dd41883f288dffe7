"""``bench/standing/bench_reconstruction.py --json``: the schema of its rows, from a tiny real run.

The benchmark module is loaded from its file with ``importlib`` (nothing is added to
``sys.path``); one tiny mesh is measured with the benchmark's own function and written with
its writer. Only the schema and the measured quantities' consistency are checked, never a
timing bound.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.patch.protocol import ProtocolSpec, build_protocol

REPO = Path(__file__).resolve().parents[2]


def _load_bench():
    name = "eit_skin_bench_reconstruction"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            name, REPO / "bench" / "standing" / "bench_reconstruction.py"
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def test_json_rows_of_a_tiny_run(tmp_path):
    bench = _load_bench()
    r = bench.R
    protocol = build_protocol(ProtocolSpec(), 16)
    data = ForwardModel(disk_mesh(r, h_m=0.006), protocol, 1e-4)
    v0 = data.voltages(1.0)
    phantoms = []
    for c in (np.array([0.3 * r, 0.1 * r]), np.array([-0.5 * r, -0.2 * r])):
        sig = np.ones(data.mesh.n_triangles)
        sig[np.linalg.norm(data.mesh.centroids - c, axis=1) < 0.1 * r] = 2.0
        phantoms.append((c, data.voltages(sig)))
    frames = np.stack([v for _, v in phantoms])
    mesh = disk_mesh(r, h_m=0.012)
    grid = ImageGrid.build(mesh, 32)
    g = bench.greit_case(mesh, protocol, frames, v0, phantoms, grid, 1e9)
    # memory floor at 1 GB/s: the merged matrix, the float64 frame in, the float32 image out
    matrix = g["matrix"].merged.matrix
    assert g["frame_floor_s"] == pytest.approx((matrix.nbytes + 8 * 208 + 4 * 32 * 32) / 1e9)
    assert 0 < g["batched_floor_s"] < g["frame_floor_s"]
    build, frame_t, batch_t, ours = g["build_s"], g["frame_s"], g["batched_s"], g["merit"]
    # the frame -> image product is float32: close to the float64 chain, not equal
    assert 0 < g["image_error"] < 1e-5
    row = bench.json_row(
        triangles=mesh.n_triangles,
        build_s=build,
        frame_ms=frame_t * 1e3,
        batched_frame_ms=batch_t * 1e3,
        gn_frame_ms=None,
        max_pe_r=ours[0],
        pyeit_build_s=None,
        pyeit_frame_ms=float("nan"),
    )
    path = tmp_path / "out.json"
    bench.write_json(path, [row])
    back = json.loads(path.read_text())
    assert isinstance(back, list) and len(back) == 1
    assert list(back[0]) == [
        "triangles",
        "build_s",
        "frame_ms",
        "batched_frame_ms",
        "gn_frame_ms",
        "max_pe_r",
        "pyeit_build_s",
        "pyeit_frame_ms",
        "pyeit_max_pe_r",
    ]
    got = back[0]
    assert got["triangles"] == mesh.n_triangles and isinstance(got["triangles"], int)
    # measured values come through as numbers, in the units the keys name
    assert got["build_s"] == build and got["frame_ms"] == frame_t * 1e3
    assert got["max_pe_r"] == ours[0] and 0 <= got["max_pe_r"] < 1
    # not measured (None, NaN or left out): null
    assert got["gn_frame_ms"] is None and got["pyeit_frame_ms"] is None
    assert got["pyeit_max_pe_r"] is None and got["pyeit_build_s"] is None
    with pytest.raises(ValueError, match="frame_s"):
        bench.json_row(triangles=1, frame_s=1.0)
