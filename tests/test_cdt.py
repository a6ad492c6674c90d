"""The compiled constrained Delaunay kernel (codec._cdt, codec/cdt.hpp): the same
triangles as Triangle followed by the canonical pass (ATM.md §4.2.5) on ties, walls,
large extents and every conformance file; bad input refused with ATMError."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import codec
from codec import container
from codec.coding import canonical_triangles
from codec.errors import ATMError
from codec.mesh import segments
from codec.triangulate import Triangulation, by_triangle as triangle_and_pass, delaunay, split_at_vertices
from tests.test_canonical import local_rule_holds, perturbed_delaunay

CONFORMANCE = Path(__file__).resolve().parent.parent / "format_spec" / "conformance"


def by_triangle(vertices: np.ndarray, segs: np.ndarray | None) -> np.ndarray:
    """The reference: Triangle (exact arithmetic) and the canonical flip pass."""
    return canonical_triangles(triangle_and_pass(vertices, segs, exact=True))


def ring_points(r2: int) -> np.ndarray:
    """The lattice points on the circle x^2 + y^2 = r2 (all cocircular)."""
    r = int(np.sqrt(r2))
    return np.array([(x, y) for x in range(-r, r + 1) for y in range(-r, r + 1) if x * x + y * y == r2])


def some_walls(draw, rng: np.random.Generator, pts: np.ndarray) -> np.ndarray | None:
    """None, or a few edges of a triangulation of a subset of pts (vertex index pairs):
    walls that never cross but may pass over other vertices."""
    if len(pts) < 6 or not draw(st.booleans()):
        return None
    sub = rng.permutation(len(pts))[: max(4, len(pts) // 3)]
    try:
        tris = by_triangle(pts[sub], None)
    except ATMError:
        return None
    return sub[tris[rng.permutation(len(tris))[: draw(st.integers(1, 8))], :2]] if len(tris) else None


@st.composite
def point_sets(draw) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertices with many exact ties (a lattice with holes, cocircular rings, or random
    points on a small grid), scaled and moved, in a random order; and some walls: edges
    of a triangulation of a subset of them, which never cross but may pass over other
    vertices (the kernel cuts them there, as Triangle does)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    kind = draw(st.sampled_from(["lattice", "rings", "grid"]))
    if kind == "lattice":
        w, h = draw(st.integers(2, 12)), draw(st.integers(2, 12))
        gx, gy = np.meshgrid(np.arange(w), np.arange(h))
        pts = np.stack([gx.ravel(), gy.ravel()], 1)
        pts = pts[rng.random(len(pts)) < draw(st.floats(0.3, 1.0))]
    elif kind == "rings":
        pts = np.concatenate([ring_points(r2) + rng.integers(0, 30, 2)
                              for r2 in rng.choice([25, 50, 65, 85, 325], draw(st.integers(1, 3)))])
        if draw(st.booleans()):
            pts = np.concatenate([pts, rng.integers(0, 60, (draw(st.integers(0, 20)), 2))])
    else:
        pts = rng.integers(0, draw(st.integers(2, 20)), (draw(st.integers(3, 120)), 2))
    pts = np.unique(pts, axis=0) * draw(st.sampled_from([1, 3, 4097, 1 << 20]))
    pts = pts + draw(st.sampled_from([0, 1 << 27]))
    pts = pts[rng.permutation(len(pts))]
    return pts, some_walls(draw, rng, pts)


@settings(max_examples=300, deadline=None)
@given(point_sets())
def test_the_kernel_gives_triangles_and_the_canonical_pass_the_same(case):
    """On ties, walls through tie regions and extents up to 2^28 (the 128-bit incircle),
    the kernel's triangles equal Triangle's after the canonical pass, in canonical
    order and positively oriented."""
    pts, walls = case
    out = delaunay(pts, walls)
    np.testing.assert_array_equal(out, by_triangle(pts, walls))
    np.testing.assert_array_equal(out, canonical_triangles(out))
    if len(out):
        a, b, c = (pts[out[:, i]] for i in range(3))
        assert ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) > 0).all()


@settings(max_examples=150, deadline=None)
@given(point_sets())
def test_raster_ordered_vertices_give_the_same_triangles(case):
    """Vertices already in raster order (a decoder's, ATM.md §4.2.2: the kernel neither
    sorts nor renumbers them) give the triangles of the same vertices shuffled, renumbered,
    and Triangle's after the canonical pass."""
    pts, walls = case
    rank = np.lexsort((pts[:, 0], pts[:, 1]))  # raster position -> shuffled index
    where = np.empty_like(rank)
    where[rank] = np.arange(len(rank))  # shuffled index -> raster position
    ordered = pts[rank]
    ordered_walls = None if walls is None else where[walls]
    out = delaunay(ordered, ordered_walls)
    np.testing.assert_array_equal(out, canonical_triangles(where[delaunay(pts, walls)]))
    np.testing.assert_array_equal(out, by_triangle(ordered, ordered_walls))


@pytest.mark.parametrize("r2", [25, 325, 1105])
def test_rings_match_the_definition(r2):
    """All lattice points of a circle tie at once: the kernel gives exactly the
    brute-force perturbed Delaunay triangulation of ATM.md §4.2.5's definition."""
    ring = ring_points(r2) + 40
    for v in (ring, np.concatenate([ring, [[40, 40]]])):
        out = delaunay(v)
        np.testing.assert_array_equal(out, perturbed_delaunay(v))
        assert local_rule_holds(v, out, None)


@pytest.mark.parametrize("scale", [1638, 1639, 3276, 3277, 26214, 1 << 16])
def test_ties_at_the_edge_of_the_narrow_incircle_in_a_wide_band(scale):
    """A wide band (extent over 2^14) takes the 64-bit incircle for each quadrilateral
    whose differences are all at most 2^14 and the 128-bit one otherwise: cocircular
    rings scaled so that their differences fall just below and just above 2^14, with a
    copy moved by one pixel (near ties) and random points among them (whose incircle
    overflows 64 bits when differences near 2^18 take the narrow path), and far
    vertices making the band wide, give the exact triangulation on both sides."""
    ring = ring_points(25) * scale  # differences up to 10 * scale
    ring = ring - ring.min(axis=0) + 3
    far = np.array([[0, 0], [1 << 20, 0], [0, 1 << 20], [1 << 20, 1 << 20]])
    scattered = np.random.default_rng(scale).integers(0, 10 * scale, (40, 2)) + 3
    v = np.unique(np.concatenate([ring, ring + [1, 0], scattered, far]), axis=0)
    out = delaunay(v)
    np.testing.assert_array_equal(out, by_triangle(v, None))
    np.testing.assert_array_equal(delaunay(ring), by_triangle(ring, None))


def test_every_conformance_band_is_the_kernels():
    """Each Delaunay band of every conformance file: the kernel equals Triangle and the
    canonical pass, and the file decodes to its stored image."""
    from codec.files import read_image

    bands = 0
    for path in sorted(CONFORMANCE.glob("*.atm")):
        for _, m in container.unpack(path.read_bytes())[1]:
            walls = segments(m.constraints) if m.constraints else None
            if len(m.triangles) == 0:
                continue
            np.testing.assert_array_equal(delaunay(m.vertices, walls), by_triangle(m.vertices, walls))
            bands += 1
        npy = path.with_suffix(".npy")
        expected = np.load(npy) if npy.exists() else read_image(path.with_suffix(".png"))
        np.testing.assert_array_equal(codec.decode(path.read_bytes()), expected)
    assert bands >= 12


def test_a_segment_through_vertices_is_cut_at_them():
    """A wall from corner to corner of a lattice passes over the diagonal's vertices:
    every piece becomes an edge, as with Triangle."""
    gx, gy = np.meshgrid(np.arange(6), np.arange(6))
    v = np.stack([gx.ravel(), gy.ravel()], 1)
    wall = np.array([[0, 35]])
    out = delaunay(v, wall)
    np.testing.assert_array_equal(out, by_triangle(v, wall))
    edges = {frozenset(e) for t in out.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    assert all(frozenset((7 * i, 7 * i + 7)) in edges for i in range(5))


def test_bad_input_is_refused():
    """Crossing segments, a vertex twice, an index beyond the vertices and extents
    beyond the exact predicates: ATMError naming the problem, before any work."""
    square = np.array([[0, 0], [4, 0], [0, 4], [4, 4], [2, 1]])
    with pytest.raises(ATMError, match="cross each other"):
        delaunay(square, np.array([[0, 3], [1, 2]]))
    with pytest.raises(ATMError, match="share a position"):
        delaunay(np.array([[0, 0], [4, 0], [0, 4], [4, 0]]))
    with pytest.raises(ATMError, match="beyond the 5 vertices"):
        delaunay(square, np.array([[0, 5]]))
    with pytest.raises(ATMError, match="beyond the 5 vertices"):
        delaunay(square, np.array([[-1, 2]]))
    with pytest.raises(ATMError, match="2\\^28"):
        delaunay(np.array([[0, 0], [1 << 28, 0], [0, 1]]))
    # on one line: no triangles (a one-pixel-high band), whatever the order
    assert delaunay(np.array([[3, 3], [1, 1], [2, 2]])).shape == (0, 3)
    assert delaunay(np.zeros((0, 2), np.int64)).shape == (0, 3)



def test_strict_refuses_a_segment_over_a_vertex():
    """strict (the decoder's, ATM.md §4.2.3 constraint 6): a segment over a vertex is
    refused, across triangles, along an existing edge's line and on a one-pixel line;
    without it the segment is cut there."""
    gx, gy = np.meshgrid(np.arange(5), np.arange(5))
    v = np.stack([gx.ravel(), gy.ravel()], 1)
    for wall in ([0, 24], [0, 2], [20, 4], [12, 14]):
        with pytest.raises(ATMError, match="passes over a vertex"):
            delaunay(v, np.array([wall]), strict=True)
        np.testing.assert_array_equal(delaunay(v, np.array([wall])), by_triangle(v, np.array([wall])))
    np.testing.assert_array_equal(delaunay(v, np.array([[0, 6], [6, 12]]), strict=True),
                                  by_triangle(v, np.array([[0, 6], [6, 12]])))
    line = np.stack([np.arange(6), np.zeros(6, np.int64)], 1)[::-1]
    assert delaunay(line, np.array([[0, 1], [4, 5]]), strict=True).shape == (0, 3)
    with pytest.raises(ATMError, match="passes over a vertex"):
        delaunay(line, np.array([[0, 2]]), strict=True)


@settings(max_examples=120, deadline=None)
@given(point_sets(), st.integers(1, 6), st.booleans())
def test_the_incremental_triangulation_equals_the_batch_one(case, batches, walls_first):
    """Triangulation: the image's corners, then the points inserted in a few batches
    and the walls constrained (before or after the last batch): the triangles equal
    delaunay() of all of them; and the changes reported after each step turn the
    previous triangle set into the new one."""
    from codec.triangulate import Triangulation

    pts, walls = case
    if len(pts) < 3:
        return
    pts = pts - pts.min(axis=0)
    w, h = pts.max(axis=0)
    if w == 0 or h == 0:
        return
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]])
    rest = pts[~((pts[:, 0] % w == 0) & (pts[:, 1] % h == 0))]
    vertices = np.concatenate([corners, rest])
    tri = Triangulation(corners, track_changes=True)
    state = {tuple(t) for t in canonical_triangles(tri.triangles()).tolist()}
    tri.changes()

    def step() -> None:
        removed, added = tri.changes()
        for side, rows in ((removed, -1), (added, 1)):
            for t in canonical_triangles(side).tolist():
                (state.discard if rows < 0 else state.add)(tuple(t))
        assert state == {tuple(t) for t in tri.triangles().tolist()}

    # walls name indices of pts; renumber to the order of insertion
    where = {tuple(p): i for i, p in enumerate(vertices.tolist())}
    wall_idx = None if walls is None else np.array([[where[tuple(pts[a])], where[tuple(pts[b])]] for a, b in walls])
    parts = np.array_split(np.arange(len(rest)), batches)
    for k, part in enumerate(parts):
        if k == len(parts) - 1 and walls_first and wall_idx is not None:
            inserted = set(range(4 + part[0] if len(part) else 4))
            if all(i in inserted for i in wall_idx.ravel().tolist()):
                tri.constrain(wall_idx)
                step()
        indices = tri.insert(rest[part])
        np.testing.assert_array_equal(indices, 4 + part)
        step()
    if wall_idx is not None:
        tri.constrain(wall_idx)
        step()
    np.testing.assert_array_equal(tri.triangles(), delaunay(vertices, wall_idx))


def test_the_incremental_triangulation_refuses_bad_points():
    """Outside the hull, a vertex again, negative coordinates, an unknown index,
    crossing walls: ATMError naming it; the points before a refused one stay."""
    from codec.triangulate import Triangulation

    tri = Triangulation(np.array([[0, 0], [8, 0], [0, 8], [8, 8]]))
    with pytest.raises(ATMError, match="outside"):
        tri.insert(np.array([[1, 1], [9, 3]]))
    np.testing.assert_array_equal(tri.triangles(), delaunay(np.array([[0, 0], [8, 0], [0, 8], [8, 8], [1, 1]])))
    with pytest.raises(ATMError, match="share a position"):
        tri.insert(np.array([[1, 1]]))
    with pytest.raises(ATMError, match="2\\^28"):
        tri.insert(np.array([[-1, 3]]))
    with pytest.raises(ATMError, match="beyond the 5 vertices"):
        tri.constrain(np.array([[0, 5]]))
    tri.insert(np.array([[7, 1], [4, 6]]))
    tri.constrain(np.array([[0, 3]]))
    with pytest.raises(ATMError, match="cross each other"):
        tri.constrain(np.array([[1, 2]]))
    with pytest.raises(ATMError, match="one line"):
        Triangulation(np.array([[0, 0], [1, 1], [2, 2]]))
    with pytest.raises(ValueError, match="track=True"):
        tri.changes()  # not kept unless asked for


@pytest.mark.parametrize("order", ["raster", "shuffled", "wide", "two"])
def test_the_first_vertices_twice_at_one_position_are_refused(order):
    """Triangulation's first vertices with one position twice are refused before any
    triangle is made, whether they come in raster order, shuffled (sorted by pixel
    number), shuffled over 2^27 (pixel numbers too wide for that: sorted by compares)
    or are only two; a refused start leaves nothing to insert into."""
    from codec import _cdt
    from codec.triangulate import Triangulation

    rng = np.random.default_rng(11)
    grid = np.stack(np.meshgrid(np.arange(0, 60, 3), np.arange(0, 40, 4)), -1).reshape(-1, 2)
    if order == "two":
        vertices = np.array([[5, 7], [5, 7]])
    else:
        if order == "wide":
            grid = grid * (1 << 21) + grid[::-1]
        vertices = np.concatenate([grid, grid[[17]]])  # the twin far from the first
        vertices = vertices[np.lexsort((vertices[:, 0], vertices[:, 1]))] if order == "raster" else rng.permutation(vertices)
    with pytest.raises(ATMError, match="share a position"):
        Triangulation(vertices)
    kernel = _cdt.Triangulation()
    assert kernel.start(np.ascontiguousarray(vertices, np.int64)) == _cdt.DUPLICATE
    assert kernel.insert(np.array([[1, 1]], np.int64))[0] == _cdt.OUTSIDE
    if order != "two":  # once each: the triangles of delaunay()
        once = rng.permutation(np.unique(vertices, axis=0))
        np.testing.assert_array_equal(Triangulation(once).triangles(), delaunay(once))


@pytest.mark.parametrize("bad, message", [("again", "share a position"), ("vertex", "share a position"),
                                          ("outside", "outside"), ("negative", "2\\^28")])
def test_a_batch_stops_at_its_first_refused_point(bad, message):
    """Triangulation.insert checks a whole batch first and puts it in in a spatial
    order: a refused point in the middle of a scattered batch (a position twice in the
    batch, a vertex already there, outside the hull, a negative coordinate) lets exactly
    the points before it in, numbered in the batch's order; the rest can follow."""
    from codec.triangulate import Triangulation

    corners = np.array([[0, 0], [99, 0], [0, 99], [99, 99]])
    pts = np.random.default_rng(7).permutation(np.stack(np.meshgrid(np.arange(3, 97, 7), np.arange(2, 98, 5)), -1).reshape(-1, 2))
    refused = {"again": pts[3], "vertex": corners[2], "outside": [120, 40], "negative": [-1, 5]}[bad]
    batch = np.concatenate([pts[:40], [refused], pts[40:]])
    tri = Triangulation(corners)
    with pytest.raises(ATMError, match=message):
        tri.insert(batch)
    np.testing.assert_array_equal(tri.triangles(), delaunay(np.concatenate([corners, pts[:40]])))
    np.testing.assert_array_equal(tri.insert(pts[40:]), 44 + np.arange(len(pts) - 40))
    np.testing.assert_array_equal(tri.triangles(), delaunay(np.concatenate([corners, pts])))


def test_a_point_inserted_on_a_wall_cuts_it_into_two_walls():
    """Incremental: a point on a constrained edge splits it into two constrained
    halves; points on both sides of the far half then cannot flip it away."""
    from codec.triangulate import Triangulation

    corners = np.array([[0, 0], [8, 0], [0, 8], [8, 8]])
    tri = Triangulation(corners)
    tri.constrain(np.array([[0, 3]]))
    tri.insert(np.array([[4, 4], [7, 5], [5, 7], [5, 3]]))
    every = np.concatenate([corners, [[4, 4], [7, 5], [5, 7], [5, 3]]])
    np.testing.assert_array_equal(tri.triangles(), delaunay(every, np.array([[0, 3]])))
    assert not np.array_equal(delaunay(every), delaunay(every, np.array([[0, 3]])))


def test_the_encoder_triangulates_with_the_kernel_alone(corpus, monkeypatch):
    """Every encoder triangulation (meshers, refinement to a bound, bands, holes, walls,
    the writer's check) is the compiled kernel's: Triangle is never run, and the files
    decode as the kernel rebuilds them."""
    import triangle

    def refused(*args, **kwargs):
        raise AssertionError("the encoder ran Triangle")

    monkeypatch.setattr(triangle, "triangulate", refused)
    image = corpus["camera"][:120, :160]
    depth = corpus["motorcycle_disp"][:120, :160].astype(np.float32)
    depth[40:60, 50:90] = np.nan
    for img, options in [(image, {"points": 400}), (image, {"points": 600, "band_height": 32}),
                         (image, {"quality": 60}), (image, {"max_error": 12, "mesher": "uniform"}),
                         (depth, {"max_error": 2.0})]:
        data = codec.encode(img, **options)
        codec.decode(data)


@st.composite
def band_point_sets(draw) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertices as a decoder has them (ATM.md §4.2.2): in raster order, with their
    bounding box's corners among them (a band's corners are vertices), which is what
    the kernel's sweep-line takes: ties (lattices, cocircular rings, few-valued grids),
    runs of collinear vertices on one row, all vertices on two rows, one vertex a row,
    vertices straight above the first row's ends, extents on both sides of the 64-bit
    incircle's 2^14 and up to 2^28; and walls, as in point_sets."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    kind = draw(st.sampled_from(["lattice", "rings", "grid", "rows", "two rows", "one a row", "sides"]))
    if kind in ("lattice", "rings", "grid"):
        pts = draw(point_sets())[0].reshape(-1, 2)
        pts = pts - pts.min(axis=0, initial=0)
    elif kind == "rows":  # long collinear runs, rows far apart or adjacent
        w = draw(st.integers(2, 60))
        rows = np.unique(rng.integers(0, draw(st.integers(1, 40)), draw(st.integers(1, 8))))
        pts = np.concatenate([np.stack([xs, np.full(len(xs), y)], 1) for y in rows
                              for xs in [np.unique(rng.integers(0, w, draw(st.integers(1, 20))))]])
    elif kind == "two rows":
        w, gap = draw(st.integers(1, 40)), draw(st.integers(1, 30))
        pts = np.concatenate([np.stack([xs, np.full(len(xs), y)], 1) for y in (0, gap)
                              for xs in [np.unique(rng.integers(0, w + 1, draw(st.integers(1, 30))))]])
    elif kind == "one a row":
        h = draw(st.integers(1, 60))
        pts = np.stack([rng.integers(0, draw(st.integers(1, 50)), h), np.arange(h)], 1)
    else:  # many vertices on the left and right columns, straight above the ends
        w, h = draw(st.integers(1, 30)), draw(st.integers(1, 30))
        side = rng.integers(0, h + 1, (draw(st.integers(0, 30)),))
        inner = rng.integers(0, [w + 1, h + 1], (draw(st.integers(0, 30)), 2))
        pts = np.concatenate([np.stack([np.where(rng.random(len(side)) < 0.5, 0, w), side], 1), inner])
    pts = np.asarray(pts, np.int64).reshape(-1, 2)
    if kind not in ("lattice", "rings", "grid"):
        pts = pts * draw(st.sampled_from([1, 2, 1639, 4097, 1 << 20]))
    if len(pts) == 0:
        pts = np.zeros((1, 2), np.int64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]])
    pts = np.unique(np.concatenate([pts, corners]), axis=0) + draw(st.sampled_from([0, 5, 1 << 27]))
    pts = pts[np.lexsort((pts[:, 0], pts[:, 1]))]
    return pts, some_walls(draw, rng, pts)


@settings(max_examples=400, deadline=None)
@given(band_point_sets())
def test_the_sweep_gives_the_triangles_of_insertion_and_of_triangle(case):
    """Raster-ordered vertices whose first row holds the smallest and largest x (the
    sweep-line's input): the same triangles as the same vertices shuffled (which the
    build sorts back into raster order and sweeps too: the input order changes
    nothing), and as Triangle after the canonical pass; every free edge locally
    Delaunay under the perturbed rule. (Insertion one by one is compared in
    test_a_band_of_thousands_of_vertices_is_swept_to_the_triangles_of_insertion.)"""
    pts, walls = case
    out = delaunay(pts, walls)
    np.testing.assert_array_equal(out, by_triangle(pts, walls))
    shuffle = np.random.default_rng(len(pts)).permutation(len(pts))
    where = np.empty_like(shuffle)
    where[shuffle] = np.arange(len(pts))  # raster index -> shuffled index
    if len(out):
        # Triangulation numbers the vertices in its input's order (its triangles
        # name shuffled indices); it takes coordinates from 0, and a shift changes no
        # predicate
        insertion = Triangulation(pts[shuffle] - pts.min(axis=0))
        if walls is not None:
            insertion.constrain(where[walls])
        np.testing.assert_array_equal(out, canonical_triangles(shuffle[insertion.triangles()]))
    if len(out):  # the walls as the kernel keeps them: cut at the vertices on them
        cut = None if walls is None else split_at_vertices(pts, walls, int(pts[:, 0].max()) + 1)
        assert local_rule_holds(pts, out, cut)


def test_a_lawson_pass_that_does_not_end_is_reported():
    """A flip loop that would not end (as under a broken predicate) is stopped by its
    bound and reported as an internal error, in the sweep-line (start) and in an
    insertion; the points of a batch that went in before it are the ones reported,
    and the triangulation refuses further work."""
    from codec import _cdt

    gx, gy = np.meshgrid(np.arange(0, 40, 3), np.arange(0, 40, 4))
    grid = np.stack([gx.ravel(), gy.ravel()], 1)
    rng = np.random.default_rng(3)
    scattered = np.unique(rng.integers(0, 40, (60, 2)), axis=0)
    band = np.unique(np.concatenate([scattered, [[0, 0], [39, 0], [0, 39], [39, 39]]]), axis=0)
    band = band[np.lexsort((band[:, 0], band[:, 1]))]
    tri = _cdt.Triangulation()
    tri._limit_flips(0)
    assert tri.start(np.ascontiguousarray(band)) == _cdt.INTERNAL
    tri = _cdt.Triangulation()
    assert tri.start(np.array([[0, 0], [40, 0], [0, 40], [40, 40]])) == _cdt.OK
    tri._limit_flips(2)
    points = np.ascontiguousarray(rng.permutation(grid[(grid % 40 != 0).all(axis=1)]))
    status, went_in = tri.insert(points)
    assert status == _cdt.INTERNAL
    corners_of = set(tri.triangles().ravel().tolist())
    assert 0 < len(went_in) < len(points)
    assert set(went_in.tolist()) == corners_of - {0, 1, 2, 3}
    assert tri.insert(np.array([[1, 1]]))[0] == _cdt.INTERNAL
    assert tri.constrain(np.array([[0, 3]])) == _cdt.INTERNAL


def test_a_long_first_row_costs_linear_flips():
    """The sweep-line fans a band's first row from the next vertex: a long row with that
    vertex at one end needs a quadratic number of flips (a 201-byte file of two rows,
    37,420 and 22,580 vertices, took minutes to decode; the fuzzer found it). The
    sweep has a flip budget and the triangulation is then made by insertion: the same
    triangles, in linear time."""
    from codec import _cdt

    for k in (300, 20000):
        x = np.arange(k)
        pts = np.concatenate([np.stack([x, 0 * x], 1), np.stack([x[: k * 3 // 5], 0 * x[: k * 3 // 5] + 1], 1)])
        pts = np.ascontiguousarray(pts, dtype=np.int64)
        status, tris, flips, _ = _cdt.triangulate(pts, np.zeros((0, 2), np.int64), True)
        assert status == _cdt.OK
        assert flips < 60 * len(pts)  # the sweep alone made len(pts)**2 / 4
        if k == 300:
            np.testing.assert_array_equal(tris, canonical_triangles(triangle_and_pass(pts)))


@pytest.mark.parametrize("seed", range(6))
def test_a_band_in_any_order_is_swept_to_the_same_triangles(seed):
    """Triangulation's first vertices in any order (the encoder's): a band's (its first
    row spans it) are swept in raster order and numbered back; the triangles, vertex
    numbers and later insertions, walls and changes are those of delaunay() and of
    Triangle with the canonical pass, ties included (points on a lattice). A long first
    row fanned from one end, shuffled, still goes over to insertion."""
    from codec.triangulate import Triangulation

    rng = np.random.default_rng(seed)
    w, h = int(rng.integers(20, 120)), int(rng.integers(6, 50))
    step = int(rng.choice([1, 2, 5]))
    pts = np.unique(rng.integers(0, [w // step, h // step], (w * h // 12, 2)) * step, axis=0)
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]])
    pts = pts[~((pts[:, 0] % w == 0) & (pts[:, 1] % h == 0))]
    first = np.concatenate([corners, pts[: len(pts) // 2]])
    first = first[rng.permutation(len(first))]
    later = pts[len(pts) // 2:]
    tri = Triangulation(first, track_changes=True)
    np.testing.assert_array_equal(tri.triangles(), delaunay(first))
    np.testing.assert_array_equal(canonical_triangles(tri.triangles()), canonical_triangles(triangle_and_pass(first)))
    before = {tuple(t) for t in tri.triangles().tolist()}
    assert tri.changes()[0].shape == (0, 3)
    tri.insert(later)
    everything = np.concatenate([first, later])
    removed, added = tri.changes()
    before -= {tuple(t) for t in canonical_triangles(removed).tolist()}
    before |= {tuple(t) for t in canonical_triangles(added).tolist()}
    assert before == {tuple(t) for t in tri.triangles().tolist()}
    walls = many_walls(rng, everything, 0.3)
    if walls is not None:
        tri.constrain(walls)
    np.testing.assert_array_equal(tri.triangles(), delaunay(everything, walls))

    x = np.arange(3000)
    row = np.concatenate([np.stack([x, 0 * x], 1), np.stack([x[:1800], 0 * x[:1800] + 1], 1)])
    row = row[rng.permutation(len(row))]
    np.testing.assert_array_equal(Triangulation(row).triangles(), delaunay(row))


def many_walls(rng: np.random.Generator, pts: np.ndarray, share: float) -> np.ndarray | None:
    """Many walls that never cross: a random share of the edges of a triangulation of a
    random half of pts; long ones cross many edges of pts' triangulation."""
    sub = rng.permutation(len(pts))[: max(3, len(pts) // 2)]
    tris = by_triangle(pts[sub], None)
    if not len(tris):
        return None
    edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1), axis=0)
    keep = edges[rng.random(len(edges)) < share]
    return sub[keep] if len(keep) else None


@settings(max_examples=200, deadline=None)
@given(band_point_sets(), st.floats(0.05, 1.0), st.integers(0, 2**32 - 1))
def test_many_walls_forced_in_give_the_triangles_of_triangle(case, share, seed):
    """Walls go in by taking out the triangles they cross and triangulating the polygon
    on each side (or by flips, where a polygon meets itself): with ties, many walls
    crossing many edges, walls over vertices (cut there), the same triangles as
    Triangle after the canonical pass, batch and incremental."""
    pts, _ = case
    rng = np.random.default_rng(seed)
    if len(pts) < 4:
        return
    walls = many_walls(rng, pts, share)
    out = delaunay(pts, walls)
    np.testing.assert_array_equal(out, by_triangle(pts, walls))
    if len(out) and walls is not None:
        tri = Triangulation(pts - pts.min(axis=0))
        tri.constrain(walls[rng.permutation(len(walls))])
        np.testing.assert_array_equal(out, tri.triangles())


def test_a_wall_whose_right_side_meets_itself_is_flipped_in():
    """A wall that crosses every triangle of a vertex but one edge of it (the vertex
    hangs in the polygon beside the wall by that edge: the polygon meets itself) goes
    in by flips; the triangles are Triangle's. Found by search: the kernel reports
    flips only for such walls after a sweep without flips."""
    from codec import _cdt

    rng = np.random.default_rng(5)
    found = 0
    for _ in range(4000):
        pts = np.unique(rng.integers(0, 12, (14, 2)), axis=0)
        pts = np.unique(np.concatenate([pts, [[0, 0], [11, 0], [0, 11], [11, 11]]]), axis=0)
        pts = np.ascontiguousarray(pts[np.lexsort((pts[:, 0], pts[:, 1]))])
        status, _, swept, _ = _cdt.triangulate(pts, np.zeros((0, 2), np.int64), True)
        wall = np.ascontiguousarray(rng.choice(len(pts), (1, 2), replace=False))
        status, tris, flips, _ = _cdt.triangulate(pts, wall, False)
        if status != _cdt.OK or flips == swept:
            continue
        found += 1
        np.testing.assert_array_equal(tris, by_triangle(pts, wall))
    assert found >= 5


def _wall_past_two_columns(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices at (0, 2i + 1) and (2, 2i + 2), i < k, the corners of a 3 x (2k + 3) band
    and (1, 0), (1, H - 1), in raster order; the wall between the last two."""
    h = 2 * k + 3
    pts = {(0, 2 * i + 1) for i in range(k)} | {(2, 2 * i + 2) for i in range(k)}
    pts |= {(1, 0), (1, h - 1), (0, 0), (2, 0), (0, h - 1), (2, h - 1)}
    v = np.array(sorted(pts, key=lambda p: (p[1], p[0])), np.int64)
    index = {p: j for j, p in enumerate(map(tuple, v.tolist()))}
    return v, np.array([[index[(1, 0)], index[(1, h - 1)]]], np.int64)


def test_a_wall_through_a_long_fan_costs_linear_time():
    """A wall crossing a long fan leaves polygons of k vertices on its sides; cavity()
    tests every remaining vertex for each triangle it makes (k^2 / 2 tests: a 137-byte
    file of two columns of 32,000 vertices decoded for 4.4 s, a reviewer found it), so
    a long polygon goes in by flips: the same triangles, in about linear time."""
    import time

    from codec import _cdt

    v, wall = _wall_past_two_columns(150)  # polygons over the cavity bound: the flip path
    status, tris, _, _ = _cdt.triangulate(v, wall, True)
    assert status == _cdt.OK
    np.testing.assert_array_equal(tris, canonical_triangles(triangle_and_pass(v, wall)))
    v, wall = _wall_past_two_columns(32000)
    start = time.process_time()
    status, tris, _, _ = _cdt.triangulate(v, wall, True)
    assert status == _cdt.OK
    assert time.process_time() - start < 1.0  # 4.3 s of CPU by cavity()


@pytest.mark.parametrize("count", [0, 1, 2, 3, 4, 5, 6, 10, 11, 21, 22, 40, 300, 5000])
def test_the_kernel_gives_the_crc_of_the_triangles_it_writes(count):
    """The kernel's CRC of its canonical triangles (ATM.md's triangle_crc, which the
    decoder checks without a u32 copy) equals zlib's over their u32 little-endian
    list, whatever their number against the 16 values the fast path takes a step
    (a vertex count gives about twice as many triangles)."""
    from codec.coding import triangle_crc
    from codec.triangulate import delaunay_and_crc

    rng = np.random.default_rng(count)
    pts = np.unique(rng.integers(0, 70000, (count + 2, 2)), axis=0) if count else np.zeros((0, 2), np.int64)
    triangles, crc = delaunay_and_crc(pts)
    assert np.array_equal(triangles, delaunay(pts))
    assert crc == triangle_crc(triangles)
    # fans of 2 to 22 triangles: one fast step and the rest, or none
    for k in range(3, 24):
        fan = np.array([[0, 0]] + [[40 * j, 1600 - j * j] for j in range(k)])
        t, c = delaunay_and_crc(fan)
        assert c == triangle_crc(t)


def test_a_reused_triangulator_gives_what_fresh_calls_give():
    """codec.triangulate.Delaunay keeps its kernel's buffers from call to call (a
    decoder's, band after band): a run of inputs of growing and shrinking size, with
    refusals (crossing walls, a wall over a vertex, a vertex twice) between them, gives
    each the triangles, CRC and refusal of a fresh call."""
    from codec.triangulate import Delaunay, delaunay_and_crc

    rng = np.random.default_rng(20)
    owner = Delaunay()
    refused = 0
    for trial in range(60):
        n = int(rng.choice([3, 40, 900, 5000]))
        pts = np.unique(rng.integers(0, int(rng.choice([8, 300, 1 << 16])), (n, 2)), axis=0)
        if trial % 2:
            pts = pts[np.lexsort((pts[:, 0], pts[:, 1]))]  # raster order: the sweep
        walls = rng.integers(0, len(pts), (int(rng.integers(0, 4)), 2)) if trial % 3 else None
        if trial % 7 == 0:
            pts = np.concatenate([pts, pts[:1]])  # a vertex twice
        strict = bool(trial % 5 == 0)
        try:
            expected = delaunay_and_crc(pts, walls, strict=strict)
        except ATMError as exc:
            refused += 1
            with pytest.raises(ATMError, match=re.escape(str(exc))):
                owner.triangles_and_crc(pts, walls, strict=strict)
            continue
        triangles, crc = owner.triangles_and_crc(pts, walls, strict=strict)
        np.testing.assert_array_equal(triangles, expected[0])
        assert crc == expected[1]
    assert 5 < refused < 50


def test_a_triangulation_is_used_by_one_thread_at_a_time():
    """The encoder's Triangulation works in buffers of its own with the GIL released
    (canonical()'s counts among them): a second thread's call while one runs raises
    RuntimeError instead of sharing them (two threads listing the triangles of one
    object overran the output and crashed the process), and the answers stay right."""
    import threading

    from codec.native import _cdt

    rng = np.random.default_rng(3)
    pts = np.unique(rng.integers(0, 3000, (200_000, 2)), axis=0).astype(np.int64)
    t = _cdt.Triangulation()
    assert t.start(pts) == _cdt.OK
    expected = t.triangles()
    results, refused = [], []

    def lister():
        for _ in range(15):
            try:
                results.append(t.triangles())
            except RuntimeError as exc:
                assert "in use by another thread" in str(exc)
                refused.append(1)

    threads = [threading.Thread(target=lister) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(results) + len(refused) == 30 and results
    assert all(np.array_equal(r, expected) for r in results)
    # after the race the object is free again
    assert np.array_equal(t.triangles(), expected)


def test_the_incremental_triangulation_lists_its_slots_and_the_slots_each_insert_rewrites():
    """#20: refinement keeps its triangles' numbers by the kernel's slot: slots() gives
    each slot's triangle in canonical rotation, dirty() the slots rewritten since the
    last call (into a table kept by slot, with into=), and size() the slot count; a
    table kept by dirty(into=) alone stays slots(), and in canonical order it is
    triangles(), the rows saying which slot each came from."""
    from codec.native import _renumber
    from codec.triangulate import Triangulation

    rng = np.random.default_rng(20)
    for case in range(6):
        w, h = (int(v) for v in rng.integers(20, 120, 2))
        pts = np.unique(np.stack([rng.integers(1, w, 400), rng.integers(1, h, 400)], 1), axis=0)
        pts = pts[rng.permutation(len(pts))]
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]])
        tri = Triangulation(np.concatenate([corners, pts[:40]]), track_changes=True)
        with pytest.raises(ValueError, match="a row per slot"):
            tri.dirty(into=np.zeros((tri.size() - 1, 3), np.int64))
        table = np.zeros((4 * len(pts), 3), np.int64)
        table[: tri.size()] = tri.slots()
        tri.dirty()
        n = 44
        for part in np.array_split(pts[40:], 4):
            tri.insert(part)
            n += len(part)
            if case % 2:
                slots = tri.dirty(into=table)
            else:
                slots, rows = tri.dirty()
                table[slots] = rows
            assert len(np.unique(slots)) == len(slots) and slots.max() < tri.size()
            m = tri.size()
            np.testing.assert_array_equal(table[:m], tri.slots())
            # canonical rotation: each starts at its smallest corner
            assert (table[:m, 0] < table[:m, 1:].min(axis=1)).all()
            canon, source = _renumber.canonical_renumbered(table[:m], np.arange(n), rows=True)
            np.testing.assert_array_equal(canon, tri.triangles())
            np.testing.assert_array_equal(canon, table[source])
            assert tri.dirty()[0].shape == (0,)
    with pytest.raises(ValueError, match="track"):
        Triangulation(corners).dirty()


def test_inserting_free_points_leaves_out_those_on_taken_positions_as_merge_does():
    """#20: Triangulation.insert_free leaves out a point at a position taken (by a
    vertex, or a point of the batch before it) where insert() refuses it: the points
    that go in are merge()'s, in its order, with their near hints (some naming points
    left out or not yet in), and the triangles are delaunay()'s of them all. On the
    old kernel a taken position stopped the batch there."""
    from codec.mesher.refine import merge
    from codec.triangulate import Triangulation

    rng = np.random.default_rng(31)
    for case in range(8):
        w, h = (int(v) for v in rng.integers(10, 60, 2))
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]])
        first = np.concatenate([corners, np.stack([rng.integers(0, w + 1, 30), rng.integers(0, h + 1, 30)], 1)])
        first = first[np.unique(first[:, 1] * (w + 1) + first[:, 0], return_index=True)[1]]
        tri = Triangulation(first, track_changes=bool(case % 2))
        vertices = first
        for _ in range(3):
            points = np.stack([rng.integers(0, w + 1, 40), rng.integers(0, h + 1, 40)], 1)
            # some on vertices, some twice in the batch
            points = np.concatenate([points, vertices[rng.integers(0, len(vertices), 5)], points[:5]])
            points = points[rng.permutation(len(points))]
            near = rng.integers(-3, len(vertices) + 55, len(points))
            free = tri.insert_free(points, near)
            merged = merge(w + 1, vertices, points)
            np.testing.assert_array_equal(np.concatenate([vertices, points[free]]), merged)
            assert (~free).any()
            vertices = merged
            np.testing.assert_array_equal(tri.triangles(), delaunay(vertices))
        with pytest.raises(ATMError, match="outside"):
            tri.insert_free(np.array([[w + 1, 0]]))
        with pytest.raises(ValueError, match="one entry per point"):
            tri._kernel.insert(np.zeros((2, 2), np.int64), None, np.zeros(1, np.uint8))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["uniform", "clusters", "lattice"]),
       st.sampled_from([(512, 48), (2000, 24), (90, 600)]), st.sampled_from([0.004, 0.03, 0.2]))
def test_a_band_of_thousands_of_vertices_is_swept_to_the_triangles_of_insertion(seed, kind, shape, share):
    """Bands the size of a decoder's (thousands of vertices, evenly spread, in clusters
    as an adaptive mesh puts them, or on a lattice, with ties): the sweep-line's
    triangles (delaunay, vertices in raster order: a long front, fills on both sides of
    many vertices, its walks started from buckets of x those fills re-point) are those
    of the same vertices inserted one by one into the band's corners (point location
    and Lawson flips, no front); some checked against Triangle too."""
    rng = np.random.default_rng(seed)
    w, h = shape
    count = max(4, int(share * w * h))
    if kind == "uniform":
        pts = rng.integers(0, [w, h], (count, 2))
    elif kind == "clusters":
        centres = rng.integers(0, [w, h], (int(rng.integers(1, 12)), 2))
        pts = centres[rng.integers(0, len(centres), count)] + rng.normal(0, rng.uniform(1, 30), (count, 2))
        pts = np.clip(np.rint(pts), 0, [w - 1, h - 1]).astype(np.int64)
    else:
        step = int(rng.integers(2, 6))
        pts = rng.integers(0, [w // step, h // step], (count, 2)) * step
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    pts = np.unique(np.concatenate([pts, corners]), axis=0)
    pts = pts[np.lexsort((pts[:, 0], pts[:, 1]))]
    swept = delaunay(pts)
    inner = ~((pts[:, 0] % (w - 1) == 0) & (pts[:, 1] % (h - 1) == 0))
    inserted = Triangulation(corners)
    inserted.insert(pts[inner])
    number = np.concatenate([np.flatnonzero(~inner)[[0, 1, 2, 3]], np.flatnonzero(inner)])
    # corners went in as given: (0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1), which is
    # their raster order too
    np.testing.assert_array_equal(swept, canonical_triangles(number[inserted.triangles()]))
    if len(pts) <= 3000:
        np.testing.assert_array_equal(swept, by_triangle(pts, None))
