"""Triangular meshes of skin sheets.

A :class:`Mesh` is the geometry the forward model and the image grid work on:
linear triangles in the patch frame (metres), plus, for every electrode, the
boundary edges it covers (complete electrode model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Mesh:
    """A 2-D triangle mesh of one sheet.

    Attributes:
        nodes: ``[n_nodes, 2]`` float64 node coordinates, metres, patch frame.
        triangles: ``[n_triangles, 3]`` int64 node indices, counter-clockwise.
        electrode_edges: one ``[k_i, 2]`` int64 array per electrode: the boundary
            edges (node index pairs) under electrode ``i``, electrodes numbered
            counter-clockwise as in the patch config.
    """

    nodes: np.ndarray
    triangles: np.ndarray
    electrode_edges: tuple[np.ndarray, ...]

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def n_electrodes(self) -> int:
        return len(self.electrode_edges)

    @property
    def areas(self) -> np.ndarray:
        """``[n_triangles]`` triangle areas, m^2 (positive for CCW triangles)."""
        p = self.nodes[self.triangles]
        d1 = p[:, 1] - p[:, 0]
        d2 = p[:, 2] - p[:, 0]
        return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])

    @property
    def centroids(self) -> np.ndarray:
        """``[n_triangles, 2]`` triangle centroids, metres."""
        return self.nodes[self.triangles].mean(axis=1)
