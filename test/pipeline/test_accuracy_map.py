"""Predicted accuracy of a design (``eit-skin patch --predict``) against the benchmark's data.

The predictor simulates its own targets on a finer data mesh; on the reconstruction
benchmark's disc, with the benchmark's 30 targets, its largest position error must agree
within 10 % with the same model imaging the benchmark's own data (another data mesh:
bench_reconstruction's 1.2 mm disc mesh). Crowding the electrodes into one half of the sheet
must make the other half worse, and the command's JSON must hold what its line says.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.disk import disk_mesh
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.phantoms import disc_centres, simulate_discs
from eit_skin.inverse.figures_of_merit import figures_of_merit
from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.protocol import ProtocolSpec, build_protocol
from eit_skin.pipeline.accuracy_map import TARGET_CONTRAST, TARGET_RADIUS_R, predict_accuracy
from eit_skin.pipeline.builder import LayerImager

R = 0.05


def disc_patch(positions=None, max_edge: float = 0.0026):
    """bench_reconstruction's disc as a patch: 16 electrodes 5 mm wide, z = 1e-4, GREIT."""
    electrodes = {"width": 0.005, "contact_impedance": 1.0e-4}
    electrodes |= {"positions": positions} if positions else {"count": 16, "layout": "even"}
    return patch_from_dict(
        {
            "name": "disc",
            "frame_id": "disc_link",
            "layers": [
                {
                    "name": "pressure",
                    "outline": {"type": "circle", "radius": R},
                    "electrodes": electrodes,
                    "current": 1.0e-3,
                    "material": {
                        "quantity": "pressure",
                        "sheet_conductance": 1.0,
                        "pressure_scale": 1.0e4,
                    },
                    "mesh": {"max_edge": max_edge, "electrode_edge": max_edge},
                    "solver": {"method": "greit", "noise_figure": 0.13, "image_pixels": 64},
                }
            ],
        }
    )


def test_prediction_agrees_with_the_benchmark_data_on_its_targets():
    layer = disc_patch().layers[0]
    centres = disc_centres(R)
    predicted = predict_accuracy(layer, centres=centres, cache_dir=None)
    assert predicted.data_triangles > 2 * predicted.inverse_triangles  # no inverse crime
    # the benchmark's data: its own 1.2 mm disc mesh, its noise draws
    protocol = build_protocol(ProtocolSpec(), 16)
    fine = ForwardModel(disk_mesh(R, h_m=0.0012), protocol, 1e-4)
    bench = simulate_discs(
        fine, centres, TARGET_RADIUS_R * R, TARGET_CONTRAST, 0.01, np.random.default_rng(0)
    )
    imager = LayerImager.build(layer, None)
    images = imager.images(imager.relative_change(bench.frames, bench.reference))
    grid = imager.grid
    measured = np.array(
        [
            figures_of_merit(im, grid.x, grid.y, c, sign=1.0).position_error_m
            for im, c in zip(images, centres, strict=True)
        ]
    )
    worst_predicted, worst_measured = predicted.position_error_m.max(), measured.max()
    assert worst_predicted == pytest.approx(worst_measured, rel=0.10)
    assert np.median(predicted.position_error_m) == pytest.approx(np.median(measured), rel=0.25)
    assert (
        0.005 * R < worst_predicted < 0.05 * R
    )  # bench/standing/reconstruction.md: 1.1-1.6 % R on disc meshes


def test_electrodes_crowded_into_one_half_leave_the_other_half_worse():
    even = predict_accuracy(disc_patch().layers[0], quality="preview", cache_dir=None)
    half = [round(0.5 * k / 16, 6) for k in range(16)]  # all on the upper half (y > 0)
    crowded = predict_accuracy(
        disc_patch(positions=half).layers[0],
        quality="preview",
        cache_dir=None,
        centres=even.centres,
    )
    lower = even.centres[:, 1] < -0.3 * R
    assert np.median(crowded.position_error_m[lower]) > 2 * np.median(even.position_error_m[lower])
    assert np.median(crowded.resolution[lower]) > np.median(even.resolution[lower])


def test_predict_command_line_json_and_png(tmp_path, capsys):
    out_json, out_png = tmp_path / "face.json", tmp_path / "face.png"
    args = ["face", "--predict", "--quality", "preview", "--json", str(out_json)]
    code = main(["patch", *args, "--png", str(out_png)])
    printed = capsys.readouterr().out
    assert code == 0
    line = next(x for x in printed.splitlines() if "predicted pressure:" in x)
    assert "[greit, noise figure 0.13," in line
    data = json.loads(out_json.read_text())
    layer = data["layers"][0]
    summary = layer["summary"]
    errors = np.array(layer["phantoms"]["position_error_m"])
    assert summary["position_error_worst_m"] == pytest.approx(errors.max(), abs=1e-7)
    assert f"worst {summary['position_error_worst_m'] * 1e3:.2f} mm" in line
    assert summary["position_error_median_m"] == pytest.approx(np.median(errors), abs=1e-7)
    pe_map = np.array(layer["maps"]["position_error_m"], dtype=float)
    assert pe_map.shape == (len(layer["y_m"]), len(layer["x_m"]))
    assert np.nanmax(pe_map) == pytest.approx(errors.max(), rel=1e-6)
    assert out_png.stat().st_size > 10_000
