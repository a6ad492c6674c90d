"""Constrained Delaunay triangulation of sample pixels with the `triangle` library."""

from __future__ import annotations

import numpy as np
import triangle

from .errors import ATMError
from .mesh import orient


def triangulate(vertices: np.ndarray, segments: np.ndarray | None = None) -> np.ndarray:
    """Triangulate integer (x, y) vertices, keeping every segment (pairs of vertex
    indices) as an edge. Returns M x 3 positively oriented triangles, or none when all
    vertices lie on one row or column (a one-pixel-wide image needs no triangles).

    The vertex set is used as given: a triangulation that would need an extra vertex
    (crossing segments) is refused, because vertices must stay on pixel centres.
    """
    vertices = np.asarray(vertices, dtype=np.int64)
    if len(vertices) < 3 or np.ptp(vertices[:, 0]) == 0 or np.ptp(vertices[:, 1]) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    data = {"vertices": vertices.astype(np.float64)}
    switches = "Q"
    if segments is not None and len(segments):
        data["segments"] = np.asarray(segments, dtype=np.int32).reshape(-1, 2)
        switches = "pcQ"
    result = triangle.triangulate(data, switches)
    if len(result["vertices"]) != len(vertices):
        raise ATMError(
            "constraint segments cross each other, so the triangulation would need vertices "
            "off the pixel grid"
        )
    return orient(vertices, result["triangles"])


def through_vertices(vertices: np.ndarray, polylines: list[np.ndarray]) -> list[np.ndarray]:
    """The polylines with every vertex that lies exactly on one of their segments put
    in its place along the segment. A constrained triangulation splits a segment at
    such vertices, so these are the polylines whose steps are its edges."""
    if not polylines:
        return polylines
    v = np.asarray(vertices, dtype=np.int64)
    width = int(v[:, 0].max()) + 1
    keys = v[:, 1] * width + v[:, 0]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    out = []
    for line in polylines:
        a, b = v[line[:-1]], v[line[1:]]
        d = b - a
        g = np.gcd(np.abs(d[:, 0]), np.abs(d[:, 1]))
        steps = np.maximum(g, 1)
        # lattice points a + k (b - a) / g, k = 0 .. g-1, of every segment, then the end
        seg = np.repeat(np.arange(len(a)), steps)
        k = np.arange(len(seg)) - np.repeat(np.cumsum(steps) - steps, steps)
        pts = a[seg] + (d[seg] // steps[seg, None]) * k[:, None]
        pts = np.concatenate([pts, v[line[-1:]]])
        pk = pts[:, 1] * width + pts[:, 0]
        at = np.clip(np.searchsorted(sorted_keys, pk), 0, len(keys) - 1)
        hit = sorted_keys[at] == pk
        idx = order[at[hit]]
        # a zero-length step is no edge
        out.append(idx[np.r_[True, idx[1:] != idx[:-1]]])
    return out

