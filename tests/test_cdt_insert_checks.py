"""Triangulation.insert's checks (a position taken, outside the hull) made without
locating each point first: on hulls of every shape, with points on the hull, just off
it and at taken positions, a batch stops at exactly its first refused point and what
went in is delaunay()'s triangulation."""

from __future__ import annotations

import numpy as np
import pytest

from codec.errors import ATMError
from codec.triangulate import Triangulation, delaunay


def _inside(hull: np.ndarray, q: np.ndarray) -> bool:
    """q in the convex polygon `hull` (counterclockwise, y down as the kernel's
    orientation has it) or on it."""
    a, b = hull, np.roll(hull, -1, axis=0)
    return bool(np.all((b[:, 0] - a[:, 0]) * (q[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[0] - a[:, 0]) >= 0))


def _start(rng: np.random.Generator, shape: str) -> tuple[np.ndarray, np.ndarray]:
    """(first vertices, their hull's corners in the kernel's orientation)."""
    if shape == "rectangle":
        w, h = int(rng.integers(5, 60)), int(rng.integers(5, 60))
        hull = np.array([[0, 0], [0, h], [w, h], [w, 0]])
    elif shape == "triangle":
        hull = np.array([[0, 0], [0, 40], [50, 20]])
    else:  # a pentagon with slanted sides
        hull = np.array([[10, 0], [0, 20], [15, 45], [45, 35], [40, 5]])
    hull = hull + 3  # points just off it stay at non-negative coordinates
    if not _inside(hull, hull.mean(axis=0)):
        hull = hull[::-1]
    lo, hi = hull.min(axis=0), hull.max(axis=0)
    cand = np.stack([rng.integers(lo[0], hi[0] + 1, 300), rng.integers(lo[1], hi[1] + 1, 300)], 1)
    inner = np.array([q for q in cand if _inside(hull, q)])[: int(rng.integers(0, 40))].reshape(-1, 2)
    # vertices on the hull's sides (straight stretches of it, which the checks must
    # not take for corners), where a side has lattice points
    sides = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        g = int(np.gcd(*(b - a)))
        if g > 1:
            sides.append(a + (b - a) // g * int(rng.integers(1, g)))
    first = np.concatenate([hull, np.array(sides).reshape(-1, 2), inner]).astype(np.int64)
    _, keep = np.unique(first[:, 1] * 1000 + first[:, 0], return_index=True)
    return rng.permutation(first[np.sort(keep)]), hull


@pytest.mark.parametrize("shape", ["rectangle", "triangle", "pentagon"])
@pytest.mark.parametrize("seed", range(12))
def test_a_batch_goes_in_up_to_its_first_refused_point(shape: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    first, hull = _start(rng, shape)
    tri = Triangulation(first)
    there = first
    lo, hi = hull.min(axis=0) - 2, hull.max(axis=0) + 2
    grid = np.stack(np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1)), -1).reshape(-1, 2)
    inside = np.array([_inside(hull, q) for q in grid])
    for _ in range(4):
        # free positions inside the hull or on it, then maybe one refused point among them
        taken = {tuple(q) for q in there.tolist()}
        free = np.array([q for q in grid[inside].tolist() if tuple(q) not in taken])
        batch = free[rng.permutation(len(free))[:40]]
        at, kind = int(rng.integers(0, len(batch))), rng.integers(0, 4)
        if kind == 1:  # a vertex already there
            batch[at] = there[int(rng.integers(len(there)))]
        elif kind == 2 and at > 0:  # a point of the batch again
            batch[at] = batch[int(rng.integers(0, at))]
        elif kind == 3:  # just off the hull
            batch[at] = grid[~inside][int(rng.integers((~inside).sum()))]
        # the expected stop: the first point at a taken position or outside the hull
        seen = {tuple(q) for q in there.tolist()}
        stop, why = len(batch), None
        for j, q in enumerate(batch.tolist()):
            if tuple(q) in seen:
                stop, why = j, "share a position"
                break
            if not _inside(hull, np.array(q)):
                stop, why = j, "outside"
                break
            seen.add(tuple(q))
        if why is None:
            np.testing.assert_array_equal(tri.insert(batch), len(there) + np.arange(len(batch)))
        else:
            with pytest.raises(ATMError, match=why):
                tri.insert(batch)
        there = np.concatenate([there, batch[:stop]])
        np.testing.assert_array_equal(tri.triangles(), delaunay(there))


@pytest.mark.parametrize("seed", range(6))
def test_batches_give_the_one_triangulation(seed: int) -> None:
    """Triangulation.insert's batches, in whatever order it puts them in, give
    triangulate()'s triangles, constraints and all, on grids whose many cocircular
    quadruples make every tie of ATM.md §4.2.5 count."""
    from codec.triangulate import triangulate

    rng = np.random.default_rng(seed)
    side = 40
    corners = np.array([[0, 0], [side, 0], [0, side], [side, side]], np.int64)
    cells = rng.permutation((side + 1) ** 2)[: 300 + 100 * seed]
    points = np.stack([cells % (side + 1), cells // (side + 1)], axis=1).astype(np.int64)
    points = points[~((points[:, 0] % side == 0) & (points[:, 1] % side == 0))]
    # a wall across the grid, as refinement's walls come before its rounds
    wall = np.array([[3, 5], [20, 5], [35, 30]], np.int64)
    points = points[~(points[:, None] == wall[None]).all(-1).any(1)]
    start = np.concatenate([corners, wall])
    tri = Triangulation(start)
    segments = np.array([[4, 5], [5, 6]], np.int64)
    tri.constrain(segments)
    vertices = start
    for batch in np.array_split(points, 3 + seed):
        tri.insert(batch)
        vertices = np.concatenate([vertices, batch])
        np.testing.assert_array_equal(tri.triangles(), triangulate(vertices, segments))


def test_a_batch_that_flips_one_fan_again_and_again_stays_near_a_fresh_build() -> None:
    """Points on a row inserted into a triangulation whose fan spans that row: along the
    Hilbert curve alone each point flipped the fan again (n = 4,000: 0.33 s, against
    0.01 s for a fresh triangulation of every point); insert's randomised rounds keep it
    near linear."""
    import time

    n = 4000
    side = 4 * n
    corners = np.array([[0, 0], [side, 0], [0, side], [side, side]], np.int64)
    middle = np.stack([2 * np.arange(1, n + 1), np.full(n, side // 2)], axis=1).astype(np.int64)
    low = np.stack([2 * np.arange(1, n + 1) + 1, np.ones(n, np.int64)], axis=1).astype(np.int64)
    fresh, batch = [], []
    for _ in range(3):
        start = time.process_time()
        Triangulation(np.concatenate([corners, middle, low]))
        fresh.append(time.process_time() - start)
        tri = Triangulation(np.concatenate([corners, middle]))
        start = time.process_time()
        tri.insert(low)
        batch.append(time.process_time() - start)
    np.testing.assert_array_equal(tri.triangles(), delaunay(np.concatenate([corners, middle, low])))
    assert min(batch) < 5 * min(fresh) + 0.005, (min(batch), min(fresh))


@pytest.mark.parametrize("seed", range(4))
def test_a_start_vertex_per_point_is_a_hint_only(seed: int) -> None:
    """#20: insert's `near` (a vertex to start each point's location from, which
    refinement knows) changes no triangle, whatever it names: a good hint (a corner of
    the triangle the point falls in), a far one, a point of the same batch not yet in,
    none (-1), or numbers naming no vertex at all; walls stay walls."""
    from codec.triangulate import triangulate

    rng = np.random.default_rng(100 + seed)
    side = 60
    corners = np.array([[0, 0], [side, 0], [0, side], [side, side]], np.int64)
    wall = np.array([[5, 7], [30, 9], [50, 44]], np.int64)
    start = np.concatenate([corners, wall])
    segments = np.array([[4, 5], [5, 6]], np.int64)
    cells = rng.permutation((side + 1) ** 2)[:900]
    points = np.stack([cells % (side + 1), cells // (side + 1)], axis=1).astype(np.int64)
    points = points[~(points[:, None] == start[None]).all(-1).any(1)]
    tri = Triangulation(start)
    tri.constrain(segments)
    vertices = start
    for batch in np.array_split(points, 4):
        n = len(vertices)
        now = triangulate(vertices, segments)
        # the corner of the triangle holding each point (any holding it, on an edge)
        a, b, c = (vertices[now[:, k]] for k in range(3))

        def side_of(p, q, r):
            return (q[:, None, 0] - p[:, None, 0]) * (r[None, :, 1] - p[:, None, 1]) - \
                (q[:, None, 1] - p[:, None, 1]) * (r[None, :, 0] - p[:, None, 0])

        inside = (side_of(a, b, batch) >= 0) & (side_of(b, c, batch) >= 0) & (side_of(c, a, batch) >= 0)
        good = now[inside.argmax(axis=0), 0]
        kinds = rng.integers(0, 5, len(batch))
        near = np.where(kinds == 0, good, -1)
        near = np.where(kinds == 1, rng.integers(0, n, len(batch)), near)  # anywhere
        near = np.where(kinds == 2, n + rng.integers(0, len(batch), len(batch)), near)  # the batch's own
        near = np.where(kinds == 3, rng.choice([-7, 10**6, 2**40], len(batch)), near)  # no vertex
        tri.insert(batch, near)
        vertices = np.concatenate([vertices, batch])
        np.testing.assert_array_equal(tri.triangles(), triangulate(vertices, segments))
    with pytest.raises(ValueError, match="one vertex index per point"):
        tri.insert(np.array([[1, 2], [2, 2]]), np.array([0]))
