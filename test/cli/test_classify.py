"""``eit-skin classify`` end to end on a short simulated elbow push (cached imager)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator


@pytest.fixture(scope="module")
def elbow_push(tmp_path_factory):
    out = tmp_path_factory.mktemp("push")
    patch = load_patch(config_path("elbow"))
    recording = SkinSimulator(patch, "push", rate_hz=50.0, seed=11).run()
    recording.save(out)
    return out, recording.truth[0]


def test_classify_prints_the_finished_push(elbow_push, capsys, monkeypatch, tmp_path) -> None:
    out, truth = elbow_push
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path.parent / "imager-cache"))
    code = main(
        ["classify", "--patch", "elbow", "--frames", str(out / "pressure.npz"), "--rate", "50"]
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert code == 0 and len(lines) == 1
    event = json.loads(lines[0])
    assert set(event) == {
        *("label", "t_start", "t_end", "confidence", "centroid", "position", "normal"),
        *("fault", "faulty_electrodes", "channels_left_out"),
    }
    placement = load_patch(config_path("elbow")).placement
    on_surface = placement.to_3d([event["centroid"]])[0]
    assert event["position"] == pytest.approx(list(on_surface), abs=1e-4)  # centroid rounded
    assert event["normal"] == pytest.approx(
        list(placement.normals([event["centroid"]])[0]), abs=1e-3
    )
    assert not event["fault"] and not event["faulty_electrodes"]
    assert event["channels_left_out"] == 0
    assert event["label"] == "push"
    assert truth.t_start_s <= event["t_start"] <= truth.t_start_s + 0.15
    assert event["t_end"] == pytest.approx(truth.t_end_s, abs=0.15)
    assert event["centroid"] == pytest.approx(list(truth.contacts[0]), abs=0.01)
    assert 0.0 <= event["confidence"] <= 1.0


def test_frame_times_come_from_the_file_without_rate(elbow_push, capsys, monkeypatch, tmp_path):
    """The simulator's t is k / 50 Hz: the same event as with --rate 50, to the bit."""
    out, _ = elbow_push
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path.parent / "imager-cache"))
    base = ["classify", "--patch", "elbow", "--frames", str(out / "pressure.npz")]
    assert main([*base, "--rate", "50"]) == 0
    with_rate = capsys.readouterr().out
    assert main(base) == 0
    assert capsys.readouterr().out == with_rate and '"push"' in with_rate
    with np.load(out / "pressure.npz") as data:
        np.savez(tmp_path / "no_t.npz", reference=data["reference"], frames=data["frames"][:5])
    assert main([*base[:-1], str(tmp_path / "no_t.npz")]) == 1
    err = capsys.readouterr().err
    assert "no_t.npz: no 't'" in err and "give --rate" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frames", "/nonexistent.npz", "--rate", "50"], "/nonexistent.npz: no such file"),
        (["--frames", "{out}/pressure.npz", "--rate", "0"], "--rate: must be > 0"),
        (
            ["--frames", "{out}/pressure.npz", "--rate", "50", "--stretch-frames", "x.npz"],
            "has no layer measuring stretch",
        ),
    ],
)
def test_bad_input_is_one_line_error(elbow_push, capsys, extra, message) -> None:
    out, _ = elbow_push
    args = ["classify", "--patch", "elbow"] + [a.format(out=out) for a in extra]
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err and err.startswith("eit-skin classify: error:")
