"""Disk meshes for the forward-model tests and bench (PyPI ``triangle``, boundary on the circle).

Electrode endpoints are boundary vertices placed exactly on the circle and Triangle is told
not to split boundary segments (``Y``), so every boundary node lies on the circle and the
electrode edges are known by construction.
"""

from __future__ import annotations

import numpy as np
import triangle

from eit_skin.fem.mesh import Mesh


def disk_mesh(
    radius_m: float = 0.05,
    n_electrodes: int = 16,
    electrode_width_rad: float = 0.1,
    h_m: float = 0.005,
    electrode_centres_rad: np.ndarray | None = None,
    electrode_h_m: float | None = None,
    min_angle_deg: float = 30.0,
    sliver_offset_m: float = 0.0,
) -> Mesh:
    """Disk of ``radius_m`` with electrodes centred at ``electrode_centres_rad`` (CCW).

    ``h_m`` is the boundary spacing and sets the interior triangle area (~h^2 sqrt(3)/4);
    ``electrode_h_m`` (default ``h_m``) is the node spacing under the electrodes;
    ``min_angle_deg = 0`` switches Triangle's quality bound off; ``sliver_offset_m > 0`` then
    adds a vertex ``sliver_offset_m`` inside the circle below the middle of every electrode edge,
    which makes sliver triangles (aspect ~ edge / offset) along the electrodes.
    """
    if electrode_centres_rad is None:
        electrode_centres_rad = 2 * np.pi * np.arange(n_electrodes) / n_electrodes
    centres = np.asarray(electrode_centres_rad, dtype=float)
    eh = h_m if electrode_h_m is None else electrode_h_m
    half = electrode_width_rad / 2
    # boundary angles: electrodes finely, gaps with spacing h
    angles, on_electrode = [], []
    order = np.argsort(centres % (2 * np.pi))
    starts = centres[order] % (2 * np.pi) - half
    ends = starts + electrode_width_rad
    for i in range(len(starts)):
        n_e = max(1, int(np.ceil(electrode_width_rad * radius_m / eh)))
        a = starts[i] + electrode_width_rad * np.arange(n_e) / n_e
        angles.append(a)
        on_electrode.append(np.full(n_e, order[i]))
        gap_end = starts[(i + 1) % len(starts)] + (2 * np.pi if i + 1 == len(starts) else 0)
        gap = gap_end - ends[i]
        n_g = max(1, int(np.ceil(gap * radius_m / h_m)))
        angles.append(ends[i] + gap * np.arange(n_g) / n_g)
        on_electrode.append(np.full(n_g, -1))
    angles = np.concatenate(angles)
    owner = np.concatenate(on_electrode)  # segment i -> i+1 lies on electrode owner[i] or -1
    nb = len(angles)
    pts = radius_m * np.column_stack([np.cos(angles), np.sin(angles)])
    seg = np.column_stack([np.arange(nb), (np.arange(nb) + 1) % nb])
    if sliver_offset_m > 0:
        chord_mid = 0.5 * (pts[seg[:, 0]] + pts[seg[:, 1]])[owner >= 0]
        r = np.linalg.norm(chord_mid, axis=1, keepdims=True)
        pts = np.vstack([pts, chord_mid * (1 - sliver_offset_m / r)])
    area = h_m * h_m * np.sqrt(3) / 4
    out = triangle.triangulate(
        {"vertices": pts, "segments": seg},
        (f"pq{min_angle_deg:g}" if min_angle_deg > 0 else "p") + f"a{area:.12f}YQ",
    )
    nodes = out["vertices"]
    tri = out["triangles"].astype(np.int64)
    d1 = nodes[tri[:, 1]] - nodes[tri[:, 0]]
    d2 = nodes[tri[:, 2]] - nodes[tri[:, 0]]
    cw = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] < 0
    tri[cw] = tri[cw][:, [0, 2, 1]]
    edges = tuple(seg[owner == i].astype(np.int64) for i in range(len(centres)))
    return Mesh(nodes=nodes, triangles=tri, electrode_edges=edges)
