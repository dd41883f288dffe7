"""CAD import: hand-made DXF and SVG drawings -> patch files, and every refused geometry.

The DXF files are written with ezdxf entity by entity (lines, bulged polylines, arcs, circles,
splines; mm and inch headers), the SVG files by hand; each import is checked against the
drawing's analytic size, area or curve, and each refusal against the entity it must name.
"""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.fem.mesh import build_mesh
from eit_skin.patch import geometry
from eit_skin.patch.cad_import import CadError, area_m2, read_drawing
from eit_skin.patch.cad_patch import patch_data
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.resources import config_path

TOL = 5e-5  # m, the default flattening tolerance


def dxf(path: Path, units: int = 4) -> tuple[ezdxf.document.Drawing, object]:
    doc = ezdxf.new(units=units)
    return doc, doc.modelspace()


def rectangle_lines(msp, w: float, h: float, layer: str = "sheet") -> None:
    corners = [(0, 0), (w, 0), (w, h), (0, h)]
    for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
        msp.add_line(a, b, dxfattribs={"layer": layer})


def test_dxf_lines_hole_and_marks_in_mm(tmp_path):
    doc, msp = dxf(tmp_path)
    rectangle_lines(msp, 100.0, 60.0)  # four separate LINEs, chained into one loop
    msp.add_circle((50.0, 30.0), 10.0, dxfattribs={"layer": "sheet"})
    for x, y in [(10, 0), (90, 0), (100, 30), (90, 60), (10, 60), (0, 30)]:
        msp.add_point((x, y), dxfattribs={"layer": "electrodes"})
    doc.saveas(tmp_path / "plate.dxf")
    drawing = read_drawing(tmp_path / "plate.dxf")
    assert drawing.units == "mm"
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([0.1, 0.06])
    assert len(drawing.holes) == 1
    # the flattened circle loses at most the sagitta band: area within 2 pi r tol
    exact = 0.1 * 0.06 - math.pi * 0.01**2
    assert area_m2(drawing) == pytest.approx(exact, abs=2 * math.pi * 0.01 * TOL)
    hole = drawing.holes[0]
    assert np.linalg.norm(hole - [0.05, 0.03], axis=1) == pytest.approx(0.01, abs=TOL)
    middles = 0.5 * (hole + np.roll(hole, -1, axis=0))  # chords within TOL of the circle
    assert np.linalg.norm(middles - [0.05, 0.03], axis=1) == pytest.approx(0.01, abs=TOL)
    assert geometry.signed_area(drawing.holes[0]) < 0 < geometry.signed_area(drawing.outline)
    data = patch_data(drawing, "plate")
    patch = patch_from_dict(data)
    layer = patch.layers[0]
    assert layer.n_electrodes == 6 and len(layer.holes) == 1
    centres = np.array([e.center for e in layer.electrodes])
    marks = {(round(x, 6), round(y, 6)) for x, y in centres}
    assert marks == {(0.01, 0.0), (0.09, 0.0), (0.1, 0.03), (0.09, 0.06), (0.01, 0.06), (0.0, 0.03)}


def test_dxf_bulged_polyline_in_inches_is_flattened_within_tolerance(tmp_path):
    # a 4 x 2 in rounded rectangle: corners of radius 0.5 in as polyline bulges (90 deg arcs)
    r, w, h = 0.5, 4.0, 2.0
    bulge = math.tan(math.pi / 8)
    pts = [
        (r, 0, 0, 0, 0),
        (w - r, 0, 0, 0, bulge),
        (w, r, 0, 0, 0),
        (w, h - r, 0, 0, bulge),
        (w - r, h, 0, 0, 0),
        (r, h, 0, 0, bulge),
        (0, h - r, 0, 0, 0),
        (0, r, 0, 0, bulge),
    ]
    doc, msp = dxf(tmp_path, units=1)
    msp.add_lwpolyline(pts, format="xyseb", close=True)
    doc.saveas(tmp_path / "rounded.dxf")
    drawing = read_drawing(tmp_path / "rounded.dxf")
    assert drawing.units == "in"
    inch = 0.0254
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([w * inch, h * inch], abs=1e-9)
    exact = (w * h - (4 - math.pi) * r * r) * inch**2
    assert area_m2(drawing) == pytest.approx(exact, abs=2 * math.pi * r * inch * TOL)
    # every chord of the lower-left corner arc stays within the tolerance of the arc
    centre = np.array([r, r]) * inch
    corner = drawing.outline[
        (drawing.outline[:, 0] < r * inch) & (drawing.outline[:, 1] < r * inch)
    ]
    assert np.linalg.norm(corner - centre, axis=1) == pytest.approx(r * inch, abs=TOL)
    angles = np.arctan2(corner[:, 1] - centre[1], corner[:, 0] - centre[0])
    ordered = corner[np.argsort(angles)]
    middles = 0.5 * (ordered[1:] + ordered[:-1])
    assert np.linalg.norm(middles - centre, axis=1) == pytest.approx(r * inch, abs=TOL)
    assert ordered.shape[0] >= 4  # the arc was flattened, not cut as one chord


def test_dxf_arcs_and_lines_make_a_stadium(tmp_path):
    doc, msp = dxf(tmp_path)
    msp.add_line((0, 0), (40, 0))
    msp.add_arc((40, 10), 10, -90, 90)
    msp.add_line((40, 20), (0, 20))
    msp.add_arc((0, 10), 10, 90, 270)
    doc.saveas(tmp_path / "stadium.dxf")
    drawing = read_drawing(tmp_path / "stadium.dxf")
    exact = (40 * 20 + math.pi * 10**2) * 1e-6
    assert area_m2(drawing) == pytest.approx(exact, abs=2 * math.pi * 0.01 * TOL)
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([0.06, 0.02], abs=1e-9)


def test_dxf_closed_spline(tmp_path):
    doc, msp = dxf(tmp_path)
    angles = np.linspace(0, 2 * np.pi, 13)[:-1]
    fit = [(30 * math.cos(a), 30 * math.sin(a)) for a in angles]
    msp.add_spline([*fit, fit[0]])  # through 12 points of a 30 mm circle and back
    hole = [(x / 3, y / 3) for x, y in fit]  # and a hole of 10 mm
    msp.add_spline([*hole, hole[0]])
    doc.saveas(tmp_path / "spline.dxf")
    drawing = read_drawing(tmp_path / "spline.dxf")
    radii = np.linalg.norm(drawing.outline, axis=1)
    assert radii == pytest.approx(0.03, rel=0.03)
    assert drawing.outline.shape[0] > 24  # flattened, not just the fit points
    assert len(drawing.holes) == 1
    assert np.linalg.norm(drawing.holes[0], axis=1) == pytest.approx(0.01, rel=0.03)
    data = patch_data(drawing, "round", count=8)
    assert patch_from_dict(data).layers[0].n_electrodes == 8


SVG_MM = """<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="60mm"
  viewBox="0 0 100 60">
  <path id="sheet" d="M 0 0 H 100 V 60 H 0 Z"/>
  <circle id="hole" cx="30" cy="30" r="8"/>
  <path id="slot" d="M 60 25 H 80 A 5 5 0 0 1 80 35 H 60 A 5 5 0 0 1 60 25 Z"/>
  <g id="electrodes">
    <circle cx="10" cy="60" r="1"/><circle cx="90" cy="60" r="1"/>
    <circle cx="100" cy="30" r="1"/><circle cx="90" cy="0" r="1"/>
    <circle cx="10" cy="0" r="1"/><circle cx="0" cy="30" r="1"/>
  </g>
</svg>
"""


def test_svg_in_mm_with_holes_arcs_and_marks(tmp_path):
    (tmp_path / "plate.svg").write_text(SVG_MM)
    drawing = read_drawing(tmp_path / "plate.svg")
    assert drawing.units == "mm"
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([0.1, 0.06], abs=1e-9)
    assert len(drawing.holes) == 2
    slot = (20 * 10 + math.pi * 5**2) * 1e-6
    exact = 0.1 * 0.06 - math.pi * 0.008**2 - slot
    assert area_m2(drawing) == pytest.approx(exact, abs=2 * math.pi * 0.013 * TOL)
    # SVG's y points down: the mark drawn at y = 60 (the bottom) is at y = -0.06
    assert drawing.electrode_marks[:, 1].min() == pytest.approx(-0.06)
    patch = patch_from_dict(patch_data(drawing, "plate"))
    assert patch.layers[0].n_electrodes == 6


SVG_IN = """<svg xmlns="http://www.w3.org/2000/svg" width="2in" height="2in" viewBox="0 0 2 2">
  <path d="M 1 0.2 C 1.5 0.2 1.8 0.5 1.8 1 C 1.8 1.5 1.5 1.8 1 1.8
           C 0.5 1.8 0.2 1.5 0.2 1 C 0.2 0.5 0.5 0.2 1 0.2 Z"/>
</svg>
"""


def test_svg_in_inches_with_cubic_curves(tmp_path):
    (tmp_path / "blob.svg").write_text(SVG_IN)
    drawing = read_drawing(tmp_path / "blob.svg")
    assert drawing.units == "in"
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([1.6 * 0.0254] * 2, rel=1e-6)
    assert drawing.outline.shape[0] > 16
    data = patch_data(drawing, "blob", count=16)
    assert patch_from_dict(data).layers[0].n_electrodes == 16


SVG_GROUPS = """<svg xmlns="http://www.w3.org/2000/svg" width="60mm" height="60mm"
  viewBox="-30 -30 60 60">
  <g id="cut" transform="rotate(90)">
    <rect x="-20" y="-10" width="40" height="20" rx="5"/>
    <polygon points="-3,-3 3,-3 0,4"/>
  </g>
  <g id="electrodes" transform="translate(0, 10)"><path d="M 0 0 l 1 1"/></g>
  <circle id="drill" cx="0" cy="0" r="1" transform="translate(0, 200)"/>
</svg>
"""


def test_svg_group_transforms_rounded_rect_polygon_and_layer(tmp_path):
    (tmp_path / "g.svg").write_text(SVG_GROUPS)
    drawing = read_drawing(tmp_path / "g.svg", layer="cut")  # the stray circle is not on it
    # the 40 x 20 mm rounded rectangle turned by 90 degrees: 20 wide, 40 high
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([0.02, 0.04], abs=1e-9)
    exact = (40 * 20 - (4 - math.pi) * 5**2 - 6 * 7 / 2) * 1e-6
    assert area_m2(drawing) == pytest.approx(exact, abs=2 * math.pi * 0.005 * TOL)
    assert drawing.electrode_marks == pytest.approx(np.array([[0.0, -0.01]]))
    with pytest.raises(CadError, match="2 outer contours"):
        read_drawing(tmp_path / "g.svg")
    (tmp_path / "t.svg").write_text(SVG_GROUPS.replace("rotate(90)", "perspective(3)"))
    with pytest.raises(CadError, match=r"<g transform='perspective\(3\)'>: cannot read"):
        read_drawing(tmp_path / "t.svg")


def test_unitless_svg_needs_units(tmp_path):
    (tmp_path / "u.svg").write_text(
        '<svg xmlns="http://www.w3.org/2000/svg"><rect width="50" height="20"/></svg>'
    )
    with pytest.raises(CadError, match="states no units: give --units"):
        read_drawing(tmp_path / "u.svg")
    drawing = read_drawing(tmp_path / "u.svg", units="cm")
    assert np.ptp(drawing.outline, axis=0) == pytest.approx([0.5, 0.2])


def saved(tmp_path: Path, build, units: int = 4) -> Path:
    doc, msp = dxf(tmp_path, units)
    build(msp)
    doc.saveas(tmp_path / "bad.dxf")
    return tmp_path / "bad.dxf"


def test_refused_geometry_names_the_entity(tmp_path):
    def open_contour(msp):
        msp.add_line((0, 0), (10, 0))
        msp.add_line((10, 0), (10, 10))
        msp.add_line((10, 10), (0, 10))

    with pytest.raises(CadError, match=r"LINE #\w+ on layer '0'.*open contour"):
        read_drawing(saved(tmp_path, open_contour))

    def bow_tie(msp):
        msp.add_lwpolyline([(0, 0), (10, 10), (10, 0), (0, 10)], close=True)

    with pytest.raises(CadError, match=r"LWPOLYLINE #\w+.*intersects itself"):
        read_drawing(saved(tmp_path, bow_tie))

    def two_sheets(msp):
        msp.add_circle((0, 0), 5)
        msp.add_circle((20, 0), 5)

    with pytest.raises(CadError, match=r"CIRCLE #\w+ .*; CIRCLE #\w+ .*2 outer contours"):
        read_drawing(saved(tmp_path, two_sheets))

    def island(msp):
        msp.add_circle((0, 0), 20)
        msp.add_circle((0, 0), 10)
        msp.add_circle((0, 0), 5)

    with pytest.raises(CadError, match="inside a hole"):
        read_drawing(saved(tmp_path, island))

    def crossing(msp):
        msp.add_circle((0, 0), 20)
        msp.add_circle((18, 0), 5)

    with pytest.raises(CadError, match="cross each other"):
        read_drawing(saved(tmp_path, crossing))

    def text_only(msp):
        msp.add_text("no sheet here")

    with pytest.raises(CadError, match=r"\(file\): no geometry"):
        read_drawing(saved(tmp_path, text_only))
    with pytest.raises(CadError, match="layer 'cut': no geometry"):
        read_drawing(saved(tmp_path, lambda m: m.add_circle((0, 0), 5)), layer="cut")


def test_refused_units_files_and_electrodes(tmp_path):
    circle = saved(tmp_path, lambda m: m.add_circle((0, 0), 5), units=0)
    with pytest.raises(CadError, match=r"\$INSUNITS: the drawing states no units"):
        read_drawing(circle)
    assert read_drawing(circle, units="mm").units == "mm"
    inch = saved(tmp_path, lambda m: m.add_circle((0, 0), 5), units=1)
    with pytest.raises(CadError, match="the drawing is in in, --units says mm"):
        read_drawing(inch, units="mm")
    with pytest.raises(CadError, match="--units: unknown unit 'furlong'"):
        read_drawing(inch, units="furlong")
    (tmp_path / "x.step").write_text("ISO-10303-21;")
    with pytest.raises(CadError, match=r"expected a \.dxf or \.svg"):
        read_drawing(tmp_path / "x.step")
    (tmp_path / "broken.dxf").write_text("0\nSECTION\n2\nNONSENSE\n")
    with pytest.raises(CadError, match=r"broken.dxf: \(file\): not a readable DXF"):
        read_drawing(tmp_path / "broken.dxf")
    drawing = read_drawing(inch)
    with pytest.raises(CadError, match="give --electrodes N"):
        patch_data(drawing, "c")
    with pytest.raises(CadError, match="at least 4"):
        patch_data(drawing, "c", count=3)

    def far_mark(msp):
        msp.add_circle((0, 0), 5)
        for x, y in [(0, 0), (5, 0), (0, 5), (-5, 0)]:
            msp.add_point((x, y), dxfattribs={"layer": "electrodes"})

    marked = read_drawing(saved(tmp_path, far_mark))
    with pytest.raises(
        CadError, match=r"electrodes mark 0 at \(0.00, 0.00\) mm: 4.9\d mm from the outline"
    ):
        patch_data(marked, "c")
    with pytest.raises(CadError, match="marks 4 electrodes and --electrodes 8"):
        patch_data(marked, "c", count=8)


@pytest.fixture(scope="module")
def face_dxf(tmp_path_factory) -> Path:
    """The shipped face sheet as a CAD drawing: its outline in mm, its electrodes as points."""
    face = load_patch(config_path("face")).layers[0]
    doc = ezdxf.new(units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline((face.outline * 1e3).tolist(), close=True, dxfattribs={"layer": "cut"})
    for e in face.electrodes:
        msp.add_point((e.center * 1e3).tolist(), dxfattribs={"layer": "electrodes"})
    path = tmp_path_factory.mktemp("face") / "face_sheet.dxf"
    doc.saveas(path)
    return path


def test_face_drawing_gives_the_hand_written_patch_mesh(face_dxf, tmp_path, capsys):
    out = tmp_path / "face_import.yaml"
    code = main(["patch", "import", str(face_dxf), "--template", "face", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    text = out.read_text()
    assert text.startswith("# Imported by `eit-skin patch import` from face_sheet.dxf (mm")
    imported = load_patch(out).layers[0]
    shipped = load_patch(config_path("face")).layers[0]
    a, b = build_mesh(imported), build_mesh(shipped)
    for mine, theirs in [
        (a.n_triangles, b.n_triangles),
        (a.n_nodes, b.n_nodes),
        (imported.area_m2, shipped.area_m2),
        (imported.perimeter_m, shipped.perimeter_m),
        (float(np.abs(a.areas).sum()), float(np.abs(b.areas).sum())),
    ]:
        assert mine == pytest.approx(theirs, rel=0.01)
    centres = np.array([e.center for e in imported.electrodes])
    assert centres == pytest.approx(np.array([e.center for e in shipped.electrodes]), abs=1e-6)


def test_import_command_errors_name_the_file(face_dxf, tmp_path, capsys):
    out = tmp_path / "x.yaml"
    code = main(["patch", "import", str(face_dxf), "--electrodes", "16", "--out", str(out)])
    assert code == 1
    assert "face_sheet.dxf: electrodes: the drawing marks 16 electrodes" in capsys.readouterr().err
    assert not out.exists()
    assert main(["patch", "import", str(face_dxf)]) == 2
    assert "needs OUTLINE.(dxf|svg) and --out" in capsys.readouterr().err
