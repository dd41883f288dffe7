"""The 3-D contact fields of ``Contact`` and ``TouchEvent``: a sheet point on the placed surface.

Contacts and touches are found in sheet coordinates (``centroid``: metres, patch frame, z = 0
on the flat sheet). The patch's placement (:mod:`eit_skin.patch.placement`) lays the sheet on
the robot in that same frame, as the skin markers are drawn; ``position`` and ``normal`` are
the centroid carried onto it and the surface's outward unit normal there, so a controller
that transforms them through TF gets a point on the robot's surface.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from eit_skin.patch.placement import Placement


def place_on_surface(items: Sequence[Any], placement: Placement, points_xy: Any) -> None:
    """Set ``position`` and ``normal`` of each message in ``items`` from its sheet point.

    Args:
        items: ``Contact`` or ``TouchEvent`` messages (anything with ``position`` and
            ``normal`` of x, y, z).
        placement: the patch's placement.
        points_xy: ``[n, 2]`` sheet points, m, patch frame, one per item (NaN: NaN fields).
    """
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    if not len(pts):
        return
    xyz, normals = placement.to_3d(pts), placement.normals(pts)
    for item, p, n in zip(items, xyz.tolist(), normals.tolist(), strict=True):
        item.position.x, item.position.y, item.position.z = p
        item.normal.x, item.normal.y, item.normal.z = n
