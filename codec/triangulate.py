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
