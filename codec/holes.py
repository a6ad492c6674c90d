"""Holes (pixels without data: nodata values, NaN, masks) in a band's mesh.

The mesher meshes the band with its holes filled from the nearest valid pixel, so no
edge is found at a hole's rim and no nodata value reaches a vertex. Then the holes'
outlines, traced and simplified like the walls (more coarsely when they would take
more than RIM_SHARE of the band's vertices; never crossing each other), become
constraint polylines of the triangulation, so that no triangle crosses a hole's rim,
and vertices inside holes are dropped. The hole mask itself is stored losslessly; decoders put the nodata value back.
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


#: Share of a band's vertex budget that hole rims may take: beyond it they are
#: simplified more coarsely (RIM_ERRORS, in turn), then the smallest holes go without
#: a rim. A hole keeps its exact pixels either way (the mask is stored losslessly); a
#: rim only keeps triangles from bridging it.
RIM_SHARE = 0.3
RIM_ERRORS = (OUTLINE_ERROR, 2.0, 4.0, 8.0, 16.0)


def _contours(holes: np.ndarray) -> list[np.ndarray]:
    """Every hole's outer outline and every island's, pixel by pixel (K x 2 int64)."""
    import cv2

    found, _ = cv2.findContours(holes.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    return [c.reshape(-1, 2).astype(np.int64) for c in found]


def _closed(contour: np.ndarray, error: float | None) -> np.ndarray:
    """The contour simplified to `error` pixels (None: as traced), closed."""
    contour, at = _simplified(contour, error)
    return _points(contour, at)


def _points(contour: np.ndarray, at: np.ndarray) -> np.ndarray:
    return np.concatenate([contour, contour[:1]])[at]


def _simplified(contour: np.ndarray, error: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(the contour, maybe started at another of its points; the indices of the points
    its simplification to `error` pixels keeps (None: all), increasing, the last
    len(contour): the first point again, closing it)."""
    import cv2

    n = len(contour)
    if error is None or n <= 3:
        return contour, np.arange(n + 1)
    simple = cv2.approxPolyDP(contour.reshape(-1, 1, 2).astype(np.int32), error, True).reshape(-1, 2)
    if len(simple) < 2:
        return contour, np.arange(n + 1)
    # the kept points in the contour's order (approxPolyDP keeps a subsequence, maybe
    # rotated), each found at its first position after the one before
    key = contour[:, 1] * (int(contour[:, 0].max()) + 1) + contour[:, 0]
    want = simple[:, 1].astype(np.int64) * (int(contour[:, 0].max()) + 1) + simple[:, 0]
    start = int(np.flatnonzero(key == want[0])[0])
    key = np.roll(key, -start)
    at, j = [], 0
    contour = np.roll(contour, -start, axis=0)
    for q in want:
        found = np.flatnonzero(key[j:] == q)
        if len(found) == 0:
            return contour, np.arange(n + 1)
        j += int(found[0])
        at.append(j)
    return contour, np.unique(np.r_[at, n])


def _crossing_steps(polylines: list[np.ndarray]) -> list[np.ndarray]:
    """Per polyline (K x 2 points), which of its steps properly cross another step, of
    the same polyline or another (a crossing a triangulation with only pixel centres as
    vertices cannot keep). Steps that only touch or overlap do not count:
    codec.triangulate.through_vertices splits them at the vertices they share."""
    counts = [max(len(p) - 1, 0) for p in polylines]
    hit = np.zeros(sum(counts), bool)
    if not hit.size:
        return [np.zeros(c, bool) for c in counts]
    seg = np.concatenate([np.stack([p[:-1], p[1:]], 1) for p in polylines if len(p) >= 2])  # S x 2 x 2
    lo, hi = seg.min(axis=1), seg.max(axis=1)
    # steps meet only where their boxes share a grid cell: pairs are tested cell by cell
    cell = 16
    c0, c1 = lo // cell, hi // cell
    nx, ny = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
    n = nx * ny
    which = np.repeat(np.arange(len(seg)), n)
    k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    key = (c0[which, 1] + k // nx[which]) * (int(c1[:, 0].max()) + 2) + c0[which, 0] + k % nx[which]
    order = np.argsort(key, kind="stable")
    key, which = key[order], which[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    size = np.diff(np.r_[start, len(key)])
    per = np.repeat(size, size)  # the size of every entry's cell
    left = np.repeat(np.arange(len(key)), per)
    right = np.repeat(np.repeat(start, size), per) + np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    a, b = which[left], which[right]
    keep = a < b
    a, b = a[keep], b[keep]
    p, q, r, t = seg[a, 0], seg[a, 1], seg[b, 0], seg[b, 1]

    def orient(u, v, w):
        return np.sign((v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0]))

    proper = (orient(p, q, r) * orient(p, q, t) < 0) & (orient(r, t, p) * orient(r, t, q) < 0)
    hit[a[proper]] = True
    hit[b[proper]] = True
    return np.split(hit, np.cumsum(counts)[:-1])


def crossing(polylines: list[np.ndarray]) -> np.ndarray:
    """Which polylines have a step that properly crosses another step (_crossing_steps)."""
    return np.array([bool(h.any()) for h in _crossing_steps(polylines)], bool)


def rims(holes: np.ndarray, budget: int | None = None) -> list[np.ndarray]:
    """Closed polylines along the holes' rims (through hole pixels, first point
    repeated at the end), no two of their steps crossing, with at most about `budget`
    vertices in all (None: no limit): as finely as that allows (RIM_ERRORS), then the
    largest holes' only."""
    contours = [c for c in _contours(holes) if len(c) >= 2]
    if not contours:
        return []
    level = 0
    if budget is not None:
        while level + 1 < len(RIM_ERRORS) and sum(
            len(_simplified(c, RIM_ERRORS[level])[1]) - 1 for c in contours
        ) > budget:
            level += 1
    contours, kept = map(list, zip(*(_simplified(c, RIM_ERRORS[level]) for c in contours)))
    alive = np.ones(len(contours), bool)
    while True:
        live = np.flatnonzero(alive)
        hits = _crossing_steps([_points(contours[i], kept[i]) for i in live])
        if not any(h.any() for h in hits):
            break
        # a crossing step gets back the traced point midway along it; when only steps
        # between neighbouring traced pixels cross, their holes go without a rim
        refined = False
        for i, h in zip(live, hits):
            at = kept[i]
            lo, hi = at[:-1][h], at[1:][h]
            long = hi - lo >= 2
            if long.any():
                kept[i] = np.unique(np.r_[at, (lo[long] + hi[long]) // 2])
                refined = True
        if not refined:
            alive[[i for i, h in zip(live, hits) if h.any()]] = False
    live = np.flatnonzero(alive)
    if budget is not None:
        # the largest holes keep their rims (by outline length)
        size = np.array([len(kept[i]) - 1 for i in live])
        by_length = np.argsort([-len(contours[i]) for i in live], kind="stable")
        live = np.sort(live[by_length[np.cumsum(size[by_length]) <= max(budget, 0)]])
    return [_points(contours[i], kept[i]) for i in live]


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


def _dropped(mesh: Mesh, holes: np.ndarray, outline: list[np.ndarray]) -> np.ndarray:
    """Which of the mesh's vertices cut() drops: in a hole or on a rim, unless an
    image corner off the rims."""
    h, w = holes.shape
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    drop = holes[y, x] | _on_lines(outline, (h, w))[y, x]
    corners = (x % max(w - 1, 1) == 0) & (y % max(h - 1, 1) == 0)
    rim_keys = np.concatenate([p[:, 1] * w + p[:, 0] for p in outline]) if outline else np.zeros(0, np.int64)
    return drop & ~(corners & ~np.isin(y * w + x, rim_keys))


def kept(mesh: Mesh, holes: np.ndarray, outline: list[np.ndarray]) -> int:
    """How many of the mesh's vertices cut(mesh, holes, outline) keeps, besides the rims'."""
    return int(np.count_nonzero(~_dropped(mesh, holes, outline)))


def cut(mesh: Mesh, holes: np.ndarray, outline: list[np.ndarray] | None = None) -> Mesh:
    """Give `mesh` (of the filled band) its holes: outline walls, no vertex inside.
    outline: the rims to use (rims(holes, budget)'s; None: rims(holes)). The result is
    in stored order, triangulated as a decoder rebuilds it (meshcode.in_stored_order)."""
    if not holes.any():
        return mesh
    outlined = cut_open(mesh, holes, outline)
    try:
        return in_stored_order(outlined)
    except ATMError:
        # walls that cross no rim still crossed: keep the rims only
        rim_only = [c for c in outlined.constraints if holes[outlined.vertices[c, 1], outlined.vertices[c, 0]].all()]
        return in_stored_order(Mesh(outlined.vertices, outlined.values, outlined.triangles, outlined.width,
                                    outlined.height, rim_only, holes))


def cut_open(mesh: Mesh, holes: np.ndarray, outline: list[np.ndarray] | None = None) -> Mesh:
    """cut()'s vertices and walls, not triangulated: the mesh's vertices off the holes
    and their rims, its walls that cross no rim, and the rims (`outline`; None:
    rims(holes)) as closed polylines."""
    h, w = holes.shape
    outline = rims(holes) if outline is None else outline
    # vertices in holes, or on a rim, would sit on or inside the new walls
    base = without_vertices(mesh, ~_dropped(mesh, holes, outline))
    walls = _walls_clear_of(base, _on_lines(outline, (h, w), thickness=3))
    # a wall may still cross a rim where it passes one of the rim's corners
    crossed = crossing([base.vertices[c] for c in walls] + outline)[: len(walls)]
    walls = [c for c, bad in zip(walls, crossed) if not bad]
    rim_xy = np.concatenate(outline) if outline else np.zeros((0, 2), np.int64)
    vertices, where = np.unique(np.concatenate([base.vertices, rim_xy]), axis=0, return_inverse=True)
    where = where.ravel()
    remap = where[: len(base.vertices)]
    constraints = [remap[c] for c in walls]
    start = len(base.vertices)
    for r in outline:
        constraints.append(where[start : start + len(r)])
        start += len(r)
    values = np.zeros((len(vertices),) + mesh.values.shape[1:], mesh.dtype)
    values[remap] = base.values
    # through_vertices also drops the zero-length steps of rims that double back
    lines = through_vertices(vertices, constraints)
    return Mesh(vertices, values, np.zeros((0, 3), np.int64), w, h, lines, holes)
