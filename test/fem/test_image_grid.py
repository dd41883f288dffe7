from __future__ import annotations

import numpy as np
import pytest

from eit_skin.fem.image_grid import ImageGrid, locate_points
from eit_skin.fem.mesh import Mesh


def square_with_hole() -> Mesh:
    """3x3 unit squares (metres), centre square missing (a hole), 2 triangles per square."""
    xs = np.arange(4.0)
    nodes = np.array([(x, y) for y in xs for x in xs])
    tris = []
    for j in range(3):
        for i in range(3):
            if (i, j) == (1, 1):
                continue
            a, b, c, d = j * 4 + i, j * 4 + i + 1, (j + 1) * 4 + i + 1, (j + 1) * 4 + i
            tris += [(a, b, c), (a, c, d)]
    return Mesh(nodes=nodes, triangles=np.array(tris, dtype=np.int64), electrode_edges=())


def test_locate_points_exact():
    mesh = square_with_hole()
    pts = np.array([[0.9, 0.1], [0.1, 0.9], [1.5, 1.5], [5.0, 5.0], [2.5, 0.2]])
    found = locate_points(mesh, pts)
    assert found[0] == 0 and found[1] == 1  # lower-right and upper-left triangle of square 0
    assert found[2] == -1 and found[3] == -1  # hole, outside
    assert found[4] == 4  # square (2, 0), lower-right triangle


def test_grid_coordinates_mask_and_values():
    mesh = square_with_hole()
    grid = ImageGrid.build(mesh, 6)
    np.testing.assert_allclose(grid.x, np.arange(6) * 0.5 + 0.25)
    np.testing.assert_allclose(grid.y, np.arange(6) * 0.5 + 0.25)
    values = np.arange(mesh.n_triangles, dtype=float)
    img = grid.to_image(values)
    assert img.dtype == np.float32 and img.shape == (6, 6)
    assert np.isnan(img[2:4, 2:4]).all()  # the hole
    assert np.isfinite(img).sum() == 32
    # every pixel shows the value of the triangle under its centre
    xx, yy = np.meshgrid(grid.x, grid.y)
    owner = locate_points(mesh, np.column_stack([xx.ravel(), yy.ravel()])).reshape(6, 6)
    ok = owner >= 0
    np.testing.assert_array_equal(img[ok], values[owner[ok]])


def test_batch_and_rectangular_grid():
    mesh = square_with_hole()
    grid = ImageGrid.build(mesh, 8, bounding_box=(0.0, 0.0, 3.0, 1.5))
    assert grid.shape == (4, 8)
    vals = np.random.default_rng(0).normal(size=(5, mesh.n_triangles))
    imgs = grid.to_image(vals)
    assert imgs.shape == (5, 4, 8)
    np.testing.assert_array_equal(imgs[3], grid.to_image(vals[3]))
    xx, yy = np.meshgrid(grid.x, grid.y)
    in_hole = (xx > 1) & (xx < 2) & (yy > 1)
    np.testing.assert_array_equal(np.isnan(imgs), np.broadcast_to(in_hole, imgs.shape))


def test_bad_arguments():
    mesh = square_with_hole()
    with pytest.raises(ValueError, match="pixels"):
        ImageGrid.build(mesh, 1)
    grid = ImageGrid.build(mesh, 4)
    with pytest.raises(ValueError, match="N=16"):
        grid.to_image(np.zeros(3))
