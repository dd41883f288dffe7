"""A read CAD drawing -> the data of an ordinary one-layer patch file.

:func:`patch_data` places the electrodes at the drawing's marks, or ``count`` of them spread
evenly by arc length from the outline's first point, and takes the non-geometric sections
from a template patch or from :data:`PLACEHOLDERS` (typical values, marked in the file as
ones to measure). The drawing itself is read by :mod:`eit_skin.patch.cad_import`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.cad_import import ELECTRODE_LAYER, CadError, Drawing

#: Non-geometric sections of an imported patch without a template: typical values of the
#: shipped sheets (docs/patches.md), to be replaced by measured ones.
PLACEHOLDERS: dict[str, Any] = {
    "contact_impedance": 2.5,
    "current": 2.0e-4,
    "material": {"quantity": "pressure", "sheet_conductance": 2.0e-4, "pressure_scale": 5.0e4},
    "protocol": {"drive": "adjacent", "measure": "adjacent"},
    "solver": {"method": "greit"},
}


def patch_data(
    drawing: Drawing,
    name: str,
    count: int | None = None,
    width_m: float | None = None,
    template: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Patch-file data of a one-layer patch on ``drawing``'s sheet.

    Args:
        drawing: the sheet.
        name: patch name (``frame_id`` is ``<name>_skin_link``).
        count: electrodes spread evenly by arc length from the outline's first point; ``None``
            uses the drawing's electrode marks.
        width_m: electrode width, m; default the template's, else a quarter of the spacing
            (at most 10 mm).
        template: parsed patch data whose first layer gives every non-geometric key
            (material, current, contact impedance, electrode width, protocol, mesh, solver);
            the 3-D placement and mount are the new sheet's own (default: a plane).

    Raises:
        CadError: neither marks nor a count, or both, or fewer than 4 electrodes.
    """
    marks = drawing.electrode_marks
    if count is None and marks.shape[0] == 0:
        raise CadError(
            drawing.source,
            ELECTRODE_LAYER,
            "no electrode marks in the drawing: give --electrodes N to spread N evenly",
        )
    if count is not None and marks.shape[0] > 0:
        raise CadError(
            drawing.source,
            ELECTRODE_LAYER,
            f"the drawing marks {marks.shape[0]} electrodes and --electrodes {count} was "
            "given: use one or the other",
        )
    n = count if count is not None else marks.shape[0]
    if n < 4:
        raise CadError(drawing.source, ELECTRODE_LAYER, f"{n} electrodes: at least 4 needed")
    layer_t = dict(((template or {}).get("layers") or [{}])[0])
    el_t = dict(layer_t.get("electrodes") or {})
    perimeter = float(geometry.arc_positions(drawing.outline)[-1])
    if width_m is None:
        width_m = el_t.get("width") or min(0.25 * perimeter / n, 0.01)
    electrodes: dict[str, Any] = {"width": _round(width_m)}
    if count is not None:
        electrodes.update(layout="even", count=n)
    else:
        electrodes["positions"] = _mark_positions(drawing, marks)
    electrodes["contact_impedance"] = el_t.get(
        "contact_impedance", PLACEHOLDERS["contact_impedance"]
    )
    layer: dict[str, Any] = {
        "name": layer_t.get("name", "pressure"),
        "outline": {"type": "polygon", "points": _rounded(drawing.outline)},
    }
    if drawing.holes:
        layer["holes"] = [{"type": "polygon", "points": _rounded(h)} for h in drawing.holes]
    layer["electrodes"] = electrodes
    layer["current"] = layer_t.get("current", PLACEHOLDERS["current"])
    for key in ("material", "protocol", "mesh", "solver"):
        if key in layer_t:
            layer[key] = layer_t[key]
        elif key in PLACEHOLDERS:
            layer[key] = PLACEHOLDERS[key]
    return {"name": name, "frame_id": f"{name}_skin_link", "layers": [layer]}


def _mark_positions(drawing: Drawing, marks: np.ndarray) -> list[list[float]]:
    """Marks projected onto the outline, counter-clockwise from its first point."""
    arc, distance = geometry.project_onto_polygon(marks, drawing.outline)
    projected = geometry.point_at_arc(drawing.outline, arc)
    size = float(np.ptp(drawing.outline, axis=0).max())
    far = np.flatnonzero(distance > 0.05 * size)
    if far.size:
        k = int(far[0])
        raise CadError(
            drawing.source,
            f"{ELECTRODE_LAYER} mark {k} at ({marks[k, 0] * 1e3:.2f}, {marks[k, 1] * 1e3:.2f}) mm",
            f"{distance[k] * 1e3:.2f} mm from the outline (more than 5 % of the sheet's size)",
        )
    return _rounded(projected[np.argsort(arc, kind="stable")])


def _round(value: float) -> float:
    return float(f"{value:.7g}")


def _rounded(points: np.ndarray) -> list[list[float]]:
    """Points in metres rounded to 0.1 um, as YAML-friendly lists."""
    return [[round(float(x), 7), round(float(y), 7)] for x, y in points]
