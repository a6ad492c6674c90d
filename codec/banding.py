"""Bands of rows: how an image is cut for streaming, and how a band's mesh is made to
share its first row exactly with the band above it."""

from __future__ import annotations

import numpy as np

from .mesh import Mesh, segments, without_vertices
from .triangulate import through_vertices

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
    lose their first-row vertices. Triangles are left empty: the caller triangulates
    once when the band's vertices are final (meshcode.in_stored_order).
    """
    keep = mesh.vertices[:, 1] > 0
    if mesh.height == 1:
        raise ValueError("a one-row band has no row below its first")
    base = without_vertices(mesh, keep)
    top = np.stack([xs, np.zeros_like(xs)], 1).astype(np.int64)
    vertices = np.concatenate([top, base.vertices])
    vals = np.concatenate([values, base.values]).astype(mesh.dtype)
    # renumbered all at once and cut into views (an addition per wall took 2 ms for a
    # 2048-wide band's thousands)
    constraints = base.constraints
    if constraints:
        bounds = np.r_[0, np.cumsum([len(c) for c in constraints])].tolist()
        flat = np.concatenate(constraints).astype(np.int64, copy=False) + len(xs)
        constraints = [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    return Mesh(vertices, vals, np.zeros((0, 3), np.int64), mesh.width, mesh.height, constraints, mesh.holes)


def sample_last_row(mesh: Mesh, band: np.ndarray, tolerance: float) -> Mesh:
    """Add vertices on the band's last row until the row, which the next band shares and
    which decodes as a polyline through those vertices, is within `tolerance` of the
    image everywhere (per channel), or every pixel of the row is a vertex.

    Greedy, coarse to fine: each round adds, between every two neighbouring row
    vertices, the pixel of largest error if it is over the tolerance. A mesh that gets
    vertices is returned with no triangles: the caller triangulates once when the
    band's vertices are final (meshcode.in_stored_order)."""
    y = mesh.height - 1
    if y == 0 or mesh.width < 3:
        return mesh
    row = band[y].reshape(mesh.width, -1).astype(np.float64)
    xs, vals = bottom_row(mesh)
    vals = vals.reshape(len(xs), -1).astype(np.float64)
    added = []
    while True:
        pos = np.arange(mesh.width)
        k = np.clip(np.searchsorted(xs, pos, side="right") - 1, 0, len(xs) - 2)
        a, b = xs[k], xs[k + 1]
        t = ((pos - a) / np.maximum(b - a, 1))[:, None]
        approx = vals[k] * (1 - t) + vals[k + 1] * t
        err = np.abs(approx - row).max(axis=1)
        err[xs] = 0.0
        if err.max() <= tolerance:
            break
        # the worst pixel of each stretch between neighbouring vertices
        starts = xs[:-1]
        worst = np.maximum.reduceat(err, starts)
        stretch = np.flatnonzero(worst > tolerance)
        new = []
        for s in stretch:  # a loop over stretches of one row, each a numpy argmax
            lo, hi = xs[s], xs[s + 1]
            new.append(lo + int(np.argmax(err[lo:hi])))
        new = np.asarray(new, dtype=np.int64)
        added.append(new)
        order = np.argsort(np.concatenate([xs, new]), kind="stable")
        xs = np.concatenate([xs, new])[order]
        vals = np.concatenate([vals, row[new]])[order]
    if not added:
        return mesh
    new = np.concatenate(added)
    top = np.stack([new, np.full_like(new, y)], 1)
    vertices = np.concatenate([mesh.vertices, top])
    values = np.concatenate([mesh.values, band[y, new]]).astype(mesh.dtype)
    # a new vertex may sit on a wall that runs along the row: the wall then passes it.
    # Only a step with both ends on the last row has a pixel of that row inside it (the
    # band has no row below), so only walls with such a step are split (all of a
    # 2048-wide band's walls took 4 ms)
    constraints = list(mesh.constraints)
    steps = segments(constraints)
    along = (mesh.vertices[steps[:, 0], 1] == y) & (mesh.vertices[steps[:, 1], 1] == y)
    if along.any():
        owner = np.repeat(np.arange(len(constraints)), [len(c) - 1 for c in constraints])
        touched = np.unique(owner[along]).tolist()
        split = through_vertices(vertices, [constraints[k] for k in touched])
        if len(split) == len(touched):
            for k, line in zip(touched, split):
                constraints[k] = line
        else:  # a polyline of one vertex among them (none is made): all, as before
            constraints = through_vertices(vertices, mesh.constraints)
    return Mesh(vertices, values, np.zeros((0, 3), np.int64), mesh.width, mesh.height, constraints, mesh.holes)
