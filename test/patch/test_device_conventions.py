"""Device conventions of the patch schema (docs/real-devices.md): every way a board may send
the same measurement gives the same image as the canonical layout, and bad input is refused
with one line naming the file, key and channel, nothing written."""

import re

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import patch_from_dict
from eit_skin.patch.model import PatchError
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import forward_model

K = 5  # untouched frames giving the noise level
T = 3  # frames with the target


def _patch(protocol=None):
    layer = {
        "name": "skin",
        "outline": {"type": "circle", "radius": 0.05},
        "electrodes": {"count": 16, "width": 0.008, "contact_impedance": 0.005},
        "material": {"quantity": "pressure", "sheet_conductance": 1.0, "pressure_scale": 1e4},
        "protocol": protocol or {},
        "mesh": {"max_edge": 0.006},
        "solver": {"noise_figure": 0.5, "image_pixels": 24},
    }
    return {"name": "conv", "frame_id": "skin_link", "layers": [layer]}


def _write_patch(tmp_path, name, protocol=None):
    import yaml

    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(_patch(protocol)))
    return path


def _simulate(protocol_keys):
    """(reference [M], frames [K + T, M]) in the board's order for ``protocol_keys``."""
    layer = patch_from_dict(_patch(protocol_keys)).layers[0]
    model = forward_model(layer, build_mesh(layer))
    centroids = model.mesh.nodes[model.mesh.triangles].mean(axis=1)
    sigma = np.ones(model.n_elements)
    sigma[np.hypot(*(centroids - [0.02, 0.01]).T) < 0.01] = 2.0
    v0, v1 = model.voltages(1.0), model.voltages(sigma)
    rng = np.random.default_rng(0)
    noise = 1e-4 * np.abs(v0).mean() * rng.standard_normal((K + T, v0.size))
    frames = np.vstack([np.tile(v0, (K, 1)), np.tile(v1, (T, 1))]) + noise
    return v0, frames


def _reconstruct(tmp_path, name, patch_path, **arrays):
    src = tmp_path / f"{name}.npz"
    np.savez(src, **arrays)
    out = tmp_path / f"{name}-out.npz"
    args = ["reconstruct", "--patch", str(patch_path), "--frames", str(src), "--out", str(out)]
    opts = ["--reference-frames", str(K), "--drift-time-constant", "0", "--cache-dir", "none"]
    assert main([*args, *opts]) == 0
    with np.load(out) as data:
        return data["images"][K:]


@pytest.fixture(scope="module")
def canonical(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("canonical")
    v0, frames = _simulate({})
    images = _reconstruct(tmp, "canon", _write_patch(tmp, "canon"), reference=v0, frames=frames)
    assert np.nanmax(images) > 0.1  # the target shows
    return v0, frames, images


def _same_image(images, canonical_images):
    inside = ~np.isnan(canonical_images)
    np.testing.assert_array_equal(np.isnan(images), ~inside)
    scale = np.abs(canonical_images[inside]).max()
    np.testing.assert_allclose(images[inside], canonical_images[inside], atol=1e-4 * scale)


def test_full_layout_frames_give_the_canonical_image(tmp_path, canonical):
    v0, frames, images = canonical
    keys = {"layout": "full"}
    protocol = build_protocol(patch_from_dict(_patch(keys)).layers[0].protocol, 16)
    full, full_frames = protocol.device_frame(v0), protocol.device_frame(frames)
    assert full.shape == (256,) and np.count_nonzero(full == 0) == 48
    got = _reconstruct(
        tmp_path, "full", _write_patch(tmp_path, "full", keys), reference=full, frames=full_frames
    )
    _same_image(got, images)


def test_clockwise_numbering_gives_the_canonical_image(tmp_path, canonical):
    keys = {"electrode_order": [0, *range(15, 0, -1)]}
    v0, frames, images = canonical
    cw = build_protocol(patch_from_dict(_patch(keys)).layers[0].protocol, 16)
    canon = build_protocol(patch_from_dict(_patch()).layers[0].protocol, 16)
    # a clockwise board's channel is a canonical one with drive and measure pairs reversed
    index = {(*canon.injections[k], p, q): i for i, (k, p, q) in enumerate(canon.measurements)}
    perm = [index[(*cw.injections[k][::-1], q, p)] for k, p, q in cw.measurements]
    board_v0, board_frames = v0[perm], frames[:, perm]  # the same noise on the same channel
    simulated, _ = _simulate(keys)  # what the model says that board measures, in its order
    np.testing.assert_allclose(board_v0, simulated, rtol=1e-9, atol=1e-12)
    assert not np.allclose(board_v0, v0)
    patch = _write_patch(tmp_path, "cw", keys)
    got = _reconstruct(tmp_path, "cw", patch, reference=board_v0, frames=board_frames)
    _same_image(got, images)


def test_magnitude_and_complex_frames_give_the_canonical_image(tmp_path, canonical):
    v0, frames, images = canonical
    assert (v0 < 0).any()  # the signs are really lost in |V|
    keys = {"values": "magnitude"}
    got = _reconstruct(
        tmp_path,
        "mag",
        _write_patch(tmp_path, "mag", keys),
        reference=np.abs(v0),
        frames=np.abs(frames),
    )
    _same_image(got, images)
    # complex frames: the real part (default) with an unrelated quadrature part
    quad = 1j * 0.3 * np.abs(v0).mean()
    got = _reconstruct(
        tmp_path, "cplx", _write_patch(tmp_path, "cplx"), reference=v0 + quad, frames=frames + quad
    )
    _same_image(got, images)
    # the magnitude of complex frames (signs from the model)
    keys = {"complex_part": "magnitude"}
    got = _reconstruct(
        tmp_path,
        "cmag",
        _write_patch(tmp_path, "cmag", keys),
        reference=v0 * np.exp(0.2j),
        frames=frames * np.exp(0.2j),
    )
    _same_image(got, images)


def test_per_press_references_give_the_canonical_image(tmp_path, canonical):
    v0, frames, images = canonical
    drift = 1.0 + np.r_[np.zeros(K), 0.2 * np.arange(1, T + 1)]  # each press at its own gain
    references = np.vstack([frames[:K], np.tile(v0, (T, 1))]) * drift[:, None]
    got = _reconstruct(
        tmp_path,
        "press",
        _write_patch(tmp_path, "press"),
        reference=v0,
        frames=frames * drift[:, None],
        references=references,
    )
    _same_image(got, images)
    # without the references the gain change would show as a change everywhere
    wrong = _reconstruct(
        tmp_path,
        "nopress",
        _write_patch(tmp_path, "nopress"),
        reference=v0,
        frames=frames * drift[:, None],
    )
    assert np.nanmax(np.abs(wrong - images)) > 0.1 * np.nanmax(np.abs(images))


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        (
            {
                "reference": np.ones(208),
                "frames": np.ones((2, 208)),
                "references": np.ones((3, 208)),
            },
            "'references' must have the shape of 'frames'",
        ),
        (
            {"reference": np.ones(208), "frames": np.ones((2, 208), dtype=bool)},
            "'frames' must be real or complex numbers",
        ),
        ({"reference": np.ones(256), "frames": np.ones((2, 256))}, "expects 208 numbers"),
    ],
)
def test_bad_frames_files_name_the_key(tmp_path, capsys, arrays, message):
    src = tmp_path / "in.npz"
    np.savez(src, **arrays)
    out = tmp_path / "out.npz"
    patch = _write_patch(tmp_path, "p")
    args = ["reconstruct", "--patch", str(patch), "--frames", str(src), "--out", str(out)]
    assert main([*args, "--cache-dir", "none"]) == 1
    err = capsys.readouterr().err
    assert message in err and str(src) in err and err.count("\n") == 1
    assert not out.exists()


def test_per_press_references_refuse_capture(tmp_path, capsys):
    src = tmp_path / "in.npz"
    np.savez(src, reference=np.ones(208), frames=np.ones((2, 208)), references=np.ones((2, 208)))
    out = tmp_path / "out.npz"
    args = [
        "reconstruct",
        "--patch",
        str(_write_patch(tmp_path, "p")),
        "--frames",
        str(src),
        "--out",
        str(out),
        "--reference",
        "capture",
        "--cache-dir",
        "none",
    ]
    assert main(args) == 1
    assert "per-press 'references'" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize(
    ("protocol", "where"),
    [
        ({"electrode_order": [0, 1, 2, 2, *range(4, 16)]}, "protocol.electrode_order"),
        ({"layout": "wide"}, "protocol.layout"),
        ({"values": "abs"}, "protocol.values"),
        ({"complex_part": "imag"}, "protocol.complex_part"),
        (
            {"drive": "currents", "currents": [[1, -1] + [0] * 14, [1, 1] + [0] * 14]},
            "protocol.currents[1]",
        ),
        ({"drive": "currents", "currents": [[1, -1, 0]]}, "protocol.currents[0]"),
        ({"measure_driven": "yes"}, "protocol.measure_driven"),
    ],
)
def test_bad_convention_keys_name_the_key(protocol, where):
    with pytest.raises(PatchError, match=re.escape(f"p.yaml: layers[0].{where}")):
        patch_from_dict(_patch(protocol), source="p.yaml")


def test_per_electrode_contact_impedance_is_checked():
    data = _patch()
    data["layers"][0]["electrodes"]["contact_impedance"] = [0.01] * 15
    with pytest.raises(PatchError, match=r"electrodes.contact_impedance: 15 values for 16"):
        patch_from_dict(data, source="p.yaml")
    data["layers"][0]["electrodes"]["contact_impedance"] = [0.01] * 15 + [-1]
    with pytest.raises(PatchError, match=r"contact_impedance\[15\]: must be > 0"):
        patch_from_dict(data, source="p.yaml")


def test_simulated_magnitude_board_reports_magnitudes_and_images_like_a_signed_one():
    from eit_skin.pipeline.builder import LayerImager
    from eit_skin.sim.simulator import SkinSimulator

    signed = patch_from_dict(_patch())
    magnitude = patch_from_dict(_patch({"values": "magnitude"}))
    frames = {}
    for name, patch in (("signed", signed), ("magnitude", magnitude)):
        sim = SkinSimulator(patch, "idle", rate_hz=20.0, seed=4)
        frames[name] = sim.run(n_frames=3).layers["skin"].frames
    assert (frames["signed"] < 0).any() and (frames["magnitude"] >= 0).all()
    np.testing.assert_allclose(frames["magnitude"], np.abs(frames["signed"]))
    # the magnitude layer's imager restores the signs: the reference check passes
    imager = LayerImager.build(magnitude.layers[0], cache_dir=None)
    report = imager.use_reference(frames["magnitude"][0])
    assert not report.check.excluded.any()
    # and full-layout frames recorded after the driver (M numbers) are read as they are
    full = build_protocol(patch_from_dict(_patch({"layout": "full"})).layers[0].protocol, 16)
    np.testing.assert_array_equal(full.select(frames["signed"]), frames["signed"])


def test_driver_picks_the_used_entries_of_a_full_frame_and_rejects_other_sizes():
    from eit_skin.hardware.sources import LayerFrameFactory
    from eit_skin.hardware.wire import DeviceFrame, PatternId

    patch = patch_from_dict(_patch({"layout": "full"}))
    layer = patch.layers[0]
    factory = LayerFrameFactory(patch, layer, "skin_link")
    protocol = factory.protocol
    values = np.arange(256, dtype=np.float64) + 1.0
    flags = np.zeros(256, dtype=np.uint8)
    flags[protocol.frame_index[7]] = 1  # the 8th used channel is flagged on the wire

    def frame(v, f=None):
        return DeviceFrame(1, 0, 16, PatternId.ADJACENT, 1e-3, v, f)

    assert factory.reject(frame(values, flags)) is None
    record = factory.device_record(0, 1, values, flags)
    np.testing.assert_array_equal(record.voltages, protocol.frame_index + 1.0)
    assert record.channel_flags.shape == (208,) and np.flatnonzero(record.channel_flags) == [7]
    reason, text = factory.reject(frame(values[:208]))
    assert reason == "values" and "expects 256 (full layout)" in text


def test_convention_keys_enter_the_content_hash_only_when_set():
    def digest(protocol):
        return patch_from_dict(_patch(protocol)).layers[0].content_hash

    plain = digest({})
    assert digest({"layout": "compact", "values": "signed", "complex_part": "real"}) == plain
    changed = [
        digest(p)
        for p in (
            {"layout": "full"},
            {"values": "magnitude"},
            {"complex_part": "magnitude"},
            {"measure_driven": True},
            {"electrode_order": [0, *range(15, 0, -1)]},
            {"drive": "trigonometric"},
        )
    ]
    assert plain not in changed and len(set(changed)) == len(changed)
