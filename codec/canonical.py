"""The canonical triangulation of format version 6 (format_spec/ATM.md §4.2.5).

Any constrained Delaunay triangulation (Triangle's, with its input in any order and by
any of its algorithms) differs from the canonical one only where four vertices are
exactly cocircular. Lawson flips with the perturbed predicate (lifts raised by
infinitesimals that decrease in raster order) turn any triangulation of the vertices
and constraints into the unique one: this module makes them in rounds of independent
flips, each round vectorised over all free edges.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .errors import ATMError
from .mesh import _edge_keys

#: Largest coordinate difference at which binary64 evaluates incircle exactly: the
#: differences are below 2^12, lifts and 2x2 minors below 2^25 and the sum of the three
#: products below 3 * 2^50 < 2^53, so every operation is exact.
FLOAT_EXACT = 4095

#: Largest coordinate difference at which the lifts and minors are still exact in
#: binary64 (below 2^51), so only the three products and two sums round.
_FILTERED = 1 << 25

#: Relative bound on the rounding of those five operations (5 ulp, with a margin).
_ERROR = 8.0 * 2.0**-53


class FreeEdges(NamedTuple):
    """The free edges of a triangulation (shared by two triangles, no constraint): edge
    ab of triangle t1 = (a, b, c), whose other triangle t2 = (b, a, d)."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    t1: np.ndarray
    t2: np.ndarray


def canonicalise(vertices: np.ndarray, triangles: np.ndarray,
                 constraints: np.ndarray | None = None, *, check: bool = False) -> np.ndarray:
    """The canonical triangulation (ATM.md §4.2.5) from any triangulation of the same
    integer (x, y) vertices in which every constraint (pairs of vertex indices, none
    passing over a vertex) is an edge. Triangles are positively oriented (doubled area
    > 0) before and after. check: verify afterwards that every free edge is locally
    Delaunay by the perturbed rule (for tests; raises ATMError otherwise)."""
    tris, _ = flip_to_canonical(vertices, triangles, constraints)
    if check:
        verify(vertices, tris, constraints)
    return tris


def flip_to_canonical(vertices: np.ndarray, triangles: np.ndarray,
                      constraints: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """canonicalise's triangles and the number of flips it made to reach them."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    n, flips = len(vertices), 0
    if len(tris) < 2:
        return tris, flips
    rank = raster_rank(vertices)
    fixed = constraint_keys(constraints, n)
    while True:
        edges = free_edges(tris, n, fixed)
        bad = _not_locally_delaunay(vertices, rank, edges)
        if not bad.any():
            break
        # an independent set: an edge is flipped this round if it has the smallest
        # number among the bad edges of both its triangles (the smallest overall always
        # has), so no triangle takes part in two flips
        j = np.flatnonzero(bad)
        owner = np.full(len(tris), len(bad), np.int64)
        np.minimum.at(owner, edges.t1[j], j)
        np.minimum.at(owner, edges.t2[j], j)
        j = j[(owner[edges.t1[j]] == j) & (owner[edges.t2[j]] == j)]
        a, b, c, d = edges.a[j], edges.b[j], edges.c[j], edges.d[j]
        tris[edges.t1[j]] = np.stack([a, d, c], 1)
        tris[edges.t2[j]] = np.stack([d, b, c], 1)
        flips += len(j)
    return tris, flips


def verify(vertices: np.ndarray, triangles: np.ndarray, constraints: np.ndarray | None = None) -> None:
    """Raise ATMError unless every free edge of the triangulation is locally Delaunay
    by the perturbed rule of ATM.md §4.2.5 (every triangle positively oriented)."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    n = len(vertices)
    if len(tris) and (orient2d(*(vertices[tris[:, i]] for i in range(3))) <= 0).any():
        raise ATMError("a triangle of the canonical pass is not positively oriented")
    edges = free_edges(tris, n, constraint_keys(constraints, n))
    bad = _not_locally_delaunay(vertices, raster_rank(vertices), edges)
    if bad.any():
        raise ATMError(f"{int(bad.sum())} free edges are not locally Delaunay after the canonical pass")


def tie_count(vertices: np.ndarray, triangles: np.ndarray,
              constraints: np.ndarray | None = None) -> tuple[int, int]:
    """(free edges, those whose quadrilateral is exactly cocircular) of a triangulation."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    edges = free_edges(tris, len(vertices), constraint_keys(constraints, len(vertices)))
    s = incircle_sign(*(vertices[p] for p in edges[:4]))
    return len(s), int(np.count_nonzero(s == 0))


def raster_rank(vertices: np.ndarray) -> np.ndarray:
    """Each vertex's place in raster order (smallest y, then smallest x, first)."""
    rank = np.empty(len(vertices), np.int64)
    rank[np.lexsort((vertices[:, 0], vertices[:, 1]))] = np.arange(len(vertices))
    return rank


def constraint_keys(constraints: np.ndarray | None, n: int) -> np.ndarray:
    """The sorted undirected keys of the constraint edges (none if there are none)."""
    if constraints is None:
        return np.zeros(0, np.int64)
    c = np.asarray(constraints, dtype=np.int64).reshape(-1, 2)
    return np.unique(_edge_keys(c[:, 0], c[:, 1], n))


def free_edges(triangles: np.ndarray, n: int, fixed: np.ndarray) -> FreeEdges:
    """The edges shared by two of the triangles whose undirected key is not in the
    sorted `fixed` keys, each once."""
    src = triangles.ravel()
    dst = triangles[:, [1, 2, 0]].ravel()
    opp = triangles[:, [2, 0, 1]].ravel()
    keys = _edge_keys(src, dst, n)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    # in a triangulation an edge has at most two sides, so equal keys come in pairs
    at = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    if len(fixed):
        hit = np.minimum(np.searchsorted(fixed, sorted_keys[at]), len(fixed) - 1)
        at = at[fixed[hit] != sorted_keys[at]]
    e1, e2 = order[at], order[at + 1]
    return FreeEdges(src[e1], dst[e1], opp[e1], opp[e2], e1 // 3, e2 // 3)


def _not_locally_delaunay(vertices: np.ndarray, rank: np.ndarray, edges: FreeEdges) -> np.ndarray:
    """Per free edge ab: whether the perturbed rule flips it (incircle > 0, or = 0 with
    a or b the first of the four corners in raster order)."""
    s = incircle_sign(*(vertices[p] for p in edges[:4]))
    tie = np.flatnonzero(s == 0)
    flip = s > 0
    if len(tie):
        on_edge = np.minimum(rank[edges.a[tie]], rank[edges.b[tie]])
        off_edge = np.minimum(rank[edges.c[tie]], rank[edges.d[tie]])
        flip[tie] = on_edge < off_edge
    return flip


def orient2d(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Doubled signed area of each triangle abc (int64: exact for coordinates below 2^31)."""
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def incircle_sign(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The exact sign (-1, 0, 1) of incircle(a, b, c, d) per row of integer points:
    positive iff d is inside the circle through a, b, c when abc is positively oriented.

    binary64 is exact for small extents; larger ones are decided by it where its error
    bound allows and by Python integers on the rest, which are few (ties among them)."""
    ad, bd, cd = a - d, b - d, c - d
    extent = np.abs(np.concatenate([ad, bd, cd], 1)).max(1)
    adx, ady, bdx, bdy, cdx, cdy = (v.astype(np.float64) for v in (ad[:, 0], ad[:, 1], bd[:, 0], bd[:, 1], cd[:, 0], cd[:, 1]))
    alift, blift, clift = adx * adx + ady * ady, bdx * bdx + bdy * bdy, cdx * cdx + cdy * cdy
    bc, ca, ab = bdx * cdy - bdy * cdx, cdx * ady - cdy * adx, adx * bdy - ady * bdx
    det = alift * bc + blift * ca + clift * ab
    sign = np.sign(det).astype(np.int64)
    unsure = extent > FLOAT_EXACT
    if unsure.any():
        bound = _ERROR * (alift * np.abs(bc) + blift * np.abs(ca) + clift * np.abs(ab))
        unsure &= (np.abs(det) <= bound) | (extent > _FILTERED)
        for i in np.flatnonzero(unsure).tolist():
            sign[i] = _exact_incircle_sign(ad[i].tolist(), bd[i].tolist(), cd[i].tolist())
    return sign


def _exact_incircle_sign(ad: list[int], bd: list[int], cd: list[int]) -> int:
    """incircle's sign in Python integers, from the differences to d."""
    (adx, ady), (bdx, bdy), (cdx, cdy) = ad, bd, cd
    det = (
        (adx * adx + ady * ady) * (bdx * cdy - bdy * cdx)
        + (bdx * bdx + bdy * bdy) * (cdx * ady - cdy * adx)
        + (cdx * cdx + cdy * cdy) * (adx * bdy - ady * bdx)
    )
    return (det > 0) - (det < 0)
