"""``eit-skin patch``: summary and exit 0 for good files, one-line reason and exit 1 for bad."""

from __future__ import annotations

from pathlib import Path

import yaml

from eit_skin.cli.main import main

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_summary_of_shipped_patch(capsys):
    assert main(["patch", str(CONFIG / "arm.yaml")]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert "frame_id: arm_skin_link" in out
    assert "layer 'pressure'" in out and "layer 'stretch'" in out
    assert out.count("16 injections, 208 measurements per frame") == 2
    assert "outline: circle, 80.0 x 80.0 mm" in out
    assert "placement: cylinder r=0.058 m" in out
    holes = [line for line in out.splitlines() if "holes:" in line]
    assert holes[0].strip() == "holes: 0" and int(holes[1].split()[-1]) > 40
    assert out.count("triangles") == 2


def test_shipped_patch_by_name(capsys):
    assert main(["patch", "elbow"]) == 0
    out, _ = capsys.readouterr()
    assert "frame_id: elbow_skin_link" in out
    assert "outline: rectangle, 90.0 x 160.0 mm" in out


def test_bad_patch_prints_one_line_reason(tmp_path, capsys):
    data = yaml.safe_load((CONFIG / "elbow.yaml").read_text())
    data["layers"][0]["electrodes"]["positions"][3] = [0.03, -0.01]  # 15 mm inside the sheet
    path = tmp_path / "elbow_bad.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["patch", str(path)]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert f"{path}: layers[0].electrodes.positions[3]: point is 15 mm off the outline" in lines[0]


def test_missing_file(tmp_path, capsys):
    assert main(["patch", str(tmp_path / "none.yaml")]) == 1
    _, err = capsys.readouterr()
    assert "none.yaml" in err and len(err.strip().splitlines()) == 1


def test_png(tmp_path, capsys):
    out_png = tmp_path / "face.png"
    assert main(["patch", "face", "--png", str(out_png)]) == 0
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out_png.stat().st_size > 10_000
    assert f"wrote {out_png}" in capsys.readouterr().out


def test_oversized_mesh_is_refused_before_meshing(tmp_path, capsys, monkeypatch):
    import triangle

    def triangulate(*args, **kwargs):
        raise AssertionError("eit-skin patch started meshing")

    monkeypatch.setattr(triangle, "triangulate", triangulate)
    data = yaml.safe_load((CONFIG / "elbow.yaml").read_text())
    data["layers"][0]["mesh"].update(max_edge=1.0e-5, electrode_edge=1.0e-5)
    path = tmp_path / "elbow_fine.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["patch", str(path)]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert f"{path}: layers[0].mesh.max_edge: ~" in lines[0]
    assert "GiB" in lines[0] and "max_edge >= " in lines[0] and lines[0].endswith("would fit")
