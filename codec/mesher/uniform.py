"""The uniform mesher: a regular grid of samples, the comparison baseline of section 3.3.2.3 of
"Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes"."""

from __future__ import annotations

import math

import numpy as np

from . import values as vertex_values
from ..mesh import Mesh
from ..meshcode import in_stored_order
from . import Finish, Meshed
from ..triangulate import triangulate


def grid_shape(width: int, height: int, points: int) -> tuple[int, int]:
    """Columns and rows of a grid with about `points` nodes and the image's aspect.

    Among grids whose count is within 10 % of `points`, the one whose spacing is most
    nearly square wins; if none is that close, the closest count wins. A side longer
    than one pixel always has its two end pixels in the grid.
    """
    lo_x, lo_y = min(width, 2), min(height, 2)
    best = None
    for ny in range(lo_y, min(height, max(points // lo_x, lo_y)) + 1):
        nx = int(min(width, max(lo_x, round(points / ny))))
        miss = abs(nx * ny - points) / points
        spacing_x = (width - 1) / max(nx - 1, 1)
        spacing_y = (height - 1) / max(ny - 1, 1)
        skew = abs(math.log((spacing_x + 1) / (spacing_y + 1)))
        score = (miss > 0.1, miss if miss > 0.1 else skew)
        if best is None or score < best[0]:
            best = (score, nx, ny)
    return best[1], best[2]


def build(image: np.ndarray, points: int, finish: Finish | None = None, *, values: str = "sample") -> Meshed:
    """Mesh `image` with a uniform grid of about `points` vertices. finish: changes the
    mesh just before it is triangulated (codec.mesher.Finish)."""
    height, width = image.shape[:2]
    nx, ny = grid_shape(width, height, points)
    xs = np.unique(np.round(np.linspace(0, width - 1, nx)).astype(np.int64))
    ys = np.unique(np.round(np.linspace(0, height - 1, ny)).astype(np.int64))
    gx, gy = np.meshgrid(xs, ys)
    # row by row: raster order, the stored order, so this is the decoder's triangulation
    vertices = np.stack([gx.ravel(), gy.ravel()], axis=1)
    if finish is not None:
        grid = Mesh(vertices, vertex_values.sample(image, vertices), np.zeros((0, 3), np.int64), width, height)
        mesh = in_stored_order(finish(grid, None))
        vals = vertex_values.fit(image, mesh.vertices, mesh.triangles, values)
        return Meshed(Mesh(mesh.vertices, vals, mesh.triangles, width, height, mesh.constraints), delaunay=True)
    triangles = triangulate(vertices)
    vals = vertex_values.fit(image, vertices, triangles, values)
    return Meshed(Mesh(vertices, vals, triangles, width, height), delaunay=True)
