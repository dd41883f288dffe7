"""Patch files: loading, conventions, and every validation failure named in issue 3."""

from __future__ import annotations

import copy
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from eit_skin.patch import geometry
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.patch.material import Material
from eit_skin.patch.mesh_budget import estimate_layer
from eit_skin.patch.model import PatchError
from eit_skin.patch.placement import CylinderPlacement, HeightmapPlacement, PlanePlacement
from eit_skin.patch.protocol import build_protocol
from eit_skin.patch.yaml_reader import read_yaml

CONFIG = Path(__file__).resolve().parents[2] / "config"
RADIUS = 0.04


def base() -> dict:
    return {
        "name": "disk",
        "frame_id": "disk_link",
        "layers": [
            {
                "name": "sheet",
                "outline": {"type": "circle", "radius": RADIUS, "center": [0.0, 0.0]},
                "electrodes": {"count": 16, "width": 0.004, "contact_impedance": 4.0},
                "material": {
                    "quantity": "pressure",
                    "sheet_conductance": 1e-4,
                    "pressure_scale": 3e4,
                },
            }
        ],
    }


def write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "bad_patch.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def layer0(data: dict) -> dict:
    return data["layers"][0]


def square_layer(data: dict) -> dict:
    layer = layer0(data)
    layer["outline"] = {
        "type": "polygon",
        "points": [[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]],
    }
    return layer


def _set(path: str, value):
    """Mutator setting a dotted key inside layers[0]."""

    def mutate(data: dict) -> None:
        node = layer0(data)
        *head, last = path.split(".")
        for key in head:
            node = node[key]
        node[last] = value

    return mutate


def _bow_tie(data):
    square_layer(data)["outline"]["points"] = [[0, 0], [0.1, 0.1], [0.1, 0], [0, 0.1]]


def _off_boundary_point(data):
    square_layer(data)["electrodes"] = {
        "positions": [[0.05, 0.0], [0.1, 0.05], [0.05, 0.095], [0.0, 0.05]],
        "width": 0.004,
        "contact_impedance": 4.0,
    }


def _off_boundary_fraction(data):
    layer0(data)["electrodes"] = {
        "positions": [0.0, 0.25, 1.2, 0.75],
        "width": 0.004,
        "contact_impedance": 4.0,
    }


def _overlap_explicit(data):
    layer0(data)["electrodes"] = {
        "positions": [0.0, 0.25, 0.26, 0.75],
        "width": 0.004,
        "contact_impedance": 4.0,
    }


def _overlap_wraparound(data):
    # perimeter ~0.2513 m: 0.99 -> 0.005 is 0.015 * P = 3.8 mm, less than the 5 mm width
    layer0(data)["electrodes"] = {
        "positions": [0.005, 0.25, 0.5, 0.99],
        "width": 0.005,
        "contact_impedance": 4.0,
    }


def _not_ccw(data):
    layer0(data)["electrodes"] = {
        "positions": [0.0, 0.5, 0.25, 0.75],
        "width": 0.004,
        "contact_impedance": 4.0,
    }


def _hole_outside(data):
    layer0(data)["holes"] = [{"type": "circle", "radius": 0.005, "center": [0.038, 0.0]}]


def _hole_far_outside(data):
    layer0(data)["holes"] = [{"type": "polygon", "points": [[0.1, 0.1], [0.12, 0.1], [0.12, 0.12]]}]


def _holes_overlap(data):
    layer0(data)["holes"] = [
        {"type": "circle", "radius": 0.005, "center": [0.0, 0.0]},
        {"type": "circle", "radius": 0.005, "center": [0.008, 0.0]},
    ]


def _grid_pitch(data):
    layer0(data)["holes"] = [{"type": "grid", "diameter": 0.005, "pitch": 0.005}]


def _rename(key, new):
    def mutate(data):
        layer0(data)[new] = layer0(data).pop(key)

    return mutate


def _rename_top(key, new):
    def mutate(data):
        data[new] = data.pop(key)

    return mutate


def _missing(key):
    def mutate(data):
        del layer0(data)[key]

    return mutate


def _missing_top(key):
    def mutate(data):
        del data[key]

    return mutate


BAD = [
    # (id, mutate, key path, reason fragment)
    ("self-intersecting outline", _bow_tie, "layers[0].outline.points", "intersects itself"),
    (
        "electrode point off boundary",
        _off_boundary_point,
        "layers[0].electrodes.positions[2]",
        "off the outline",
    ),
    (
        "electrode fraction off boundary",
        _off_boundary_fraction,
        "layers[0].electrodes.positions[2]",
        "off the outline",
    ),
    (
        "overlapping electrodes (even)",
        _set("electrodes.width", 0.016),
        "layers[0].electrodes.width",
        "overlap",
    ),
    (
        "overlapping electrodes (explicit)",
        _overlap_explicit,
        "layers[0].electrodes.positions[2]",
        "electrodes 1 and 2 overlap",
    ),
    (
        "overlapping electrodes (wrap-around)",
        _overlap_wraparound,
        "layers[0].electrodes.positions[0]",
        "electrodes 3 and 0 overlap",
    ),
    (
        "electrodes not counter-clockwise",
        _not_ccw,
        "layers[0].electrodes.positions",
        "counter-clockwise",
    ),
    (
        "fewer than 4 electrodes",
        _set("electrodes.count", 3),
        "layers[0].electrodes.count",
        "at least 4",
    ),
    ("zero width", _set("electrodes.width", 0.0), "layers[0].electrodes.width", "> 0"),
    (
        "unknown protocol",
        _set("protocol", {"drive": "zigzag"}),
        "layers[0].protocol.drive",
        "unknown pattern",
    ),
    (
        "protocol skip joins electrode to itself",
        _set("protocol", {"drive": "skip", "drive_skip": 15}),
        "layers[0].protocol.drive_skip",
        "itself",
    ),
    (
        "unknown protocol key",
        _set("protocol", {"drvie": "adjacent"}),
        "layers[0].protocol.drvie",
        "unknown key; did you mean 'drive'?",
    ),
    (
        "drive_skip wraps around",
        _set("protocol", {"drive": "skip", "drive_skip": 16}),
        "layers[0].protocol.drive_skip",
        "16 is not below the electrode count 16",
    ),
    (
        "measure_skip wraps around",
        _set("protocol", {"measure": "skip", "measure_skip": 40}),
        "layers[0].protocol.measure_skip",
        "40 is not below the electrode count 16",
    ),
    (
        "misspelt top-level key",
        _rename_top("layers", "layerz"),
        "layerz",
        "unknown key; did you mean 'layers'?",
    ),
    (
        "misspelt layer key",
        _rename("electrodes", "electrodez"),
        "layers[0].electrodez",
        "unknown key; did you mean 'electrodes'?",
    ),
    (
        "misspelt solver key",
        _set("solver", {"metod": "greit"}),
        "layers[0].solver.metod",
        "unknown key; did you mean 'method'?",
    ),
    (
        "misspelt outline key",
        _set("outline", {"type": "circle", "raduis": 0.04}),
        "layers[0].outline.raduis",
        "unknown key of a circle outline; did you mean 'radius'?",
    ),
    (
        "key of another outline type",
        _set("outline", {"type": "circle", "radius": 0.04, "width": 0.1}),
        "layers[0].outline.width",
        "unknown key of a circle outline; allowed: center, radius, segments, type",
    ),
    (
        "misspelt grid key",
        _set("holes", [{"type": "grid", "diameter": 0.003, "pich": 0.005}]),
        "layers[0].holes[0].pich",
        "unknown key of a grid hole; did you mean 'pitch'?",
    ),
    (
        "misspelt placement key",
        lambda d: d.update(placement={"type": "cylinder", "raduis": 0.05}),
        "placement.raduis",
        "unknown key of a cylinder placement; did you mean 'radius'?",
    ),
    (
        "misspelt type key",
        _set("outline", {"tpye": "circle", "radius": 0.04}),
        "layers[0].outline.tpye",
        "did you mean 'type'?",
    ),
    (
        "misspelt choice",
        _set("solver", {"method": "gauss-newton"}),
        "layers[0].solver.method",
        "unknown value 'gauss-newton' (did you mean 'gauss_newton'?)",
    ),
    (
        "negative conductivity",
        _set("material.sheet_conductance", -1e-4),
        "layers[0].material.sheet_conductance",
        "must be > 0",
    ),
    (
        "negative resistivity",
        _set(
            "material",
            {
                "quantity": "stretch",
                "volume_resistivity": -7.6,
                "thickness": 5e-4,
                "gauge_factor": 5.0,
            },
        ),
        "layers[0].material.volume_resistivity",
        "must be > 0",
    ),
    (
        "unknown quantity",
        _set("material.quantity", "temperature"),
        "layers[0].material.quantity",
        "unknown value",
    ),
    ("hole crossing the outline", _hole_outside, "layers[0].holes[0]", "not strictly inside"),
    ("hole outside the sheet", _hole_far_outside, "layers[0].holes[0]", "not strictly inside"),
    ("holes overlapping", _holes_overlap, "layers[0].holes[1]", "overlaps layers[0].holes[0]"),
    ("grid pitch below diameter", _grid_pitch, "layers[0].holes[0].pitch", "must exceed"),
    ("missing material", _missing("material"), "layers[0].material", "missing required key"),
    ("missing electrodes", _missing("electrodes"), "layers[0].electrodes", "missing required"),
    ("missing frame_id", _missing_top("frame_id"), "frame_id", "missing required key"),
    (
        "missing radius",
        _set("outline", {"type": "circle"}),
        "layers[0].outline.radius",
        "missing required key",
    ),
    (
        "radius is a string",
        _set("outline.radius", "big"),
        "layers[0].outline.radius",
        "expected a number",
    ),
    (
        "count is a float",
        _set("electrodes.count", 16.5),
        "layers[0].electrodes.count",
        "expected an integer",
    ),
    ("boolean as number", _set("current", True), "layers[0].current", "expected a number"),
    (
        "center wrong length",
        _set("outline.center", [0.0]),
        "layers[0].outline.center",
        "expected 2 numbers",
    ),
    (
        "electrodes not a mapping",
        _set("electrodes", [1, 2, 3]),
        "layers[0].electrodes",
        "expected a mapping",
    ),
    (
        "unknown solver method",
        _set("solver", {"method": "magic"}),
        "layers[0].solver.method",
        "unknown value",
    ),
    (
        "electrode edge above max edge",
        _set("mesh", {"max_edge": 0.002, "electrode_edge": 0.003}),
        "layers[0].mesh.electrode_edge",
        "<= max_edge",
    ),
    (
        "start angle on a polygon",
        lambda d: square_layer(d)["electrodes"].update(start_angle_deg=10.0),
        "layers[0].electrodes.start_angle_deg",
        "only for circle",
    ),
]


@pytest.mark.parametrize(
    ("mutate", "key_path", "reason"), [b[1:] for b in BAD], ids=[b[0] for b in BAD]
)
def test_bad_file_names_file_key_path_and_reason(tmp_path, mutate, key_path, reason):
    data = base()
    mutate(data)
    path = write(tmp_path, data)
    with pytest.raises(PatchError) as info:
        load_patch(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key_path}: "), message
    assert reason in message
    assert "\n" not in message
    assert info.value.key_path == key_path


def test_layers_must_be_a_list(tmp_path):
    data = base()
    data["layers"] = {"name": "x"}
    path = write(tmp_path, data)
    with pytest.raises(PatchError, match=r"bad_patch\.yaml: layers: expected a list"):
        load_patch(path)


def test_duplicate_layer_names():
    data = base()
    data["layers"].append(copy.deepcopy(data["layers"][0]))
    with pytest.raises(PatchError, match=r"^<dict>: layers\[1\]\.name: duplicate"):
        patch_from_dict(data)


def test_yaml_syntax_error_names_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nframe_id: [unclosed\nlayers: []\n")
    with pytest.raises(PatchError, match=r"broken\.yaml: line \d+, column \d+: invalid YAML"):
        load_patch(path)


def test_missing_file(tmp_path):
    with pytest.raises(PatchError, match=r"nothing\.yaml: \(file\): "):
        load_patch(tmp_path / "nothing.yaml")


DUPLICATE = """\
name: disk
frame_id: disk_link
layers:
  - name: sheet
    outline: {type: circle, radius: 0.04}
    electrodes: {count: 16, width: 0.004, contact_impedance: 4.0}
    material: {quantity: pressure, sheet_conductance: 1.0e-4, pressure_scale: 3.0e4}
    current: 1.0e-3
"""


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            DUPLICATE + "    current: 2.0e-3\n",
            "layers[0].current: duplicate key: first on line 8, again on line 9",
        ),
        (
            DUPLICATE.replace("radius: 0.04}", "radius: 0.04, radius: 0.05}"),
            "layers[0].outline.radius: duplicate key: first on line 5, again on line 5",
        ),
        ("name: a\n" + DUPLICATE, "name: duplicate key: first on line 1, again on line 2"),
    ],
    ids=["layer", "flow mapping", "top"],
)
def test_duplicate_key_is_refused_naming_both_lines(tmp_path, text, message):
    path = tmp_path / "dup.yaml"
    path.write_text(text)
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert str(info.value) == f"{path}: {message}"
    path.write_text(DUPLICATE)
    assert load_patch(path).layers[0].current_a == 1.0e-3  # the same file without the repeat


def test_first_duplicate_in_document_order_is_reported(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text("a: [{x: 1, y: 2}, {x: 1, x: 2}]\nb: {y: 1, y: 2}\n")
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert str(info.value) == f"{path}: a[1].x: duplicate key: first on line 1, again on line 1"


def test_second_document_is_refused(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(DUPLICATE + "---\nname: other\n")
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert str(info.value) == (
        f"{path}: line 9, column 1: invalid YAML: expected a single document in the stream, "
        "but found another document"
    )


@pytest.mark.parametrize("text", ["", "  \n\t\n", "# nothing here yet\n\n"])
def test_empty_file_is_reported_as_empty(tmp_path, text):
    path = tmp_path / "empty.yaml"
    path.write_text(text)
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert str(info.value) == f"{path}: (file): empty file"


def test_explicit_null_document_is_not_a_mapping(tmp_path):
    path = tmp_path / "null.yaml"
    path.write_text("null\n")
    with pytest.raises(PatchError, match=r"null\.yaml: \(root\): expected a mapping, got nothing"):
        load_patch(path)


def test_non_utf8_file_names_the_byte_offset(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: d\u00fcse\n".encode("latin-1"))
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert str(info.value) == f"{path}: (file): not UTF-8 text: bad byte at offset 7"


def test_yaml_reader_uses_yaml_1_2_scalars(tmp_path):
    path = tmp_path / "scalars.yaml"
    path.write_text(
        "a: 5e-3\nb: 010\nc: yes\nd: 1:30\ne: 2001-12-14\nf: 0x1F\ng: 0o17\nh: 1_000\n"
        "i: .5\nj: -.inf\nk: True\nl: ~\nm: +3\n"
    )
    data = read_yaml(path, PatchError)
    assert data == {
        "a": 0.005,
        "b": 10,
        "c": "yes",
        "d": "1:30",
        "e": "2001-12-14",
        "f": 31,
        "g": 15,
        "h": "1_000",
        "i": 0.5,
        "j": -np.inf,
        "k": True,
        "l": None,
        "m": 3,
    }
    assert type(data["a"]) is float and type(data["b"]) is int


def test_exponent_without_sign_is_a_number(tmp_path):
    text = yaml.safe_dump(base()).replace("30000.0", "3.0e4")
    assert "3.0e4" in text
    path = tmp_path / "p.yaml"
    path.write_text(text)
    assert load_patch(path).layers[0].material.pressure_scale_pa == 3.0e4


@pytest.mark.parametrize("name", ["arm", "face", "elbow"])
def test_shipped_configs_load(name):
    patch = load_patch(CONFIG / f"{name}.yaml")
    assert patch.frame_id == f"{name}_skin_link"
    for layer in patch.layers:
        assert layer.n_electrodes == 16
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        assert protocol.n_measurements == 16 * 13
        assert geometry.signed_area(layer.outline) > 0
        for hole in layer.holes:
            assert geometry.signed_area(hole) < 0


def test_arm_config_matches_the_seed():
    patch = load_patch(CONFIG / "arm.yaml")
    assert isinstance(patch.placement, CylinderPlacement)
    assert patch.placement.radius == pytest.approx(0.076 / 2 + 4 * 0.005)
    assert patch.layer_names == ("pressure", "stretch")
    stretch = patch.layer("stretch")
    assert stretch.material.quantity == "stretch"
    assert stretch.material.sheet_conductance_s == pytest.approx(0.5e-3 / (0.76e3 * 1e-2))
    centres = np.array([h.mean(axis=0) for h in stretch.holes])
    diameters = np.array([np.ptp(h[:, 0]) for h in stretch.holes])
    np.testing.assert_allclose(diameters, 0.005, rtol=1e-12)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    np.testing.assert_allclose(d.min(axis=1), 0.0072, rtol=1e-9)
    assert len(stretch.holes) > 40
    pressure = patch.layer("pressure")
    assert pressure.material.quantity == "pressure"
    assert not pressure.holes
    with pytest.raises(KeyError, match="no layer 'skin'"):
        patch.layer("skin")


def test_face_electrodes_are_not_evenly_spaced():
    layer = load_patch(CONFIG / "face.yaml").layers[0]
    s = np.array([e.center_m for e in layer.electrodes])
    gaps = np.diff(np.append(s, s[0] + layer.perimeter_m))
    assert gaps.max() > 2 * gaps.min()
    assert isinstance(load_patch(CONFIG / "face.yaml").placement, HeightmapPlacement)


def test_elbow_electrodes_only_on_long_edges():
    layer = load_patch(CONFIG / "elbow.yaml").layers[0]
    centres = np.array([e.center for e in layer.electrodes])
    half_width = 0.5 * np.ptp(layer.outline[:, 0])
    np.testing.assert_allclose(np.abs(centres[:, 0]), half_width, rtol=0, atol=1e-15)
    assert np.ptp(layer.outline[:, 1]) > np.ptp(layer.outline[:, 0])


def test_electrodes_numbered_counter_clockwise_from_start_angle():
    data = base()
    layer0(data)["electrodes"]["start_angle_deg"] = 90.0
    layer = patch_from_dict(data).layers[0]
    centres = np.array([e.center for e in layer.electrodes])
    angles = np.unwrap(np.arctan2(centres[:, 1], centres[:, 0]))
    np.testing.assert_allclose(angles, np.pi / 2 + 2 * np.pi * np.arange(16) / 16, atol=1e-12)
    # electrode ends are width/2 either side of the centre along the outline
    for e in layer.electrodes:
        assert np.mod(e.end_m - e.start_m, layer.perimeter_m) == pytest.approx(e.width_m)


def test_polygon_orientation_normalised_keeping_start_point():
    data = base()
    cw = [[0.0, 0.0], [0.0, 0.1], [0.1, 0.1], [0.1, 0.0]]
    layer0(data)["outline"] = {"type": "polygon", "points": cw}
    layer0(data)["electrodes"] = {
        "positions": [0.0, 0.25, 0.5, 0.75],
        "width": 0.01,
        "contact_impedance": 1.0,
    }
    layer = patch_from_dict(data).layers[0]
    np.testing.assert_array_equal(layer.outline, [[0, 0], [0.1, 0], [0.1, 0.1], [0, 0.1]])
    np.testing.assert_allclose(
        [e.center for e in layer.electrodes], [[0, 0], [0.1, 0], [0.1, 0.1], [0, 0.1]], atol=1e-15
    )
    assert layer.electrodes[0].start_m == pytest.approx(0.4 - 0.005)  # wraps the start point
    assert layer.electrodes[0].end_m == pytest.approx(0.005)


def test_rectangle_starts_at_lower_left_corner():
    data = base()
    layer0(data)["outline"] = {
        "type": "rectangle",
        "width": 0.2,
        "height": 0.1,
        "center": [1.0, 2.0],
    }
    layer0(data)["electrodes"]["start_fraction"] = 0.0
    layer0(data)["electrodes"]["count"] = 6
    layer = patch_from_dict(data).layers[0]
    np.testing.assert_allclose(layer.outline[0], [0.9, 1.95])
    np.testing.assert_allclose(layer.electrodes[0].center, [0.9, 1.95])
    # perimeter 0.6 m, 6 electrodes -> every 0.1 m: the second one is on the bottom edge
    np.testing.assert_allclose(layer.electrodes[1].center, [1.0, 1.95])


def test_content_hash_depends_on_content_only(tmp_path):
    data = base()
    a = patch_from_dict(data, source="a")
    path = tmp_path / "x.yaml"
    path.write_text("# a comment\n" + yaml.safe_dump(data, default_flow_style=True))
    b = load_patch(path)
    assert a.content_hash == b.content_hash
    assert a.layers[0].content_hash == b.layers[0].content_hash
    layer0(data)["electrodes"]["width"] = 0.0041
    c = patch_from_dict(data)
    assert c.content_hash != a.content_hash
    assert len(a.content_hash) == 64


def test_patch_is_immutable():
    patch = patch_from_dict(base())
    with pytest.raises(AttributeError):
        patch.name = "x"
    with pytest.raises(ValueError, match="read-only"):
        patch.layers[0].outline[0, 0] = 1.0


def test_defaults():
    layer = patch_from_dict(base()).layers[0]
    assert layer.current_a == 1e-3
    assert layer.protocol.drive == "adjacent" and layer.protocol.measure == "adjacent"
    assert layer.solver.method == "one_step" and layer.solver.hyperparameter is None
    assert layer.mesh.max_edge_m == pytest.approx(layer.perimeter_m / 100)
    assert layer.mesh.electrode_edge_m == pytest.approx(0.001)
    assert isinstance(patch_from_dict(base()).placement, PlanePlacement)


# ---------------------------------------------------------------- material


def test_pressure_material_is_linear_and_invertible():
    m = Material("pressure", 1e-4, pressure_scale_pa=3e4)
    r = np.array([[0.0, 0.5], [1.0, -0.2]])
    p = m.to_physical(r)
    assert p.shape == r.shape
    np.testing.assert_allclose(p, 3e4 * r)
    np.testing.assert_allclose(m.from_physical(p), r)
    assert m.unit == "Pa"
    np.testing.assert_allclose(m.conductance(3e4), 2e-4)


def test_stretch_material_follows_gauge_law_and_guards_r_minus_one():
    m = Material("stretch", 1e-4, gauge_factor=2.0)
    # strain 0.5 with G = 2 doubles the resistance: sigma = sigma0 / 2, r = -0.5
    assert m.from_physical(0.5) == pytest.approx(-0.5)
    assert m.to_physical(-0.5) == pytest.approx(0.5)
    strain = np.linspace(-0.3, 1.5, 7).reshape(7, 1)
    np.testing.assert_allclose(m.to_physical(m.from_physical(strain)), strain, rtol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            out = m.to_physical(np.array([-1.0, -2.0, 0.0]))
            back = m.from_physical(np.array([-0.5, -1.0]))
    assert np.isinf(out[:2]).all() and out[2] == 0.0
    assert np.isinf(back).all()
    assert not np.isnan(out).any()
    # NaN marks "no sheet here" in images (holes, outside): it must stay NaN, not +inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(m.to_physical(np.array([np.nan]))).all()
        assert np.isnan(m.from_physical(np.array([np.nan]))).all()


def test_physical_range_is_a_tenfold_conductance_change_either_way():
    """The images' bound comes from the material law: sigma/sigma0 in [1/10, 10]."""
    pressure = Material("pressure", 1e-4, pressure_scale_pa=3e4)
    assert pressure.physical_range == pytest.approx((-0.9 * 3e4, 9.0 * 3e4))
    stretch = Material("stretch", 1e-4, gauge_factor=2.0)
    low, high = stretch.physical_range  # strain falls as r rises: the ends swap
    assert (low, high) == pytest.approx(((0.1 - 1.0) / 2.0, (10.0 - 1.0) / 2.0))
    for m in (pressure, stretch):
        ratio = m.conductance(np.array(m.physical_range)) / m.sheet_conductance_s
        np.testing.assert_allclose(np.sort(ratio), [0.1, 10.0])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"quantity": "heat", "sheet_conductance_s": 1.0},
        {"quantity": "pressure", "sheet_conductance_s": -1.0, "pressure_scale_pa": 1.0},
        {"quantity": "pressure", "sheet_conductance_s": 1.0},
        {"quantity": "stretch", "sheet_conductance_s": 1.0, "gauge_factor": 0.0},
    ],
)
def test_material_validation(kwargs):
    with pytest.raises(ValueError):
        Material(**kwargs)


# ---------------------------------------------------------------- placement


def test_cylinder_wraps_without_stretch():
    cyl = CylinderPlacement(
        radius=0.058, axis=[0, 0, 2.0], origin=[1.0, 0, 0], reference=[1.0, 0, 0]
    )
    x = np.linspace(-0.05, 0.05, 11)
    pts = np.column_stack([x, np.full(11, 0.02)])
    p3 = cyl.to_3d(pts)
    assert p3.shape == (11, 3)
    np.testing.assert_allclose(np.hypot(p3[:, 0] - 1.0, p3[:, 1]), 0.058, rtol=1e-12)
    np.testing.assert_allclose(p3[:, 2], 0.02)
    angles = np.arctan2(p3[:, 1], p3[:, 0] - 1.0)
    np.testing.assert_allclose(angles, x / 0.058, atol=1e-12)  # counter-clockwise about +z
    np.testing.assert_allclose(cyl.to_3d([[0.0, 0.0]]), [[1.058, 0, 0]], atol=1e-15)


def test_plane_rotation():
    plane = PlanePlacement(origin=[0, 0, 1.0], rpy=[0, 0, np.pi / 2])
    np.testing.assert_allclose(plane.to_3d([[1.0, 0.0]]), [[0.0, 1.0, 1.0]], atol=1e-15)


def test_heightmap_is_bilinear():
    x_min, x_max, y_min, y_max = -0.1, 0.1, 0.0, 0.3
    xs = np.linspace(x_min, x_max, 5)
    ys = np.linspace(y_min, y_max, 4)
    heights = 0.5 * xs[None, :] + 0.2 * ys[:, None] + 0.01  # a plane is reproduced exactly
    hm = HeightmapPlacement(heights=heights, bounds=[x_min, x_max, y_min, y_max])
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(x_min, x_max, 50), rng.uniform(y_min, y_max, 50)])
    np.testing.assert_allclose(
        hm.to_3d(pts)[:, 2], 0.5 * pts[:, 0] + 0.2 * pts[:, 1] + 0.01, atol=1e-15
    )
    bump = HeightmapPlacement(heights=[[0, 0], [0, 1.0]], bounds=[0, 1, 0, 1])
    assert bump.height([[0.5, 0.5]])[0] == pytest.approx(0.25)


def test_heightmap_bounds_default_to_outline_box():
    patch = load_patch(CONFIG / "face.yaml")
    lo, hi = patch.layers[0].outline.min(axis=0), patch.layers[0].outline.max(axis=0)
    np.testing.assert_allclose(patch.placement.bounds, [lo[0], hi[0], lo[1], hi[1]])


def disc50(**mesh) -> dict:
    data = base()
    layer0(data)["outline"]["radius"] = 0.025
    layer0(data)["mesh"] = mesh
    return data


@pytest.fixture
def no_meshing(monkeypatch):
    """Any attempt to mesh fails the test: the budget is checked before meshing."""
    import triangle

    def triangulate(*args, **kwargs):
        raise AssertionError("the loader started meshing")

    monkeypatch.setattr(triangle, "triangulate", triangulate)


def suggested(message: str, key: str) -> float:
    match = re.search(rf"{key} >= ([0-9.e+-]+) m would fit", message)
    assert match, message
    return float(match.group(1))


def test_mesh_too_big_is_refused_with_estimate_and_fitting_max_edge(tmp_path, no_meshing):
    path = write(tmp_path, disc50(max_edge=1.0e-5))
    with pytest.raises(PatchError) as info:
        load_patch(path)
    message = str(info.value)
    assert message.startswith(f"{path}: layers[0].mesh.max_edge: ~"), message
    # 1.58 * area / (sqrt(3)/4 h^2) = 1.58 * 1.963e-3 / 4.33e-11 = 7.2e7 triangles, ~500 GB
    triangles = float(re.search(r"~([0-9.e+]+) triangles", message).group(1))
    assert 6.5e7 < triangles < 8e7
    assert "GiB" in message and "the limit is 2 GiB and 60 s" in message
    fit = suggested(message, "max_edge")
    assert 1e-4 < fit < 2e-4
    patch_from_dict(disc50(max_edge=fit), source="fits")  # the suggestion is accepted ...
    with pytest.raises(PatchError, match=r"mesh\.max_edge: .* max_edge >= "):
        patch_from_dict(disc50(max_edge=0.8 * fit))  # ... and is (nearly) the smallest


def test_too_fine_electrode_edge_is_refused(no_meshing):
    with pytest.raises(PatchError) as info:
        patch_from_dict(disc50(max_edge=1e-3, electrode_edge=1e-9))
    assert info.value.key_path == "layers[0].mesh.electrode_edge"
    fit = suggested(str(info.value), "electrode_edge")
    patch_from_dict(disc50(max_edge=1e-3, electrode_edge=fit))


def test_too_fine_inverse_mesh_is_refused(no_meshing):
    with pytest.raises(PatchError) as info:
        patch_from_dict(disc50(max_edge=1e-3, inverse_max_edge=2e-5))
    assert info.value.key_path == "layers[0].mesh.inverse_max_edge"
    assert "inverse_max_edge >= " in str(info.value)


def test_more_measurements_lower_the_limit(no_meshing):
    data = disc50(max_edge=1.6e-4)
    patch_from_dict(data)  # 16 electrodes, 208 measurements: fits
    layer0(data)["electrodes"] = {"count": 32, "width": 0.002, "contact_impedance": 4.0}
    with pytest.raises(PatchError, match=r"layers\[0\]\.mesh\.max_edge: "):
        patch_from_dict(data)  # 928 measurements: the Jacobian alone is 4x bigger


@pytest.mark.parametrize(
    "mesh",
    [
        {"max_edge": 5e-4, "electrode_edge": 5e-4},
        {"max_edge": 5e-4, "electrode_edge": 3e-5},
        {"max_edge": 2e-3, "electrode_edge": 1.25e-4},
    ],
)
def test_triangle_estimate_matches_the_mesh(mesh):
    from eit_skin.fem.mesh import build_mesh

    layer = patch_from_dict(disc50(**mesh)).layers[0]
    actual = build_mesh(layer).n_triangles
    assert 0.95 * actual < estimate_layer(layer).triangles < 1.25 * actual


@pytest.mark.parametrize("name", ["arm", "face", "elbow"])
def test_triangle_estimate_of_shipped_layers(name):
    from eit_skin.fem.mesh import build_mesh

    for layer in load_patch(CONFIG / f"{name}.yaml").layers:
        actual = build_mesh(layer).n_triangles
        assert 0.75 * actual < estimate_layer(layer).triangles < 1.5 * actual


@pytest.mark.parametrize(
    ("mount", "key_path", "reason"),
    [
        ({"xyz": [0, 0, 0]}, "mount.parent_frame", "missing required key"),
        ({"parent_frame": "link", "xyz": [1, 2]}, "mount.xyz", "expected 3 numbers, got 2"),
        ({"parent_frame": "link", "rpy": [0, 0, "x"]}, "mount.rpy[2]", "expected a number"),
        ({"parent_frame": "link", "ryp": [0, 0, 0]}, "mount.ryp", "did you mean 'rpy'?"),
        ({"parent_frame": ""}, "mount.parent_frame", "non-empty string"),
        ("forearm", "mount", "expected a mapping"),
    ],
)
def test_bad_mount_names_the_key(tmp_path, mount, key_path, reason):
    data = base()
    data["mount"] = mount
    path = write(tmp_path, data)
    with pytest.raises(PatchError) as info:
        load_patch(path)
    assert info.value.key_path == key_path and reason in str(info.value), str(info.value)


def test_mount_is_read_in_metres_and_radians_and_keeps_layer_hashes(tmp_path):
    data = base()
    plain = load_patch(write(tmp_path, data))
    assert (plain.mount.parent_frame, plain.mount.xyz, plain.mount.rpy) == (
        "base_link",
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
    )
    data["mount"] = {"parent_frame": "forearm_link", "xyz": [0.1, 0, 0.02], "rpy": [0, 0, 1.5]}
    mounted = load_patch(write(tmp_path, data))
    assert mounted.mount.xyz == (0.1, 0.0, 0.02) and mounted.mount.rpy == (0.0, 0.0, 1.5)
    assert mounted.content_hash != plain.content_hash
    assert mounted.layers[0].content_hash == plain.layers[0].content_hash  # caches stay
    data["mount"] = {"parent_frame": data["frame_id"]}
    with pytest.raises(PatchError, match=r"mount\.parent_frame: is the patch's own frame_id"):
        load_patch(write(tmp_path, data))


def test_a_layer_by_name_or_the_first_when_none_is_named():
    """``Patch.layer``: what every command's ``--layer`` (default: the first) resolves through."""
    from eit_skin.resources import config_path

    arm = load_patch(config_path("arm"))
    assert len(arm.layers) >= 2
    assert arm.layer(None) is arm.layers[0] and arm.layer("") is arm.layers[0]
    second = arm.layers[1]
    assert arm.layer(second.name) is second
    with pytest.raises(KeyError, match=rf"no layer 'nope'; layers: .*{second.name}"):
        arm.layer("nope")


def test_depth_is_a_tank_key_refused_where_it_cannot_be_honoured():
    data = base()
    assert patch_from_dict(data).layers[0].depth_m is None
    plain = patch_from_dict(data).layers[0].content_hash
    data["layers"][0]["depth"] = 0.1
    layer = patch_from_dict(data).layers[0]
    assert layer.depth_m == 0.1 and layer.content_hash != plain
    short = copy.deepcopy(data)
    short["layers"][0]["depth"] = 0.003
    with pytest.raises(PatchError, match=r"layers\[0\]\.depth: .*less than the electrodes"):
        patch_from_dict(short)
    stretch = copy.deepcopy(data)
    stretch["layers"][0]["material"] = {
        "quantity": "stretch",
        "sheet_conductance": 1e-4,
        "gauge_factor": 2.0,
    }
    with pytest.raises(PatchError, match=r"layers\[0\]\.depth: a stretch layer is a thin"):
        patch_from_dict(stretch)
