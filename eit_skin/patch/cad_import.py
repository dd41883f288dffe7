"""CAD drawings -> patch files: the sheet's outline, holes and electrode marks from DXF or SVG.

:func:`read_drawing` reads the closed contours of a drawing (DXF through ``ezdxf``: lines,
polylines, arcs, circles, ellipses, splines; SVG through ``svg.path`` and the standard XML
parser: paths, rectangles, circles, ellipses, polygons, polylines, lines, with their groups'
transforms) and flattens curves so that no chord strays more than ``tolerance_m`` from the
curve.
Open pieces (lines, arcs, open polylines or paths) are chained end to end into loops when
their ends meet within :data:`JOIN_TOLERANCE` of the drawing's size. The one loop that
contains the others is the sheet's outline, the loops inside it are holes. Entities on the
layer (DXF) or in the group or element (SVG) named :data:`ELECTRODE_LAYER` mark electrode
centres: DXF points, circles (their centres) and short lines (their midpoints); SVG circles
or ellipses (centres) and paths (their first point).

:func:`eit_skin.patch.cad_patch.patch_data` turns the :class:`Drawing` into a patch file's data.

Units: the drawing's own (DXF ``$INSUNITS``; SVG: the root's ``width`` in mm, cm, in or m
with its ``viewBox``), or ``units`` when the drawing states none; a flag that contradicts the
file is refused. Every problem raises :class:`CadError` naming the file and the entity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.patch import geometry

#: Name of the DXF layer, SVG group or element whose entities mark electrode centres.
ELECTRODE_LAYER = "electrodes"
#: Metres per drawing unit.
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "um": 1e-6, "in": 0.0254, "ft": 0.3048}
#: DXF ``$INSUNITS`` codes -> unit names (0: unitless, the file states none).
DXF_UNITS = {1: "in", 2: "ft", 4: "mm", 5: "cm", 6: "m", 13: "um"}
#: Default flattening tolerance: largest distance of a chord from its curve, m.
DEFAULT_TOLERANCE_M = 5e-5
#: Ends of open pieces closer than this fraction of the drawing's size are joined.
JOIN_TOLERANCE = 1e-6


class CadError(ValueError):
    """A drawing that cannot become a sheet: ``"<file>: <entity>: <reason>"``."""

    def __init__(self, source: str, entity: str, reason: str) -> None:
        super().__init__(f"{source}: {entity}: {reason}")


@dataclass(frozen=True)
class Contour:
    """One closed loop of the drawing.

    Attributes:
        points: ``[n, 2]`` vertices, m, no repeated closing point.
        entity: the entity (or chained entities) it came from, for messages.
    """

    points: np.ndarray
    entity: str


@dataclass(frozen=True)
class Drawing:
    """A sheet read from a drawing.

    Attributes:
        outline: ``[n, 2]`` counter-clockwise outline, m.
        holes: ``[m_i, 2]`` hole polygons, m.
        electrode_marks: ``[k, 2]`` marked electrode centres, m (``k = 0``: none marked).
        units: the unit the drawing was read in.
        source: the file.
    """

    outline: np.ndarray
    holes: tuple[np.ndarray, ...]
    electrode_marks: np.ndarray
    units: str
    source: str


def read_drawing(
    path: str | Path,
    units: str | None = None,
    layer: str | None = None,
    tolerance_m: float = DEFAULT_TOLERANCE_M,
) -> Drawing:
    """The sheet of a DXF or SVG file (see the module doc).

    Args:
        path: ``.dxf`` or ``.svg`` file.
        units: unit of a drawing that states none (a key of :data:`UNITS_M`).
        layer: only contours on this DXF layer or in this SVG group / element id.
        tolerance_m: flattening tolerance, m.

    Raises:
        CadError: unreadable file, no geometry, open or self-intersecting contours, several
            outer contours, contours inside holes, unknown or contradicting units.
    """
    source = str(path)
    if units is not None and units not in UNITS_M:
        raise CadError(source, "--units", f"unknown unit {units!r}; one of {sorted(UNITS_M)}")
    suffix = Path(path).suffix.lower()
    if suffix == ".dxf":
        pieces, marks, unit = _dxf(source, units, layer, tolerance_m)
    elif suffix == ".svg":
        pieces, marks, unit = _svg(source, units, layer, tolerance_m)
    else:
        raise CadError(source, "(file)", "not a drawing: expected a .dxf or .svg file")
    contours = _close(source, pieces)
    if not contours:
        where = f"layer {layer!r}" if layer else "(file)"
        raise CadError(source, where, "no geometry: no line, polyline, arc, spline or path")
    outline, holes = _nest(source, contours)
    return Drawing(outline, tuple(holes), marks, unit, source)


def _unit(source: str, stated: str | None, flag: str | None, what: str) -> str:
    if stated is None and flag is None:
        raise CadError(source, what, "the drawing states no units: give --units (e.g. mm)")
    if stated is not None and flag is not None and stated != flag:
        raise CadError(
            source, what, f"the drawing is in {stated}, --units says {flag}: drop the flag"
        )
    return stated or flag  # type: ignore[return-value]


# --- DXF ------------------------------------------------------------------------------


def _dxf(
    source: str, units: str | None, layer: str | None, tolerance_m: float
) -> tuple[list[Contour], np.ndarray, str]:
    """Open / closed pieces in metres, electrode marks and the unit of a DXF file."""
    import ezdxf
    from ezdxf import path as dxf_path

    try:
        doc = ezdxf.readfile(source)
    except (OSError, ezdxf.DXFError) as exc:
        raise CadError(source, "(file)", f"not a readable DXF file: {exc}") from exc
    code = int(doc.header.get("$INSUNITS", 0))
    if code not in DXF_UNITS and code != 0:
        raise CadError(source, "$INSUNITS", f"unsupported unit code {code}")
    unit = _unit(source, DXF_UNITS.get(code), units, "$INSUNITS")
    scale = UNITS_M[unit]
    tolerance = tolerance_m / scale
    pieces: list[Contour] = []
    marks: list[np.ndarray] = []
    curves = {"LINE", "LWPOLYLINE", "POLYLINE", "ARC", "CIRCLE", "ELLIPSE", "SPLINE"}
    for entity in doc.modelspace():
        kind = entity.dxftype()
        on = entity.dxf.get("layer", "0")
        name = f"{kind} #{entity.dxf.handle} on layer {on!r}"
        if on.lower() == ELECTRODE_LAYER:
            marks.append(_dxf_mark(source, entity, name) * scale)
            continue
        if (layer is not None and on != layer) or kind not in curves:
            continue
        try:
            shape = dxf_path.make_path(entity)
        except (TypeError, ValueError) as exc:
            raise CadError(source, name, f"cannot be flattened: {exc}") from exc
        for sub in shape.sub_paths():
            points = np.array([(v.x, v.y) for v in sub.flattening(tolerance)], dtype=np.float64)
            if points.shape[0] >= 2:
                pieces.append(Contour(points * scale, name))
    return pieces, np.array(marks, dtype=np.float64).reshape(-1, 2), unit


def _dxf_mark(source: str, entity: Any, name: str) -> np.ndarray:
    """The electrode centre an entity on the electrodes layer marks, drawing units."""
    kind = entity.dxftype()
    if kind == "POINT":
        p = entity.dxf.location
    elif kind in ("CIRCLE", "ARC"):
        p = entity.dxf.center
    elif kind == "LINE":
        p = (entity.dxf.start + entity.dxf.end) * 0.5
    else:
        raise CadError(source, name, "an electrode mark must be a POINT, CIRCLE or LINE")
    return np.array([p.x, p.y], dtype=np.float64)


# --- SVG ------------------------------------------------------------------------------

#: SVG namespace (elements are looked up with and without it).
_SVG_NS = "{http://www.w3.org/2000/svg}"
#: Root ``width`` units that state a physical size.
_SVG_UNITS = ("mm", "cm", "in", "m")
#: Shape elements read as contours (or marks).
_SVG_SHAPES = ("path", "rect", "circle", "ellipse", "polygon", "polyline", "line")


def _svg(
    source: str, units: str | None, layer: str | None, tolerance_m: float
) -> tuple[list[Contour], np.ndarray, str]:
    """Pieces in metres, electrode marks and the unit of an SVG file.

    A root ``width`` in mm, cm, in or m and the ``viewBox`` scale the user units; without one
    a user unit is ``units``. Group and element ``transform``s are applied. The sheet keeps the
    user coordinates' origin (the ``viewBox`` only scales); SVG's y axis points down, so y is
    flipped and the sheet is seen as drawn.
    """
    import re
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(source).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise CadError(source, "(file)", f"not a readable SVG file: {exc}") from exc
    match = re.fullmatch(r"\s*([0-9.eE+-]+)\s*([a-z%]*)\s*", root.get("width", ""))
    stated = match.group(2) if match and match.group(2) in _SVG_UNITS else None
    unit = _unit(source, stated, units, "<svg width>")
    view = [float(v) for v in re.split(r"[\s,]+", root.get("viewBox", "").strip()) if v]
    scale = UNITS_M[unit]
    if stated and match:
        width_m = float(match.group(1)) * UNITS_M[unit]
        scale = width_m / (view[2] if len(view) == 4 and view[2] > 0 else float(match.group(1)))
    flip = np.diag([scale, -scale, 1.0])  # user units -> metres, y up, same origin
    pieces: list[Contour] = []
    marks: list[np.ndarray] = []
    for k, (element, transform, groups) in enumerate(_svg_shapes(source, root, flip)):
        tag = element.tag.removeprefix(_SVG_NS)
        name = f"<{tag} id={element.get('id') or f'#{k}'}>"
        if ELECTRODE_LAYER in {g.lower() for g in groups}:
            marks.append(_apply(transform, _svg_mark(source, element, name))[0])
            continue
        if layer is not None and layer not in groups:
            continue
        gain = float(np.linalg.svd(transform[:2, :2], compute_uv=False).max()) or 1.0
        for points in _svg_subpaths(source, element, name, tolerance_m / gain):
            if points.shape[0] >= 2:
                pieces.append(Contour(_apply(transform, points), name))
    return pieces, np.array(marks, dtype=np.float64).reshape(-1, 2), unit


def _svg_shapes(source: str, root: Any, transform: np.ndarray):
    """``(element, user -> metre transform, ids of it and its groups)`` of every shape."""
    stack = [(root, transform, ())]
    while stack:
        node, parent, groups = stack.pop(0)
        for child in list(node):
            tag = child.tag.removeprefix(_SVG_NS) if isinstance(child.tag, str) else ""
            local = parent @ _svg_transform(source, child.get("transform", ""), tag)
            ids = (*groups, child.get("id") or "")
            if tag == "g":
                stack.append((child, local, ids))
            elif tag in _SVG_SHAPES:
                yield child, local, ids


def _svg_transform(source: str, text: str, tag: str) -> np.ndarray:
    """``[3, 3]`` matrix of an SVG ``transform`` attribute."""
    import re

    out = np.eye(3)
    for kind, args in re.findall(r"(\w+)\s*\(([^)]*)\)", text):
        v = [float(a) for a in re.split(r"[\s,]+", args.strip()) if a]
        m = np.eye(3)
        if kind == "matrix" and len(v) == 6:
            m[:2, :] = [[v[0], v[2], v[4]], [v[1], v[3], v[5]]]
        elif kind == "translate" and v:
            m[:2, 2] = [v[0], v[1] if len(v) > 1 else 0.0]
        elif kind == "scale" and v:
            m[0, 0], m[1, 1] = v[0], v[1] if len(v) > 1 else v[0]
        elif kind == "rotate" and v:
            a = math.radians(v[0])
            c, s = math.cos(a), math.sin(a)
            m[:2, :2] = [[c, -s], [s, c]]
            if len(v) == 3:
                m[:2, 2] = [v[1] - c * v[1] + s * v[2], v[2] - s * v[1] - c * v[2]]
        elif kind in ("skewX", "skewY") and v:
            m[0 if kind == "skewX" else 1, 1 if kind == "skewX" else 0] = math.tan(
                math.radians(v[0])
            )
        else:
            raise CadError(source, f"<{tag} transform={text!r}>", f"cannot read {kind}({args})")
        out = out @ m
    return out


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.asarray(points, np.float64).reshape(-1, 2) @ transform[:2, :2].T + transform[:2, 2]


def _svg_number(source: str, element: Any, name: str, key: str, default: float | None = None):
    import re

    value = element.get(key)
    if value is None:
        if default is None:
            raise CadError(source, name, f"missing {key}")
        return default
    number = re.fullmatch(r"\s*([0-9.eE+-]+)(px)?\s*", value)
    if not number:
        raise CadError(source, name, f"{key}={value!r}: expected a number in user units")
    return float(number.group(1))


def _svg_path_text(source: str, element: Any, name: str) -> str:
    """The ``d`` of an element as a path (rectangles with ``rx``/``ry`` get arcs)."""
    tag = element.tag.removeprefix(_SVG_NS)
    num = lambda key, default=None: _svg_number(source, element, name, key, default)  # noqa: E731
    if tag == "path":
        return element.get("d", "")
    if tag == "rect":
        x, y, w, h = num("x", 0.0), num("y", 0.0), num("width"), num("height")
        rx = num("rx", num("ry", 0.0))
        ry = num("ry", rx)
        rx, ry = min(rx, w / 2), min(ry, h / 2)
        if rx <= 0 or ry <= 0:
            return f"M{x},{y} H{x + w} V{y + h} H{x} Z"
        arc = f"A{rx},{ry} 0 0 1"
        return (
            f"M{x + rx},{y} H{x + w - rx} {arc} {x + w},{y + ry} V{y + h - ry} "
            f"{arc} {x + w - rx},{y + h} H{x + rx} {arc} {x},{y + h - ry} V{y + ry} "
            f"{arc} {x + rx},{y} Z"
        )
    if tag in ("circle", "ellipse"):
        cx, cy = num("cx", 0.0), num("cy", 0.0)
        rx = num("r") if tag == "circle" else num("rx")
        ry = rx if tag == "circle" else num("ry")
        arc = f"A{rx},{ry} 0 0 1"
        return f"M{cx + rx},{cy} {arc} {cx - rx},{cy} {arc} {cx + rx},{cy} Z"
    if tag == "line":
        return f"M{num('x1', 0.0)},{num('y1', 0.0)} L{num('x2', 0.0)},{num('y2', 0.0)}"
    points = element.get("points", "").strip()
    return f"M{points}" + (" Z" if tag == "polygon" else "")


def _svg_subpaths(source: str, element: Any, name: str, tolerance: float) -> list[np.ndarray]:
    """``[n, 2]`` flattened vertices (user units) of each subpath.

    Closed subpaths repeat their first point at the end.
    """
    from svg.path import Close, Line, Move, parse_path

    try:
        path = parse_path(_svg_path_text(source, element, name))
    except (ValueError, IndexError) as exc:
        raise CadError(source, name, f"cannot read the path: {exc}") from exc
    out: list[np.ndarray] = []
    current: list[np.ndarray] = []
    for segment in path:
        if isinstance(segment, Move):
            if current:
                out.append(np.concatenate(current))
            current = [np.array([[segment.end.real, segment.end.imag]])]
        elif isinstance(segment, (Line, Close)):
            current.append(np.array([[segment.end.real, segment.end.imag]]))
        else:
            current.append(_sample_curve(segment, tolerance)[1:])
    if current:
        out.append(np.concatenate(current))
    return [_deduplicated(p) for p in out]


def _deduplicated(points: np.ndarray) -> np.ndarray:
    """``points`` without consecutive repeats."""
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    tiny = 1e-9 * max(float(np.ptp(points)), 1e-12)
    return points[np.concatenate([[True], step > tiny])]


def _svg_mark(source: str, element: Any, name: str) -> np.ndarray:
    """An electrode mark's centre, user units.

    A circle's or ellipse's centre, else the first point of its outline.
    """
    tag = element.tag.removeprefix(_SVG_NS)
    if tag in ("circle", "ellipse"):
        cx = _svg_number(source, element, name, "cx", 0.0)
        return np.array([cx, _svg_number(source, element, name, "cy", 0.0)])
    return _svg_subpaths(source, element, name, 1.0)[0][0]


def _sample_curve(segment: Any, tolerance: float) -> np.ndarray:
    """``[n + 1, 2]`` points of a curve segment within ``tolerance`` of it.

    n doubles until every chord's midpoint is within ``tolerance`` of the curve's point half
    way between the chord's ends.
    """
    n = 8
    while True:
        t = np.linspace(0.0, 1.0, 2 * n + 1)
        z = np.array([segment.point(float(u)) for u in t])
        pts = np.column_stack([z.real, z.imag])
        chord_mid = 0.5 * (pts[0:-1:2] + pts[2::2])
        if np.max(np.linalg.norm(pts[1::2] - chord_mid, axis=1)) <= tolerance or n >= 4096:
            return pts[::2]
        n *= 2


# --- contours -------------------------------------------------------------------------


def _close(source: str, pieces: list[Contour]) -> list[Contour]:
    """Closed loops of the pieces: closed ones as they are, open ones chained end to end."""
    if not pieces:
        return []
    every = np.concatenate([p.points for p in pieces])
    join = JOIN_TOLERANCE * max(float(np.ptp(every, axis=0).max()), 1e-12)
    closed: list[Contour] = []
    open_: list[Contour] = []
    for p in pieces:
        if np.linalg.norm(p.points[0] - p.points[-1]) <= join and p.points.shape[0] > 3:
            closed.append(Contour(p.points[:-1], p.entity))
        else:
            open_.append(p)
    while open_:
        chain = open_.pop(0)
        points, names = chain.points, [chain.entity]
        while np.linalg.norm(points[0] - points[-1]) > join:
            end = points[-1]
            for i, other in enumerate(open_):
                if np.linalg.norm(other.points[0] - end) <= join:
                    points = np.vstack([points, other.points[1:]])
                elif np.linalg.norm(other.points[-1] - end) <= join:
                    points = np.vstack([points, other.points[-2::-1]])
                else:
                    continue
                names.append(other.entity)
                open_.pop(i)
                break
            else:
                gap = np.linalg.norm(points[0] - points[-1])
                raise CadError(
                    source,
                    ", ".join(names),
                    f"open contour: its ends ({_mm(points[0])}) and ({_mm(points[-1])}) are "
                    f"{gap * 1e3:.3g} mm apart and no other piece joins them",
                )
        closed.append(Contour(points[:-1], " + ".join(names)))
    return closed


def _mm(p: np.ndarray) -> str:
    return f"{p[0] * 1e3:.3f}, {p[1] * 1e3:.3f} mm"


def _nest(source: str, contours: list[Contour]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The outer contour (CCW) and the holes (CW) of closed contours."""
    for c in contours:
        if c.points.shape[0] >= 3 and geometry.self_intersects(c.points):
            raise CadError(source, c.entity, "contour intersects itself (or repeats a point)")
        if c.points.shape[0] < 3 or abs(geometry.signed_area(c.points)) == 0.0:
            raise CadError(source, c.entity, "degenerate contour: it encloses no area")
    for i, a in enumerate(contours):
        for b in contours[i + 1 :]:
            if geometry.polygons_intersect(a.points, b.points):
                raise CadError(source, f"{a.entity} and {b.entity}", "contours cross each other")
    inside = np.array(
        [
            [
                i != j and bool(geometry.points_in_polygon(a.points[:1], b.points)[0])
                for j, b in enumerate(contours)
            ]
            for i, a in enumerate(contours)
        ]
    )
    depth = inside.sum(axis=1)
    outer = np.flatnonzero(depth == 0)
    if outer.size > 1:
        names = "; ".join(contours[k].entity for k in outer)
        raise CadError(source, names, f"{outer.size} outer contours: a sheet has one outline")
    deep = np.flatnonzero(depth > 1)
    if deep.size:
        raise CadError(
            source, contours[int(deep[0])].entity, "contour inside a hole: islands are not sheets"
        )
    outline = contours[int(outer[0])].points
    if geometry.signed_area(outline) < 0:
        outline = np.concatenate([outline[:1], outline[:0:-1]])
    holes = []
    for k in np.flatnonzero(depth == 1):
        h = contours[int(k)].points
        holes.append(h if geometry.signed_area(h) < 0 else np.concatenate([h[:1], h[:0:-1]]))
    return outline, holes


def area_m2(drawing: Drawing) -> float:
    """Sheet area of a drawing (outline minus holes), m^2."""
    return geometry.signed_area(drawing.outline) + sum(
        geometry.signed_area(h) for h in drawing.holes
    )


def describe(drawing: Drawing) -> str:
    """One line: size, perimeter, holes, marks."""
    size = np.ptp(drawing.outline, axis=0) * 1e3
    perimeter = float(geometry.arc_positions(drawing.outline)[-1]) * 1e3
    return (
        f"{Path(drawing.source).name} ({drawing.units}): outline {size[0]:.1f} x {size[1]:.1f} mm,"
        f" {drawing.outline.shape[0]} vertices, perimeter {perimeter:.1f} mm, area "
        f"{area_m2(drawing) * 1e4:.2f} cm^2, {len(drawing.holes)} holes, "
        f"{drawing.electrode_marks.shape[0]} electrode marks"
    )
