"""Meshes of skin layers: electrodes on exact boundary edges, holes, quality, determinism."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eit_skin.fem.mesh import build_mesh
from eit_skin.patch import geometry
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.patch.model import Layer

CONFIG = Path(__file__).resolve().parents[2] / "config"
LAYERS = [
    (name, layer.name)
    for name in ("arm", "face", "elbow")
    for layer in load_patch(CONFIG / f"{name}.yaml").layers
]


def config_layer(name: str, layer_name: str) -> Layer:
    return load_patch(CONFIG / f"{name}.yaml").layer(layer_name)


@pytest.fixture(scope="module", params=LAYERS, ids=[f"{a}-{b}" for a, b in LAYERS])
def layer_and_mesh(request):
    layer = config_layer(*request.param)
    return layer, build_mesh(layer), request.param


def rectangle_with_corner_electrodes() -> Layer:
    """Electrode 0 wraps the outline's start point (a corner), electrode 2 spans a corner."""
    data = {
        "name": "r",
        "frame_id": "r",
        "layers": [
            {
                "name": "sheet",
                "outline": {"type": "rectangle", "width": 0.1, "height": 0.05},
                "holes": [
                    {"type": "polygon", "points": [[-0.02, -0.01], [0.0, -0.01], [-0.01, 0.01]]},
                    {"type": "circle", "radius": 0.006, "center": [0.02, 0.0]},
                ],
                "electrodes": {
                    "positions": [0.0, 0.15, 0.5, 0.6, 0.8],
                    "width": 0.012,
                    "contact_impedance": 1.0,
                },
                "material": {
                    "quantity": "pressure",
                    "sheet_conductance": 1e-3,
                    "pressure_scale": 1e4,
                },
                "mesh": {"max_edge": 0.004, "electrode_edge": 0.001, "min_angle": 32},
            }
        ],
    }
    return patch_from_dict(data).layers[0]


def check_electrodes(layer: Layer, mesh) -> None:
    boundary = {tuple(e) for e in mesh.boundary_edges.tolist()}
    perimeter = layer.perimeter_m
    assert mesh.n_electrodes == layer.n_electrodes
    pairs = zip(layer.electrodes, mesh.electrode_edges, strict=True)
    for k, (electrode, edges) in enumerate(pairs):
        # real boundary edges, sheet on the left, chained counter-clockwise
        assert {tuple(e) for e in edges.tolist()} <= boundary
        np.testing.assert_array_equal(edges[1:, 0], edges[:-1, 1])
        # every node on the outline, inside [start, end] along it
        nodes = mesh.nodes[np.unique(edges)]
        s, dist = geometry.project_onto_polygon(nodes, layer.outline)
        assert dist.max() < 1e-15 * perimeter + 1e-17
        rel = np.mod(s - electrode.start_m + 1e-12, perimeter) - 1e-12
        assert rel.min() > -1e-12 and rel.max() < electrode.width_m + 1e-12
        # ends exactly at the electrode ends
        np.testing.assert_allclose(
            mesh.nodes[edges[0, 0]],
            geometry.point_at_arc(layer.outline, electrode.start_m),
            rtol=0,
            atol=1e-15,
        )
        length = mesh.electrode_lengths[k]
        assert abs(length - electrode.width_m) <= 1e-9 * electrode.width_m, (k, length)
        # refinement: no edge under an electrode longer than the electrode edge size
        lengths = np.linalg.norm(np.diff(mesh.nodes[edges], axis=1)[:, 0], axis=1)
        assert lengths.max() <= layer.mesh.electrode_edge_m * (1 + 1e-9)


def check_covering(layer: Layer, mesh) -> None:
    assert np.all(mesh.areas > 0)  # counter-clockwise triangles
    # the mesh covers exactly the sheet minus its holes
    assert mesh.areas.sum() == pytest.approx(layer.area_m2, rel=1e-12)
    for hole in layer.holes:
        assert not geometry.points_in_polygon(mesh.centroids, hole).any()
    assert geometry.points_in_polygon(mesh.centroids, layer.outline).all()
    assert mesh.min_angles_deg.min() >= layer.mesh.min_angle_deg - 1e-9
    # every node is used
    assert np.array_equal(np.unique(mesh.triangles), np.arange(mesh.n_nodes))


def test_config_meshes(layer_and_mesh):
    layer, mesh, _ = layer_and_mesh
    assert 2000 <= mesh.n_triangles <= 10000
    assert mesh.triangles.dtype == np.int64 and mesh.nodes.dtype == np.float64
    check_electrodes(layer, mesh)
    check_covering(layer, mesh)
    h = layer.mesh.max_edge_m
    assert mesh.areas.max() <= np.sqrt(3) / 4 * h * h * (1 + 1e-9)


def test_mesh_is_deterministic(layer_and_mesh):
    _, mesh, names = layer_and_mesh
    again = build_mesh(config_layer(*names))  # freshly loaded from the file
    assert again.nodes.tobytes() == mesh.nodes.tobytes()
    assert again.triangles.tobytes() == mesh.triangles.tobytes()
    for a, b in zip(again.electrode_edges, mesh.electrode_edges, strict=True):
        assert a.tobytes() == b.tobytes()


def test_porous_layer_keeps_holes_open():
    layer = config_layer("arm", "stretch")
    mesh = build_mesh(layer)
    hole_area = -sum(geometry.signed_area(h) for h in layer.holes)
    r = 0.0025  # 5 mm holes, 16-gons
    assert hole_area == pytest.approx(len(layer.holes) * 8 * r * r * np.sin(2 * np.pi / 16))
    assert mesh.areas.sum() == pytest.approx(geometry.signed_area(layer.outline) - hole_area)
    # each hole is bounded by boundary edges: count boundary nodes on hole circles
    b_nodes = np.unique(mesh.boundary_edges)
    centres = np.array([h.mean(axis=0) for h in layer.holes])
    d = np.linalg.norm(mesh.nodes[b_nodes][:, None] - centres[None], axis=-1).min(axis=1)
    on_holes = np.isclose(d, 0.0025, rtol=0, atol=1e-4)  # 16-gon radius 2.5 mm
    assert on_holes.sum() >= 16 * len(layer.holes)


def test_corner_and_wraparound_electrodes():
    layer = rectangle_with_corner_electrodes()
    mesh = build_mesh(layer)
    check_electrodes(layer, mesh)
    check_covering(layer, mesh)
    corner = layer.outline[0]
    assert any(np.allclose(mesh.nodes[n], corner) for n in mesh.electrode_edges[0][:, 1])


def test_max_edge_override_refines_and_coarsens():
    layer = config_layer("arm", "pressure")
    coarse = build_mesh(layer, max_edge_m=0.008)
    base = build_mesh(layer)
    fine = build_mesh(layer, max_edge_m=0.0015)
    assert coarse.n_triangles < base.n_triangles < fine.n_triangles
    for mesh, h in ((coarse, 0.008), (fine, 0.0015)):
        assert mesh.areas.max() <= np.sqrt(3) / 4 * h * h * (1 + 1e-9)
        check_electrodes(layer, mesh)
        check_covering(layer, mesh)


def test_very_fine_mesh():
    layer = config_layer("arm", "pressure")
    mesh = build_mesh(layer, max_edge_m=0.0006)
    assert mesh.n_triangles >= 50_000
    check_covering(layer, mesh)
    assert mesh.electrode_lengths == pytest.approx(0.004, rel=1e-9)


def test_bad_max_edge():
    with pytest.raises(ValueError, match="max_edge_m"):
        build_mesh(config_layer("elbow", "pressure"), max_edge_m=0.0)
