"""Stage 3: unfold each edge polyline into two parallel polylines, the walls' feet.

For every control point P an exploration line crosses the edge: it bisects the two
segments meeting at P (at the polyline's ends it is perpendicular to the end segment).
The pixels along it are read outwards on both sides of P; the first one whose value
differs significantly from P's is P's opposite point O (significant: at least half of
the largest difference found within `reach` pixels on that side, and at least
`min_step`). When no side changes significantly, O is P's neighbour on the side that
changes most, so that every control point still gets a partner.

The pairs (P, O) are then swapped so that each of the two new polylines keeps to one
side of the edge: the *left* polyline collects, at every control point, whichever of
P and O lies to the left of the polyline's direction, the *right* one the other. As
triangulate() refuses crossing constraints, walls that would cross each other or any
other wall are cut back: of two conflicting segments the one from the weaker
polyline (or the later one) is dropped, its vertices kept as plain samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .polylines import Polylines


@dataclass(eq=False)
class Walls:
    """Wall feet (N x 2 int64 (x, y)), the wall segments between them (S x 2 indices
    into points, wall by wall in order along each), none meeting another but at a
    shared end, and the wall of each segment (2k: left of polyline k, 2k+1: right)."""

    points: np.ndarray
    segments: np.ndarray
    wall: np.ndarray


def _directions(lines: Polylines) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangent at every control point (the bisecting direction of the two segments
    meeting there; the end segment's direction at the ends) and its left normal."""
    p = lines.points.astype(np.float64)
    n = len(p)
    line_of = np.repeat(np.arange(len(lines)), np.diff(lines.starts))
    seg = np.zeros((n + 1, 2))
    d = p[1:] - p[:-1]
    same = line_of[1:] == line_of[:-1]
    length = np.hypot(d[:, 0], d[:, 1])
    unit = np.where((same & (length > 0))[:, None], d / np.maximum(length, 1e-12)[:, None], 0.0)
    seg[1:n] = unit  # seg[i]: unit vector of the segment ending at point i
    t = seg[:n] + seg[1 : n + 1]
    norm = np.hypot(t[:, 0], t[:, 1])
    # a hairpin (opposite segments) has no bisector: fall back to the incoming segment
    t = np.where((norm > 1e-6)[:, None], t / np.maximum(norm, 1e-12)[:, None], seg[:n] + seg[1:] * 0)
    zero = np.hypot(t[:, 0], t[:, 1]) < 1e-6
    t[zero] = seg[1 : n + 1][zero]
    left = np.stack([t[:, 1], -t[:, 0]], axis=1)  # left of the direction of travel, y down
    return t, left


def opposite_points(
    lines: Polylines, gray: np.ndarray, *, reach: int = 3, min_step: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """(left, right): the two wall feet at each control point, N x 2 int64 each."""
    h, w = gray.shape
    p = lines.points.astype(np.int64)
    tangent, normal = _directions(lines)
    steps = np.arange(1, reach + 1, dtype=np.float64)
    sides = []
    for sign in (1.0, -1.0):
        q = np.rint(p[:, None, :] + sign * steps[None, :, None] * normal[:, None, :]).astype(np.int64)
        q[..., 0] = np.clip(q[..., 0], 0, w - 1)
        q[..., 1] = np.clip(q[..., 1], 0, h - 1)
        change = np.abs(gray[q[..., 1], q[..., 0]] - gray[p[:, 1], p[:, 0]][:, None])
        # a step that lands back on P (clipped at the border) is no partner
        change[(q == p[:, None, :]).all(axis=2)] = -1.0
        biggest = change.max(axis=1)
        limit = np.maximum(0.5 * biggest, min_step)
        hit = change >= limit[:, None]
        first = np.where(hit.any(axis=1), np.argmax(hit, axis=1), reach)
        sides.append((q, change, first))
    (qa, ca, fa), (qb, cb, fb) = sides
    rows = np.arange(len(p))
    # the side whose change comes first wins; a tie goes to the larger change
    take_a = (fa < fb) | ((fa == fb) & (ca[rows, np.minimum(fa, reach - 1)] >= cb[rows, np.minimum(fb, reach - 1)]))
    # no significant change on either side: the neighbour on the side that changes more
    none = (fa == reach) & (fb == reach)
    take_a = np.where(none, ca[:, 0] >= cb[:, 0], take_a)
    ia = np.where(none, 0, np.minimum(fa, reach - 1))
    ib = np.where(none, 0, np.minimum(fb, reach - 1))
    opp = np.where(take_a[:, None], qa[rows, ia], qb[rows, ib])
    stuck = (opp == p).all(axis=1)  # both sides clipped away (a 1-pixel-wide image)
    opp[stuck] = p[stuck]
    # the paper's swap (section 3.3.2.1): each polyline keeps the points on its own side of the edge
    rel = opp - p
    on_left = rel[:, 0] * normal[:, 0] + rel[:, 1] * normal[:, 1] > 0
    left = np.where(on_left[:, None], opp, p)
    right = np.where(on_left[:, None], p, opp)
    return left, right


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.sign((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def conflicts(points: np.ndarray, segments: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """For segment pairs (i, j): do they meet anywhere but at a shared end point?"""
    a, b = points[segments[i, 0]], points[segments[i, 1]]
    c, d = points[segments[j, 0]], points[segments[j, 1]]
    o1, o2 = _orient(a, b, c), _orient(a, b, d)
    o3, o4 = _orient(c, d, a), _orient(c, d, b)
    collinear = (o1 == 0) & (o2 == 0)
    # collinear: compare the extents along the axis a-b runs along most
    k = (np.abs(b[:, 0] - a[:, 0]) < np.abs(b[:, 1] - a[:, 1])).astype(np.int64)
    r = np.arange(len(i))
    lo1, hi1 = np.minimum(a[r, k], b[r, k]), np.maximum(a[r, k], b[r, k])
    lo2, hi2 = np.minimum(c[r, k], d[r, k]), np.maximum(c[r, k], d[r, k])
    overlap = np.minimum(hi1, hi2) - np.maximum(lo1, lo2)
    si, sj = segments[i], segments[j]
    shared = (si[:, :1] == sj).any(axis=1) | (si[:, 1:] == sj).any(axis=1)
    general = ~collinear & (o1 * o2 <= 0) & (o3 * o4 <= 0)
    # sharing an end point, two segments conflict only by running along each other
    return np.where(shared, collinear & (overlap > 0), general | (collinear & (overlap >= 0)))


def drop_conflicts(points: np.ndarray, segments: np.ndarray, cell: int = 8) -> np.ndarray:
    """Keep-mask over segments such that no two kept ones meet anywhere but at a shared
    end point: of two that do, the later goes. Candidates are the pairs whose bounding
    boxes share a cell of a `cell`-pixel grid; the test is exact."""
    keep = np.ones(len(segments), dtype=bool)
    if len(segments) < 2:
        return keep
    a, b = points[segments[:, 0]], points[segments[:, 1]]
    lo, hi = np.minimum(a, b) // cell, np.maximum(a, b) // cell
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = nx * ny
    seg = np.repeat(np.arange(len(segments)), count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    stride = int(hi[:, 0].max()) + 2
    key = (lo[seg, 1] + k // nx[seg]) * stride + lo[seg, 0] + k % nx[seg]
    order = np.lexsort((seg, key))
    key, seg = key[order], seg[order]
    after = np.searchsorted(key, key, side="right") - np.arange(len(key)) - 1
    first = np.repeat(np.arange(len(key)), after)
    second = first + 1 + np.arange(int(after.sum())) - np.repeat(np.cumsum(after) - after, after)
    i, j = seg[first], seg[second]
    # a pair sharing several cells is kept in one: the first cell of the boxes' overlap
    corner = np.maximum(lo[i], lo[j])
    once = key[first] == corner[:, 1] * stride + corner[:, 0]
    i, j = i[once], j[once]
    bad = conflicts(points, segments, i, j)
    keep[np.maximum(i[bad], j[bad])] = False
    return keep


def unfold(lines: Polylines, gray: np.ndarray, *, min_step: float = 4.0) -> Walls:
    """The parallel polylines of every edge polyline, with crossing walls cut back.

    Polylines earlier in `lines` win conflicts: order them by importance first.
    """
    if len(lines.points) == 0:
        return Walls(np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    left, right = opposite_points(lines, gray, min_step=min_step)
    n = len(left)
    points = np.concatenate([left, right])
    # one vertex per pixel: merge the feet that landed on the same pixel, first come
    # first numbered
    key = points[:, 1] * gray.shape[1] + points[:, 0]
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    ids = rank[inverse.ravel()]
    merged = points[first[order]]
    # segments of the left walls, then the right walls, polyline by polyline
    line_of = np.repeat(np.arange(len(lines)), np.diff(lines.starts))
    step = np.flatnonzero(line_of[1:] == line_of[:-1])
    segs = np.concatenate([np.stack([ids[step], ids[step + 1]], 1), np.stack([ids[n + step], ids[n + step + 1]], 1)])
    rank = np.concatenate([line_of[step] * 2, line_of[step] * 2 + 1])
    order = np.argsort(rank, kind="stable")
    segs, rank = segs[order], rank[order]
    real = segs[:, 0] != segs[:, 1]
    segs, rank = segs[real], rank[real]
    # the same segment twice (feet merged): keep the first
    key = np.minimum(segs[:, 0], segs[:, 1]) * len(merged) + np.maximum(segs[:, 0], segs[:, 1])
    once = np.sort(np.unique(key, return_index=True)[1])
    segs, rank = segs[once], rank[once]
    keep = drop_conflicts(merged, segs)
    return Walls(merged, segs[keep], rank[keep])
