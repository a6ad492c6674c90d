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

from .. import native
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
    _, normal = _directions(lines)
    if gray.dtype not in (np.float32, np.float64):
        gray = gray.astype(np.float64)
    # every control point's exploration in one compiled pass (the numpy arithmetic, in
    # gray's precision: the same feet)
    return native._polylines.opposite_feet(
        np.ascontiguousarray(lines.points, dtype=np.int64), np.ascontiguousarray(normal), np.ascontiguousarray(gray),
        int(reach), float(min_step),
    )


def drop_conflicts(points: np.ndarray, segments: np.ndarray, cell: int = 8) -> np.ndarray:
    """Keep-mask over segments such that no two kept ones meet anywhere but at a shared
    end point: of two that do, the later goes. Candidates are the pairs whose bounding
    boxes share a cell of a `cell`-pixel grid; the test is exact (integer orientations;
    collinear segments by their overlap), in a compiled pass
    (codec._polylines.later_conflicts)."""
    if len(segments) < 2:
        return np.ones(len(segments), dtype=bool)
    return ~native._polylines.later_conflicts(
        np.ascontiguousarray(points, dtype=np.int64), np.ascontiguousarray(segments, dtype=np.int64), cell
    )


def unfold(lines: Polylines, gray: np.ndarray, *, min_step: float = 4.0) -> Walls:
    """The parallel polylines of every edge polyline, with crossing walls cut back.

    Polylines earlier in `lines` win conflicts: order them by importance first.
    """
    if len(lines.points) == 0:
        return Walls(np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    left, right = opposite_points(lines, gray, min_step=min_step)
    # one vertex per pixel (the feet that landed on the same pixel merged, first come
    # first numbered); the segments of each polyline's left wall, then its right wall;
    # none whose ends merged, none twice: one compiled pass
    merged, segs, rank = native._polylines.wall_segments(
        np.ascontiguousarray(left, dtype=np.int64), np.ascontiguousarray(right, dtype=np.int64),
        np.ascontiguousarray(lines.starts, dtype=np.int64), gray.shape[1], gray.shape[0])
    keep = drop_conflicts(merged, segs)
    return Walls(merged, segs[keep], rank[keep])
