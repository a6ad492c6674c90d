"""Holes (pixels without data: nodata values, NaN, masks) in a band's mesh.

The mesher meshes the band with its holes filled from the nearest valid pixel, so no
edge is found at a hole's rim and no nodata value reaches a vertex. Then the holes'
outlines, traced and simplified like the walls, become constraint polylines of the
triangulation, so that no triangle crosses a hole's rim, and vertices inside holes are
dropped. The hole mask itself is stored losslessly; decoders put the nodata value back.
"""

from __future__ import annotations

import numpy as np

from .errors import ATMError
from .mesh import Mesh, without_vertices
from .meshcode import in_stored_order
from .triangulate import through_vertices

#: Simplification tolerance of hole outlines, in pixels (the approximating error of the paper's edge polylines, section 3.3.2.1).
OUTLINE_ERROR = 1.0


def fill(image: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """The image with each hole pixel set to its nearest valid pixel's value."""
    import cv2

    if not holes.any():
        return image
    out = image.copy()
    if holes.all():
        out[...] = 0
        return out
    _, labels = cv2.distanceTransformWithLabels(
        holes.astype(np.uint8), cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_PIXEL
    )
    # labels number the valid pixels in raster order, from 1
    valid = np.flatnonzero(~holes.ravel())
    flat = out.reshape(holes.size, -1)
    source = valid[labels.ravel()[holes.ravel()] - 1]
    flat[holes.ravel()] = flat[source]
    return out


def outlines(holes: np.ndarray, simplify: bool = True) -> list[np.ndarray]:
    """Closed polylines (K x 2 arrays of x, y, first point repeated at the end) along
    the rim of every hole, through hole pixels only."""
    import cv2

    contours, _ = cv2.findContours(holes.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    lines = []
    for c in contours:
        if simplify and len(c) > 3:
            c = cv2.approxPolyDP(c, OUTLINE_ERROR, True)
        pts = c.reshape(-1, 2).astype(np.int64)
        if len(pts) >= 2:
            lines.append(np.concatenate([pts, pts[:1]]))
    return lines


def _on_lines(lines: list[np.ndarray], shape: tuple[int, int], thickness: int = 1) -> np.ndarray:
    import cv2

    mask = np.zeros(shape, np.uint8)
    if lines:
        cv2.polylines(mask, [p.astype(np.int32).reshape(-1, 1, 2) for p in lines], False, 1, thickness)
    return mask.astype(bool)


def _walls_clear_of(mesh: Mesh, blocked: np.ndarray) -> list[np.ndarray]:
    """The mesh's wall polylines, cut where a segment passes through a blocked pixel."""
    kept = []
    for line in mesh.constraints:
        p = mesh.vertices[line].astype(np.float64)
        a, b = p[:-1], p[1:]
        steps = np.maximum(2, (2 * np.abs(b - a).max(axis=1)).astype(np.int64) + 1)
        seg = np.repeat(np.arange(len(a)), steps)
        t = (np.arange(len(seg)) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
        q = np.rint(a[seg] + (b[seg] - a[seg]) * t[:, None]).astype(np.int64)
        hit = np.zeros(len(a), bool)
        np.logical_or.at(hit, seg, blocked[q[:, 1], q[:, 0]])
        for piece in np.split(np.arange(len(line)), np.flatnonzero(hit) + 1):
            # a blocked segment i joins line[i] and line[i+1]: pieces end at its start
            if len(piece) >= 2:
                kept.append(line[piece])
    return kept


def cut(mesh: Mesh, holes: np.ndarray) -> Mesh:
    """Give `mesh` (of the filled band) its holes: outline walls, no vertex inside.
    The result is in stored order, triangulated as a decoder rebuilds it
    (meshcode.in_stored_order)."""
    if not holes.any():
        return mesh
    h, w = holes.shape
    for simplify in (True, False):
        rims = outlines(holes, simplify)
        rim_pixels = _on_lines(rims, (h, w))
        # vertices in holes, or on a rim, would sit on or inside the new walls
        keep = ~holes[mesh.vertices[:, 1], mesh.vertices[:, 0]] & ~rim_pixels[mesh.vertices[:, 1], mesh.vertices[:, 0]]
        corners = (mesh.vertices[:, 0] % max(w - 1, 1) == 0) & (mesh.vertices[:, 1] % max(h - 1, 1) == 0)
        keep |= corners & ~np.isin(
            mesh.vertices[:, 1] * w + mesh.vertices[:, 0],
            np.concatenate([p[:, 1] * w + p[:, 0] for p in rims]) if rims else np.zeros(0, np.int64),
        )
        base = without_vertices(mesh, keep)
        walls = _walls_clear_of(base, _on_lines(rims, (h, w), thickness=3))
        rim_xy = np.concatenate(rims) if rims else np.zeros((0, 2), np.int64)
        vertices, where = np.unique(np.concatenate([base.vertices, rim_xy]), axis=0, return_inverse=True)
        where = where.ravel()
        remap = where[: len(base.vertices)]
        constraints = [remap[c] for c in walls]
        start = len(base.vertices)
        for r in rims:
            constraints.append(where[start : start + len(r)])
            start += len(r)
        # through_vertices also drops the zero-length steps of rims that double back
        constraints = through_vertices(vertices, constraints)
        values = np.zeros((len(vertices),) + mesh.values.shape[1:], mesh.dtype)
        values[remap] = base.values
        try:
            return in_stored_order(Mesh(vertices, values, np.zeros((0, 3), np.int64), w, h, constraints, holes))
        except ATMError:
            continue  # simplified rims crossed each other: trace them pixel by pixel
    # rims traced pixel by pixel never cross; if walls still do, keep the rims only
    return in_stored_order(Mesh(vertices, values, np.zeros((0, 3), np.int64), w, h, [], holes))
