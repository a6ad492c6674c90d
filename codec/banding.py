"""Bands of rows: how an image is cut for streaming, and how a band's mesh is made to
share its first row exactly with the band above it."""

from __future__ import annotations

import numpy as np

from .mesh import Mesh, without_vertices
from .triangulate import triangulate

#: Default band size in pixels: bands of about a megapixel keep the encoder's working
#: memory small while leaving the mesher room to place vertices freely.
BAND_PIXELS = 1 << 20
MIN_BAND_HEIGHT = 16


def default_band_height(width: int, height: int) -> int:
    """New rows per band: about BAND_PIXELS pixels per band, at least MIN_BAND_HEIGHT rows;
    an image that fits in one band is one band."""
    return max(MIN_BAND_HEIGHT, BAND_PIXELS // max(width, 1))


def bottom_row(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """The x positions (sorted) and values of the vertices on the mesh's last row."""
    on = np.flatnonzero(mesh.vertices[:, 1] == mesh.height - 1)
    on = on[np.argsort(mesh.vertices[on, 0], kind="stable")]
    return mesh.vertices[on, 0].copy(), mesh.values[on].copy()


def pin_top_row(mesh: Mesh, xs: np.ndarray, values: np.ndarray) -> Mesh:
    """Replace the vertices of the mesh's first row by the given ones (the previous band's
    last row), so both bands decode that row identically.

    Vertices below the first row keep their positions and values; constraint polylines
    lose their first-row vertices; only the triangles touching the first row change.
    """
    keep = mesh.vertices[:, 1] > 0
    if mesh.height == 1:
        raise ValueError("a one-row band has no row below its first")
    base = without_vertices(mesh, keep)
    top = np.stack([xs, np.zeros_like(xs)], 1).astype(np.int64)
    vertices = np.concatenate([top, base.vertices])
    vals = np.concatenate([values, base.values]).astype(mesh.dtype)
    constraints = [c + len(xs) for c in base.constraints]
    segments = (
        np.concatenate([np.stack([c[:-1], c[1:]], 1) for c in constraints]) if constraints else None
    )
    triangles = triangulate(vertices, segments)
    return Mesh(vertices, vals, triangles, mesh.width, mesh.height, constraints, mesh.holes)
