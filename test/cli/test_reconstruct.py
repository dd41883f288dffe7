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
    with np.load(out) as d:  # the node's physical image (Pa) of the same frames
        physical, imaged = d["physical"], d["imaged"]
    assert physical.dtype == np.float32 and physical.shape == images.shape and imaged.all()
    assert np.nanmax(np.abs(physical[0])) == 0.0
    assert np.nanargmax(physical[1]) == np.nanargmax(images[1]) and np.nanmax(physical[1]) > 1e3


def test_capture_reference_like_the_node(frames_file, tmp_path):
    """--reference capture: the first frames become the reference and are not imaged."""
    path, centre = frames_file
    with np.load(path) as d:
        ref, touched = d["frames"]
    src = tmp_path / "in.npz"
    t = 100.0 + 0.1 * np.arange(5)
    # the file's reference is deliberately wrong: capture mode must not use it
    np.savez(src, reference=0.9 * ref, frames=np.stack([ref, ref, ref, touched, ref]), t=t)
    out = tmp_path / "out.npz"
    args = ["reconstruct", "--patch", "arm", "--frames", str(src), "--out", str(out)]
    assert main([*args, "--reference", "capture", "--reference-frames", "3"]) == 0
    with np.load(out) as d:
        images, imaged, t_out, x, y = d["images"], d["imaged"], d["t"], d["x"], d["y"]
    assert imaged.tolist() == [False, False, False, True, True]
    assert np.isnan(images[:3]).all() and np.array_equal(t_out, t)
    k = np.unravel_index(np.nanargmax(images[3]), images[3].shape)
    assert np.hypot(x[k[1]] - centre[0], y[k[0]] - centre[1]) < 0.006
    assert np.nanmax(np.abs(images[4])) < 1e-9  # back to the captured reference
    assert main([*args, "--reference", "capture", "--rate", "10"]) == 0  # 20 frames: none left
    with np.load(out) as d:
        assert not d["imaged"].any() and np.array_equal(d["t"], np.arange(5) / 10.0)


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
        # one NaN reference channel is left out (test_channel_noise.py); all of them: an error
        ({"reference": np.full(208, np.nan), "frames": np.ones((2, 208))}, "zero or non-finite"),
        ({"reference": np.ones(208), "frames": np.ones((2, 208)), "rate": 0}, "--rate: must be"),
        ({"reference": np.ones(208), "frames": np.ones((2, 208)), "n": -1}, "--reference-frames"),
    ],
)
def test_bad_input_one_line_nothing_written(tmp_path, capsys, content, message):
    src = tmp_path / "in.npz"
    options = []
    if "rate" in content:
        options += ["--rate", str(content.pop("rate"))]
    if "n" in content:
        options += ["--reference-frames", str(content.pop("n"))]
    np.savez(src, **content)
    out = tmp_path / "out.npz"
    args = ["reconstruct", "--patch", "arm", "--frames", str(src), "--out", str(out)]
    assert main([*args, *options]) == 1
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
