"""The canonical triangulation of format version 6 (format_spec/ATM.md §4.2.5).

Any constrained Delaunay triangulation (Triangle's, with its input in any order and by
any of its algorithms) differs from the canonical one only where four vertices are
exactly cocircular. Lawson flips with the perturbed predicate (lifts raised by
infinitesimals that decrease in raster order) turn any triangulation of the vertices
and constraints into the unique one: this module makes them in rounds of independent
flips, vectorised: the first round tests every free edge, later ones only the edges
around the last round's flips. verify() checks the result from scratch.
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
    """canonicalise's triangles and the number of flips it made to reach them.

    Side i of triangle t (number 3t + i) is the edge from its corner i to corner
    i + 1; `twin` holds the number of the same edge's side in the neighbouring
    triangle (-1 on the border). The first round tests every free edge; a flip can
    make only the four outer edges of its quadrilateral illegal, so later rounds test
    just those."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    n, flips = len(vertices), 0
    if len(tris) < 2:
        return tris, flips
    x, y = vertices[:, 0], vertices[:, 1]
    corner = tris.ravel()  # a view: corner[s] is the first end of side s
    # the side after and before each side in its triangle (the first end of the one
    # before is the corner opposite): side numbers never change, only what they hold
    first = 3 * np.arange(len(tris))[:, None]
    nxt = (first + np.array([1, 2, 0])).ravel()
    prv = (first + np.array([2, 0, 1])).ravel()
    keys = _edge_keys(corner, corner[nxt], n)
    order = np.argsort(keys)
    sorted_keys = keys[order]
    at = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    one, other = order[at], order[at + 1]
    twin = np.full(len(corner), -1, np.int64)
    twin[one], twin[other] = other, one
    # only shared edges can be constraints that matter: the border is never flipped
    fixed = np.zeros(len(corner), bool)
    constrained = constraint_keys(constraints, n)
    if len(constrained) and len(at):
        # each constraint looked up among the shared edges' sorted keys
        shared = sorted_keys[at]
        hit = np.minimum(np.searchsorted(shared, constrained), len(shared) - 1)
        hit = hit[shared[hit] == constrained]
        fixed[one[hit]] = fixed[other[hit]] = True
    sides = one[~fixed[one]]
    while len(sides):
        across = twin[sides]
        a, b, c = corner[sides], corner[nxt[sides]], corner[prv[sides]]
        d = corner[prv[across]]
        bad = np.flatnonzero(_flips(x, y, a, b, c, d))
        if len(bad) == 0:
            break
        # an independent set: a side is flipped this round if it has the smallest
        # number among the bad ones of both its triangles (the smallest overall always
        # has), so no triangle takes part in two flips
        t1, t2 = sides[bad] // 3, across[bad] // 3
        owner = np.full(len(tris), len(sides), np.int64)
        np.minimum.at(owner, t1, bad)
        np.minimum.at(owner, t2, bad)
        chosen = (owner[t1] == bad) & (owner[t2] == bad)
        moved = np.zeros(len(tris), bool)
        moved[t1[chosen]] = moved[t2[chosen]] = True
        # bad sides left for a later round keep their numbers unless a flip moved them
        # (then they are outer sides of that flip, tested anyway)
        waiting = sides[bad[~chosen & ~moved[t1] & ~moved[t2]]]
        j = bad[chosen]
        s1, s2, t1, t2 = sides[j], across[j], t1[chosen], t2[chosen]
        a, b, c, d = a[j], b[j], c[j], d[j]
        # (a, b, c) and (b, a, d) become (a, d, c) and (d, b, c); each outer side keeps
        # its edge, so its twin and mark, under a new number
        old = np.stack([nxt[s2], prv[s1], prv[s2], nxt[s1]], 1).ravel()
        new = np.stack([3 * t1, 3 * t1 + 2, 3 * t2, 3 * t2 + 1], 1).ravel()
        renumber = np.arange(len(twin))
        renumber[old] = new
        outer, outer_fixed = twin[old], fixed[old]
        outer = np.where(outer >= 0, renumber[np.maximum(outer, 0)], -1)
        tris[t1] = np.stack([a, d, c], 1)
        tris[t2] = np.stack([d, b, c], 1)
        twin[new], fixed[new] = outer, outer_fixed
        twin[outer[outer >= 0]] = new[outer >= 0]
        twin[3 * t1 + 1], twin[3 * t2 + 2] = 3 * t2 + 2, 3 * t1 + 1
        fixed[3 * t1 + 1] = fixed[3 * t2 + 2] = False
        flips += len(j)
        # the flipped diagonal is legal (the rule is antisymmetric); test the outer
        # sides that are free edges, each once
        free = (outer >= 0) & ~outer_fixed
        sides = np.unique(np.concatenate([np.minimum(new[free], outer[free]), waiting]))
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
    bad = _flips(vertices[:, 0], vertices[:, 1], *edges[:4])
    if bad.any():
        raise ATMError(f"{int(bad.sum())} free edges are not locally Delaunay after the canonical pass")


def random_flips(vertices: np.ndarray, triangles: np.ndarray, constraints: np.ndarray | None,
                 rng: np.random.Generator, share: float, ties_only: bool = False) -> np.ndarray:
    """Another triangulation of the same vertices with the same constraints as edges,
    for tests and conformance files: of the free edges whose quadrilateral is strictly
    convex (only exact ties if ties_only), about `share` flipped, no two in one
    triangle."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    e = free_edges(tris, len(vertices), constraint_keys(constraints, len(vertices)))
    a, b, c, d = (vertices[p] for p in e[:4])
    ok = (orient2d(a, d, c) > 0) & (orient2d(d, b, c) > 0)
    if ties_only:
        ok &= incircle_sign(a, b, c, d) == 0
    used = np.zeros(len(tris), bool)
    for j in rng.permutation(np.flatnonzero(ok)).tolist():
        if not used[e.t1[j]] and not used[e.t2[j]] and rng.random() < share:
            used[[e.t1[j], e.t2[j]]] = True
            tris[e.t1[j]] = [e.a[j], e.d[j], e.c[j]]
            tris[e.t2[j]] = [e.d[j], e.b[j], e.c[j]]
    return tris


def tie_count(vertices: np.ndarray, triangles: np.ndarray,
              constraints: np.ndarray | None = None) -> tuple[int, int]:
    """(free edges, those whose quadrilateral is exactly cocircular) of a triangulation."""
    vertices = np.asarray(vertices, dtype=np.int64)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    edges = free_edges(tris, len(vertices), constraint_keys(constraints, len(vertices)))
    s = _incircle_sign(vertices[:, 0], vertices[:, 1], *edges[:4])
    return len(s), int(np.count_nonzero(s == 0))


def constraint_keys(constraints: np.ndarray | None, n: int) -> np.ndarray:
    """The sorted undirected keys of the constraint edges (none if there are none; a
    repeated one is harmless to the look-ups)."""
    if constraints is None:
        return np.zeros(0, np.int64)
    c = np.asarray(constraints, dtype=np.int64).reshape(-1, 2)
    return np.sort(_edge_keys(c[:, 0], c[:, 1], n))


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


def _flips(x: np.ndarray, y: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
           d: np.ndarray) -> np.ndarray:
    """Per edge ab of triangles (a, b, c) and (b, a, d), vertex coordinates x, y:
    whether the perturbed rule flips it (incircle > 0, or = 0 with a or b the first of
    the four corners in raster order)."""
    s = _incircle_sign(x, y, a, b, c, d)
    tie = np.flatnonzero(s == 0)
    flip = s > 0
    if len(tie):
        # raster order compares (y, x); a key y * width + x over the span does it
        width = int(x.max() - x.min()) + 1
        key = lambda v: y[v[tie]] * width + x[v[tie]]  # noqa: E731
        flip[tie] = np.minimum(key(a), key(b)) < np.minimum(key(c), key(d))
    return flip


def orient2d(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Doubled signed area of each triangle abc (int64: exact for coordinates below 2^31)."""
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def incircle_sign(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The exact sign (-1, 0, 1) of incircle(a, b, c, d) per row of integer points (K x
    2 each): positive iff d is inside the circle through a, b, c when abc is positively
    oriented."""
    xy = np.concatenate([a, b, c, d]).astype(np.int64)
    k = np.arange(len(a))
    return _incircle_sign(xy[:, 0], xy[:, 1], k, k + len(a), k + 2 * len(a), k + 3 * len(a))


def _incircle_sign(x: np.ndarray, y: np.ndarray, a: np.ndarray, b: np.ndarray,
                   c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """incircle_sign of the vertices numbered a, b, c, d, with coordinates x, y.

    binary64 is exact for small extents; larger ones are decided by it where its error
    bound allows and by Python integers on the rest, which are few (ties among them)."""
    xf, yf = x.astype(np.float64), y.astype(np.float64)
    # differences of integers below 2^53 are exact in binary64
    adx, ady = xf[a] - xf[d], yf[a] - yf[d]
    bdx, bdy = xf[b] - xf[d], yf[b] - yf[d]
    cdx, cdy = xf[c] - xf[d], yf[c] - yf[d]
    alift, blift, clift = adx * adx + ady * ady, bdx * bdx + bdy * bdy, cdx * cdx + cdy * cdy
    bc, ca, ab = bdx * cdy - bdy * cdx, cdx * ady - cdy * adx, adx * bdy - ady * bdx
    det = alift * bc + blift * ca + clift * ab
    sign = np.sign(det).astype(np.int64)
    if len(x) == 0 or max(np.ptp(x), np.ptp(y)) <= FLOAT_EXACT:
        return sign
    extent = np.max(np.abs([adx, ady, bdx, bdy, cdx, cdy]), axis=0)
    unsure = extent > FLOAT_EXACT
    bound = _ERROR * (alift * np.abs(bc) + blift * np.abs(ca) + clift * np.abs(ab))
    unsure &= (np.abs(det) <= bound) | (extent > _FILTERED)
    for i in np.flatnonzero(unsure).tolist():
        p = [(int(x[v[i]]) - int(x[d[i]]), int(y[v[i]]) - int(y[d[i]])) for v in (a, b, c)]
        sign[i] = _exact_incircle_sign(*p)
    return sign


def _exact_incircle_sign(ad: tuple[int, int], bd: tuple[int, int], cd: tuple[int, int]) -> int:
    """incircle's sign in Python integers, from the differences to d."""
    (adx, ady), (bdx, bdy), (cdx, cdy) = ad, bd, cd
    det = (
        (adx * adx + ady * ady) * (bdx * cdy - bdy * cdx)
        + (bdx * bdx + bdy * bdy) * (cdx * ady - cdy * adx)
        + (cdx * cdx + cdy * cdy) * (adx * bdy - ady * bdx)
    )
    return (det > 0) - (det < 0)
