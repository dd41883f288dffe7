from __future__ import annotations

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.resources import config_path


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    layer = load_patch(config_path("arm")).layers[0]
    mesh = build_mesh(layer, 0.002)  # finer than the patch's own meshes
    fwd = ForwardModel(
        mesh,
        build_protocol(layer.protocol, layer.n_electrodes),
        layer.contact_impedance_ohm_m,
        layer.current_a,
    )
    s0 = layer.material.sheet_conductance_s
    ref = fwd.voltages(s0)
    sigma = np.full(mesh.n_triangles, s0)
    centre = np.array([0.015, 0.01])
    sigma[np.linalg.norm(mesh.centroids - centre, axis=1) < 0.006] *= 2
    path = tmp_path_factory.mktemp("cli") / "in.npz"
    np.savez(path, reference=ref, frames=np.stack([ref, fwd.voltages(sigma)]))
    return path, centre


def test_reconstruct_writes_images(frames_file, tmp_path, capsys):
    path, centre = frames_file
    out = tmp_path / "out.npz"
    assert main(["reconstruct", "--patch", "arm", "--frames", str(path), "--out", str(out)]) == 0
    with np.load(out) as d:
        images, x, y = d["images"], d["x"], d["y"]
    assert images.dtype == np.float32 and images.shape == (2, y.size, x.size)
    assert np.isnan(images[:, 0, 0]).all()  # corner of the square grid is off the disk
    assert np.nanmax(np.abs(images[0])) == 0.0  # the reference frame itself: no change
    k = np.unravel_index(np.nanargmax(images[1]), images[1].shape)
    assert np.hypot(x[k[1]] - centre[0], y[k[0]] - centre[1]) < 0.006
    assert [p.name for p in tmp_path.iterdir()] == ["out.npz"]


def test_reconstruct_with_gauss_newton(frames_file, tmp_path):
    """--method gauss_newton: same contract, the doubled-conductance disc found with its sign."""
    path, centre = frames_file
    out = tmp_path / "gn.npz"
    args = ["reconstruct", "--patch", "arm", "--frames", str(path), "--out", str(out)]
    assert main([*args, "--method", "gauss_newton"]) == 0
    with np.load(out) as d:
        images, x, y = d["images"], d["x"], d["y"]
    assert images.dtype == np.float32 and images.shape == (2, y.size, x.size)
    assert np.nanmax(np.abs(images[0])) < 1e-6  # reference frame: no change
    k = np.unravel_index(np.nanargmax(images[1]), images[1].shape)
    assert np.hypot(x[k[1]] - centre[0], y[k[0]] - centre[1]) < 0.006
    assert np.nanmax(images[1]) > 0.2  # contrast x2 = +100 %: clearly positive
    assert np.isfinite(images[1][~np.isnan(images[1])]).all()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ({"frames": np.zeros((2, 208))}, "missing key 'reference'"),
        ({"reference": np.ones(100), "frames": np.ones((2, 100))}, "expects 208"),
        ({"reference": np.r_[np.nan, np.ones(207)], "frames": np.ones((2, 208))}, "non-finite"),
    ],
)
def test_bad_input_one_line_nothing_written(tmp_path, capsys, content, message):
    src = tmp_path / "in.npz"
    np.savez(src, **content)
    out = tmp_path / "out.npz"
    assert main(["reconstruct", "--patch", "arm", "--frames", str(src), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["in.npz"]


def test_unreadable_and_missing_files(tmp_path, capsys):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    out = tmp_path / "out.npz"
    for src in (junk, tmp_path / "absent.npz"):
        assert main(["reconstruct", "--patch", "arm", "--frames", str(src), "--out", str(out)]) == 1
        assert capsys.readouterr().err.count("\n") == 1
    assert not out.exists()
