"""Offline commands stream their files: block-wise reading/writing, same output as one block,
bad frames skipped and counted instead of aborting the run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.frames import FrameRecord
from eit_skin.io.conversion import mcap_to_npz
from eit_skin.io.mcap import McapFrameWriter
from eit_skin.io.npz import FramesNpzReader, NpzStreamWriter, load_frames_npz
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator


@pytest.mark.parametrize("save", [np.savez, np.savez_compressed])
@pytest.mark.parametrize("fortran", [False, True])
def test_reader_gives_the_file_block_by_block(tmp_path, save, fortran):
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(10, 6)).astype(np.float32)
    frames = np.asfortranarray(frames) if fortran else frames
    t = 5.0 + np.arange(10) * 0.02
    save(tmp_path / "f.npz", reference=np.ones(6), frames=frames, t=t)
    reader = FramesNpzReader(tmp_path / "f.npz", 6, block_frames=3)
    blocks = list(reader.blocks())
    assert [start for start, _, _ in blocks] == [0, 3, 6, 9]
    assert [len(f) for _, f, _ in blocks] == [3, 3, 3, 1]
    ref, whole, whole_t = load_frames_npz(tmp_path / "f.npz", 6)
    assert np.array_equal(np.concatenate([f for _, f, _ in blocks]), whole)
    assert np.array_equal(np.concatenate([b for _, _, b in blocks]), whole_t)
    assert np.array_equal(reader.reference, ref) and reader.n_frames == 10
    assert np.array_equal(reader.head(4), whole[:4]) and len(reader.head(99)) == 10


def test_reader_names_key_and_frame_of_bad_values(tmp_path):
    t = np.arange(8.0)
    t[5] = np.nan
    np.savez(tmp_path / "t.npz", reference=np.ones(4), frames=np.ones((8, 4)), t=t)
    reader = FramesNpzReader(tmp_path / "t.npz", block_frames=3)
    with pytest.raises(ValueError, match=r"t\.npz: 't' must be finite, frame 5"):
        list(reader.blocks())
    np.savez(tmp_path / "m.npz", reference=np.ones(4), frames=np.ones((8, 5)))
    with pytest.raises(ValueError, match=r"'frames' must have shape \[T>=1, M=4\].*\(8, 5\)"):
        FramesNpzReader(tmp_path / "m.npz")
    # a member cut short (zip rewritten with a truncated frames.npy)
    import zipfile

    with zipfile.ZipFile(tmp_path / "m.npz") as archive:
        data = archive.read("frames.npy")
    with zipfile.ZipFile(tmp_path / "cut.npz", "w") as archive:
        archive.writestr("reference.npy", _npy(np.ones(5)))
        archive.writestr("frames.npy", data[: len(data) - 5 * 8 * 3])
    with pytest.raises(ValueError, match="'frames' is cut short: it ends at frame 5 of 8"):
        list(FramesNpzReader(tmp_path / "cut.npz", block_frames=2).blocks())


def _npy(array: np.ndarray) -> bytes:
    import io

    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def test_stream_writer_is_complete_or_absent(tmp_path):
    out = tmp_path / "o.npz"
    with NpzStreamWriter(out, {"a": ((5, 2), np.float32), "b": ((None,), np.int64)}) as w:
        w.append(a=np.zeros((3, 2)), b=np.arange(2))
        w.append(a=np.ones((2, 2)), b=np.arange(3))
    with np.load(out) as d:
        assert d["a"].dtype == np.float32 and d["a"].tolist() == [[0, 0]] * 3 + [[1, 1]] * 2
        assert d["b"].tolist() == [0, 1, 0, 1, 2]
    with (
        pytest.raises(ValueError, match="'a' got 1 of 5 rows"),
        NpzStreamWriter(out, {"a": ((5, 2), np.float32)}) as w,
    ):
        w.append(a=np.zeros((1, 2)))
    with (
        pytest.raises(RuntimeError),
        NpzStreamWriter(tmp_path / "n.npz", {"a": ((None,), np.float32)}) as w,
    ):
        w.append(a=np.zeros(3))
        raise RuntimeError("killed half way")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.npz"]  # the old one untouched
    with np.load(out) as d:
        assert d["a"].shape == (5, 2)


@pytest.fixture(scope="module")
def elbow_push(tmp_path_factory):
    """A simulated elbow push (pressure.npz with t) with two all-NaN frames (3 and 60)."""
    out = tmp_path_factory.mktemp("stream")
    recording = SkinSimulator(load_patch(config_path("elbow")), "push", rate_hz=50.0, seed=11)
    recording.run().save(out)
    with np.load(out / "pressure.npz") as d:
        data = dict(d)
    data["frames"][[3, 60]] = np.nan
    np.savez(out / "bad.npz", **data)
    return out


def _reconstruct(src, out, *options):
    args = ["reconstruct", "--patch", "elbow", "--frames", str(src), "--out", str(out)]
    return main([*args, *options])


def test_reconstruct_block_wise_is_the_one_block_run(elbow_push, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path.parent / "imager-cache"))
    src = elbow_push / "bad.npz"
    n = FramesNpzReader(src).n_frames
    assert n > 40
    assert _reconstruct(src, tmp_path / "one.npz", "--block-frames", str(n)) == 0
    assert _reconstruct(src, tmp_path / "blocks.npz", "--block-frames", "16") == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "skipped 2 frame(s)" in err[0] and "(frame 3, 60)" in err[0]
    with np.load(tmp_path / "one.npz") as one, np.load(tmp_path / "blocks.npz") as blocks:
        assert sorted(one.files) == ["imaged", "images", "physical", "t", "x", "y"]
        for key in one.files:
            assert np.array_equal(one[key], blocks[key], equal_nan=key != "imaged"), key
        imaged, physical = one["imaged"], one["physical"]
    assert not imaged[[3, 60]].any() and imaged.sum() == n - 2
    assert np.isnan(physical[[3, 60]]).all() and np.nanmax(physical) > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocks.npz", "one.npz"]


def test_classify_block_wise_goes_past_bad_frames(elbow_push, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path.parent / "imager-cache"))
    events = []
    for name, block in (("pressure.npz", "100000"), ("bad.npz", "16")):
        args = ["classify", "--patch", "elbow", "--frames", str(elbow_push / name)]
        assert main([*args, "--block-frames", block]) == 0
        out, err = capsys.readouterr()
        events.append([json.loads(line)["label"] for line in out.splitlines()])
    assert events[0] == events[1] == ["push"]
    assert "bad.npz: skipped 2 frame(s)" in err and "(frame 3, 60)" in err


def test_frames_export_in_blocks_is_the_whole_export(tmp_path):
    rng = np.random.default_rng(1)
    with McapFrameWriter(tmp_path / "r.mcap") as writer:
        for i in range(11):
            volts = rng.normal(0, 0.1, 8).astype(np.float32)
            flags = np.zeros(8, np.uint8) if i else np.r_[0, 2, np.zeros(6)].astype(np.uint8)
            writer.write(
                "/arm/pressure/frames",
                FrameRecord(
                    10**18 + i * 20_000_000,
                    "arm",
                    "arm",
                    "pressure",
                    4,
                    "adjacent",
                    1e-3,
                    i,
                    volts,
                    flags,
                ),
            )
    assert mcap_to_npz(tmp_path / "r.mcap", tmp_path / "a.npz", reference_frames=4) == 11
    n = mcap_to_npz(tmp_path / "r.mcap", tmp_path / "b.npz", reference_frames=4, block_frames=3)
    assert n == 11
    a, b = load_frames_npz(tmp_path / "a.npz"), load_frames_npz(tmp_path / "b.npz")
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y, equal_nan=True)
    assert a[1].shape == (11, 8) and np.isnan(a[1][0, 1]) and np.isfinite(a[0]).all()
