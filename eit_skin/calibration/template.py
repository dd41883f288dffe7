"""A printable 1:1 template for calibrating a skin by hand: sheet, electrodes, numbered targets.

:func:`spread_targets` places N press targets evenly over a layer's sheet (farthest-point
start, then Lloyd relaxation towards the centroids of the targets' cells of the whole sheet,
each snapped to the nearest allowed point: an even, blue-noise-like cover reaching out to the
margin, what a data-driven localiser needs), every target at least ``margin_m`` from the
outline, the holes and the electrodes. Targets are numbered row by row from the top, in
alternating directions, so the finger travels little from one to the next.

:func:`template_drawing` draws the sheet outline, holes, electrodes (numbered), the targets
(a cross, a fingertip circle and the number) and a 10 mm scale bar at true scale;
:func:`write_template` writes it as SVG (mm units) or PDF (vector, one page, built here: no
dependency), atomically.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.model import Layer
from eit_skin.touch.shapes import FINGER_RADIUS_M

FINGER_WIDTH_M = 2.0 * FINGER_RADIUS_M
"""A fingertip's contact width, m: targets keep this far from the edge and from each other."""

PAGE_MARGIN_M = 0.015
"""Blank paper around the drawing, m."""

SCALE_BAR_M = 0.010
"""Length of the printed scale bar, m (measure it to check the print is 1:1)."""

GRID_POINTS = 8000
"""About this many candidate points cover the sheet when spreading targets."""

LLOYD_ITERATIONS = 30
"""Lloyd relaxation steps after the farthest-point start."""


class TemplateError(ValueError):
    """Targets cannot be placed as asked: names the layer and the reason."""


def sheet_clearance(layer: Layer, points: np.ndarray) -> np.ndarray:
    """``[n]`` distance of each point ``[n, 2]`` to the outline, holes and electrodes, m.

    Negative outside the sheet or inside a hole.
    """
    pts = np.atleast_2d(np.asarray(points, float))
    outline = layer.outline
    d = geometry.distance_to_segments(pts, outline, np.roll(outline, -1, axis=0))
    inside = geometry.points_in_polygon(pts, outline)
    for hole in layer.holes:
        d = np.minimum(d, geometry.distance_to_segments(pts, hole, np.roll(hole, -1, axis=0)))
        inside &= ~geometry.points_in_polygon(pts, hole)
    tips = np.array([e.center for e in layer.electrodes]).reshape(-1, 2)
    if len(tips):
        reach = np.array([0.5 * e.width_m for e in layer.electrodes])
        d = np.minimum(d, (np.linalg.norm(pts[:, None] - tips[None], axis=2) - reach).min(axis=1))
    return np.where(inside, d, -d)


def spread_targets(layer: Layer, n: int, margin_m: float = FINGER_WIDTH_M) -> np.ndarray:
    """``[n, 2]`` press targets spread evenly over the sheet, numbered in order, m.

    Raises:
        TemplateError: ``n < 1``, no room ``margin_m`` inside the sheet, or ``n`` targets
            that would lie closer than a finger's width (:data:`FINGER_WIDTH_M`) apart.
    """
    if n < 1:
        raise TemplateError(f"layer {layer.name!r}: --targets must be >= 1, got {n}")
    lo, hi = layer.outline.min(axis=0), layer.outline.max(axis=0)
    step = float(np.sqrt(np.prod(hi - lo) / GRID_POINTS))
    gx = np.arange(lo[0] + 0.5 * step, hi[0], step)
    gy = np.arange(lo[1] + 0.5 * step, hi[1], step)
    grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    clearance = sheet_clearance(layer, grid)
    sheet, allowed = grid[clearance > 0], grid[clearance >= margin_m]
    if len(allowed) < n:
        raise TemplateError(
            f"layer {layer.name!r}: no room for {n} targets {margin_m * 1e3:g} mm inside the "
            "sheet, its holes and electrodes (smaller --margin?)"
        )
    # farthest-point start from the most central allowed point
    centre = allowed[np.argmax(sheet_clearance(layer, allowed))]
    chosen = [int(np.argmin(np.linalg.norm(allowed - centre, axis=1)))]
    nearest = np.linalg.norm(allowed - allowed[chosen[0]], axis=1)
    for _ in range(n - 1):
        chosen.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(allowed - allowed[chosen[-1]], axis=1))
    targets = allowed[chosen]
    for _ in range(LLOYD_ITERATIONS):  # centroidal Voronoi cells of the whole sheet
        owner = np.argmin(((sheet[:, None] - targets[None]) ** 2).sum(axis=2), axis=1)
        counts = np.bincount(owner, minlength=n)[:, None]
        sums = np.stack([np.bincount(owner, sheet[:, k], minlength=n) for k in (0, 1)], 1)
        moved = np.where(counts > 0, sums / np.maximum(counts, 1), targets)
        # snap into the allowed region (the margin; a non-convex cell's centroid may be out)
        targets = allowed[np.argmin(((moved[:, None] - allowed[None]) ** 2).sum(axis=2), axis=1)]
    gap = np.linalg.norm(targets[:, None] - targets[None], axis=2) + np.diag(np.full(n, np.inf))
    if n > 1 and gap.min() < FINGER_RADIUS_M:
        raise TemplateError(
            f"layer {layer.name!r}: {n} targets would lie {gap.min() * 1e3:.1f} mm apart, "
            f"closer than a fingertip radius ({FINGER_RADIUS_M * 1e3:g} mm): use fewer --targets "
            "or a smaller --margin"
        )
    return reading_order(targets, float(np.median(gap.min(axis=1))) if n > 1 else 1.0)


def reading_order(points: np.ndarray, row_m: float) -> np.ndarray:
    """``points`` [n, 2] in rows ``row_m`` high from the top, alternating in direction.

    ``row_m``: the targets' spacing; the finger then travels little from one to the next.
    """
    row = np.floor((points[:, 1].max() - points[:, 1]) / row_m + 0.5).astype(int)
    x = np.where(row % 2 == 0, points[:, 0], -points[:, 0])
    return points[np.lexsort((x, row))]


@dataclass
class Drawing:
    """Vector primitives in page millimetres (origin top left, y down), for SVG and PDF.

    Attributes:
        width_mm, height_mm: page size, mm.
        items: ``(kind, data)``: ``("path", (points [k, 2], closed, stroke_mm, colour))``
            or ``("text", (x, y, text, size_mm, anchor, colour))``; colours ``"#rrggbb"``.
    """

    width_mm: float
    height_mm: float
    items: list[tuple[str, tuple]] = field(default_factory=list)

    def path(self, points, closed=False, stroke_mm=0.3, colour="#000000") -> None:
        self.items.append(("path", (np.asarray(points, float), closed, stroke_mm, colour)))

    def text(self, x, y, text, size_mm=3.0, anchor="start", colour="#000000") -> None:
        self.items.append(("text", (float(x), float(y), str(text), size_mm, anchor, colour)))


def template_drawing(layer: Layer, targets: np.ndarray, title: str) -> Drawing:
    """The 1:1 template of ``layer`` with ``targets`` [n, 2] m numbered 1..n."""
    lo, hi = layer.outline.min(axis=0), layer.outline.max(axis=0)
    pad = PAGE_MARGIN_M * 1e3
    header = 14.0  # mm of title lines and scale bar above the sheet
    drawing = Drawing((hi[0] - lo[0]) * 1e3 + 2 * pad, (hi[1] - lo[1]) * 1e3 + 2 * pad + header)

    def page(xy: np.ndarray) -> np.ndarray:  # patch metres -> page mm (y down)
        xy = np.atleast_2d(xy)
        return np.stack(
            [(xy[:, 0] - lo[0]) * 1e3 + pad, (hi[1] - xy[:, 1]) * 1e3 + pad + header], 1
        )

    drawing.text(pad, pad - 6.0, title, 3.5)
    drawing.text(pad, pad - 1.5, "print at 100 % (actual size, no fit to page)", 2.5)
    bar_x, bar_y = pad, pad + 5.0
    drawing.path([[bar_x, bar_y], [bar_x + SCALE_BAR_M * 1e3, bar_y]], stroke_mm=0.6)
    for x in (bar_x, bar_x + SCALE_BAR_M * 1e3):
        drawing.path([[x, bar_y - 1.5], [x, bar_y + 1.5]], stroke_mm=0.3)
    drawing.text(bar_x + SCALE_BAR_M * 1e3 + 2.0, bar_y + 1.0, f"{SCALE_BAR_M * 1e3:g} mm", 2.5)
    drawing.path(page(layer.outline), closed=True, stroke_mm=0.4)
    for hole in layer.holes:
        drawing.path(page(hole), closed=True, stroke_mm=0.15, colour="#808080")
    centre = layer.outline.mean(axis=0)
    for k, electrode in enumerate(layer.electrodes):
        arc = electrode.center_m + np.linspace(-0.5, 0.5, 8) * electrode.width_m
        drawing.path(
            page(geometry.point_at_arc(layer.outline, arc)), stroke_mm=1.2, colour="#c06000"
        )
        outward = electrode.center - centre
        outward = outward / max(float(np.linalg.norm(outward)), 1e-9)
        label = page(electrode.center + 0.004 * outward)[0]
        drawing.text(label[0], label[1] + 0.8, f"E{k}", 2.0, "middle", "#c06000")
    r = FINGER_RADIUS_M * 1e3
    ring = r * np.stack(
        [np.cos(np.linspace(0, 2 * np.pi, 37)), np.sin(np.linspace(0, 2 * np.pi, 37))], 1
    )
    for k, (x, y) in enumerate(page(targets), start=1):
        drawing.path(np.array([x, y]) + ring, closed=True, stroke_mm=0.15, colour="#2060c0")
        drawing.path([[x - 1.5, y], [x + 1.5, y]], stroke_mm=0.25)
        drawing.path([[x, y - 1.5], [x, y + 1.5]], stroke_mm=0.25)
        drawing.text(x + 1.2, y - 1.2, str(k), 2.8, "start", "#2060c0")
    return drawing


def svg_text(drawing: Drawing) -> str:
    """The drawing as an SVG document whose user unit is 1 mm (``width="..mm"``)."""
    w, h = drawing.width_mm, drawing.height_mm
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.3f}mm" height="{h:.3f}mm" '
        f'viewBox="0 0 {w:.3f} {h:.3f}">',
    ]
    for kind, data in drawing.items:
        if kind == "path":
            pts, closed, stroke, colour = data
            d = "M " + " L ".join(f"{x:.3f} {y:.3f}" for x, y in pts) + (" Z" if closed else "")
            out.append(
                f'<path d="{d}" fill="none" stroke="{colour}" '
                f'stroke-width="{stroke:.3f}" stroke-linecap="round"/>'
            )
        else:
            x, y, text, size, anchor, colour = data
            safe = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            out.append(
                f'<text x="{x:.3f}" y="{y:.3f}" font-family="Helvetica, Arial, sans-serif" '
                f'font-size="{size:.3f}" text-anchor="{anchor}" fill="{colour}">{safe}</text>'
            )
    out.append("</svg>")
    return "\n".join(out) + "\n"


PT_PER_MM = 72.0 / 25.4
"""PDF points per millimetre."""

HELVETICA_AVERAGE_WIDTH = 0.556
"""Width of a Helvetica digit, in font sizes (centres the electrode labels in the PDF)."""


def pdf_bytes(drawing: Drawing) -> bytes:
    """The drawing as a one-page vector PDF at true size (standard Helvetica, no embedding)."""
    w, h = drawing.width_mm * PT_PER_MM, drawing.height_mm * PT_PER_MM
    ops = ["1 J 1 j"]
    for kind, data in drawing.items:
        if kind == "path":
            pts, closed, stroke, colour = data
            p = np.stack([pts[:, 0] * PT_PER_MM, h - pts[:, 1] * PT_PER_MM], 1)
            rgb = " ".join(f"{int(colour[i : i + 2], 16) / 255:.3f}" for i in (1, 3, 5))
            segs = [f"{p[0, 0]:.2f} {p[0, 1]:.2f} m"] + [f"{x:.2f} {y:.2f} l" for x, y in p[1:]]
            paint = "s" if closed else "S"
            ops.append(f"{rgb} RG {stroke * PT_PER_MM:.2f} w " + " ".join(segs) + f" {paint}")
        else:
            x, y, text, size, anchor, colour = data
            size_pt = size * PT_PER_MM
            if anchor == "middle":
                x -= 0.5 * len(text) * HELVETICA_AVERAGE_WIDTH * size
            rgb = " ".join(f"{int(colour[i : i + 2], 16) / 255:.3f}" for i in (1, 3, 5))
            safe = text.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")
            ops.append(
                f"BT {rgb} rg /F1 {size_pt:.2f} Tf {x * PT_PER_MM:.2f} {h - y * PT_PER_MM:.2f} Td "
                f"({safe}) Tj ET"
            )
    content = "\n".join(ops).encode("latin-1", "replace")
    objects = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {w:.2f} {h:.2f}] "
        "/Resources << /Font << /F1 4 0 R >> >> /Contents 5 0 R >>".encode(),
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica /Encoding /WinAnsiEncoding >>",
        f"<< /Length {len(content)} >>\nstream\n".encode() + content + b"\nendstream",
    ]
    out = bytearray(b"%PDF-1.4\n")
    offsets = []
    for k, body in enumerate(objects, start=1):
        offsets.append(len(out))
        out += f"{k} 0 obj\n".encode() + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objects) + 1}\n0000000000 65535 f \n".encode()
    out += b"".join(f"{o:010d} 00000 n \n".encode() for o in offsets)
    out += (
        f"trailer\n<< /Size {len(objects) + 1} /Root 1 0 R >>\nstartxref\n{xref}\n%%EOF\n".encode()
    )
    return bytes(out)


def write_template(path: str | Path, drawing: Drawing) -> None:
    """Write ``drawing`` as PDF if ``path`` ends in ``.pdf``, else SVG; atomically."""
    path = Path(path)
    data = pdf_bytes(drawing) if path.suffix.lower() == ".pdf" else svg_text(drawing).encode()
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as stream:
            stream.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
