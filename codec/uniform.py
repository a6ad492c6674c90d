"""The uniform mesher: a regular grid of samples, the seed's comparison baseline."""

from __future__ import annotations

import math

import numpy as np

from . import values as vertex_values
from .mesh import Mesh
from .triangulate import triangulate


def grid_shape(width: int, height: int, points: int) -> tuple[int, int]:
    """Columns and rows of a grid with about `points` nodes and the image's aspect."""
    points = max(points, 1)
    nx = max(1, round(math.sqrt(points * width / height)))
    nx = min(nx, width)
    ny = min(height, max(1, round(points / nx)))
    if width > 1:
        nx = max(nx, 2)
    if height > 1:
        ny = max(ny, 2)
    return nx, ny


def build(image: np.ndarray, points: int, *, values: str = "sample") -> Mesh:
    """Mesh `image` with a uniform grid of about `points` vertices."""
    height, width = image.shape[:2]
    nx, ny = grid_shape(width, height, points)
    xs = np.unique(np.round(np.linspace(0, width - 1, nx)).astype(np.int64))
    ys = np.unique(np.round(np.linspace(0, height - 1, ny)).astype(np.int64))
    gx, gy = np.meshgrid(xs, ys)
    vertices = np.stack([gx.ravel(), gy.ravel()], axis=1)
    triangles = triangulate(vertices)
    vals = vertex_values.fit(image, vertices, triangles, values)
    return Mesh(vertices, vals, triangles, width, height)
