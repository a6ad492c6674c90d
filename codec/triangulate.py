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


def uncrossed(vertices: np.ndarray, polylines: list[np.ndarray], cell: int = 8) -> list[np.ndarray]:
    """The polylines without the segments that properly cross an earlier one (a later
    polyline, or a later segment of the same one, gives way), each cut where a segment
    went. Candidate pairs come from a grid of `cell`-pixel buckets, the test is exact."""
    if not polylines:
        return polylines
    v = np.asarray(vertices, dtype=np.int64)
    lens = np.array([len(c) - 1 for c in polylines])
    a = np.concatenate([c[:-1] for c in polylines])
    b = np.concatenate([c[1:] for c in polylines])
    if len(a) < 2:
        return polylines
    p, q = v[a], v[b]
    lo, hi = np.minimum(p, q) // cell, np.maximum(p, q) // cell
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = nx * ny
    seg = np.repeat(np.arange(len(a)), count)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(count) - count, count)
    cx = lo[seg, 0] + k % nx[seg]
    cy = lo[seg, 1] + k // nx[seg]
    key = cy * (int(cx.max()) + 2) + cx
    order = np.lexsort((seg, key))
    key, seg = key[order], seg[order]
    pairs = []
    d = 1
    while True:
        same = key[d:] == key[:-d]
        if not same.any():
            break
        pairs.append(np.stack([seg[:-d][same], seg[d:][same]], 1))
        d += 1
    if not pairs:
        return polylines
    pr = np.sort(np.concatenate(pairs), axis=1)
    pk = np.unique(pr[:, 0] * len(a) + pr[:, 1])  # one test per pair of segments
    i, j = pk // len(a), pk % len(a)
    shared = (a[i] == a[j]) | (a[i] == b[j]) | (b[i] == a[j]) | (b[i] == b[j])

    def orient(o, s, t):
        return np.sign((s[:, 0] - o[:, 0]) * (t[:, 1] - o[:, 1]) - (s[:, 1] - o[:, 1]) * (t[:, 0] - o[:, 0]))

    o1, o2 = orient(p[i], q[i], p[j]), orient(p[i], q[i], q[j])
    o3, o4 = orient(p[j], q[j], p[i]), orient(p[j], q[j], q[i])
    proper = (o1 * o2 < 0) & (o3 * o4 < 0) & ~shared
    # collinear overlap of two segments that share no vertex also needs a new vertex
    collinear = (o1 == 0) & (o2 == 0) & ~shared
    if collinear.any():
        axis = np.where(np.abs(q[i, 0] - p[i, 0]) >= np.abs(q[i, 1] - p[i, 1]), 0, 1)
        r = np.arange(len(i))
        lo_i = np.minimum(p[i][r, axis], q[i][r, axis])
        hi_i = np.maximum(p[i][r, axis], q[i][r, axis])
        lo_j = np.minimum(p[j][r, axis], q[j][r, axis])
        hi_j = np.maximum(p[j][r, axis], q[j][r, axis])
        proper |= collinear & (np.minimum(hi_i, hi_j) > np.maximum(lo_i, lo_j))
    dropped = np.zeros(len(a), bool)
    dropped[j[proper]] = True
    if not dropped.any():
        return polylines
    out = []
    start = 0
    for line, n in zip(polylines, lens):
        cut = np.flatnonzero(dropped[start : start + n])
        start += n
        bounds = np.r_[0, cut + 1]
        ends = np.r_[cut + 1, n + 1]
        for s, e in zip(bounds, ends):
            piece = line[s:e]
            if len(piece) >= 2:
                out.append(piece)
    return out
