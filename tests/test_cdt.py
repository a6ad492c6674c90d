"""The compiled constrained Delaunay kernel (codec._cdt, codec/cdt.hpp): the same
triangles as Triangle followed by the canonical pass (ATM.md §4.2.5) on ties, walls,
large extents and every conformance file; bad input refused with ATMError."""

from __future__ import annotations

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
from codec.triangulate import delaunay, triangulate
from tests.test_canonical import local_rule_holds, perturbed_delaunay

CONFORMANCE = Path(__file__).resolve().parent.parent / "format_spec" / "conformance"


def by_triangle(vertices: np.ndarray, segs: np.ndarray | None) -> np.ndarray:
    """The reference: Triangle (exact arithmetic) and the canonical flip pass."""
    return canonical_triangles(triangulate(vertices, segs, exact=True))


def ring_points(r2: int) -> np.ndarray:
    """The lattice points on the circle x^2 + y^2 = r2 (all cocircular)."""
    r = int(np.sqrt(r2))
    return np.array([(x, y) for x in range(-r, r + 1) for y in range(-r, r + 1) if x * x + y * y == r2])


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
    walls = None
    if len(pts) >= 6 and draw(st.booleans()):
        sub = rng.permutation(len(pts))[: max(4, len(pts) // 3)]
        try:
            tris = by_triangle(pts[sub], None)
        except ATMError:
            tris = np.zeros((0, 3), np.int64)
        if len(tris):
            walls = sub[tris[rng.permutation(len(tris))[: draw(st.integers(1, 8))], :2]]
    return pts, walls


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


@pytest.mark.parametrize("r2", [25, 325, 1105])
def test_rings_match_the_definition(r2):
    """All lattice points of a circle tie at once: the kernel gives exactly the
    brute-force perturbed Delaunay triangulation of ATM.md §4.2.5's definition."""
    ring = ring_points(r2) + 40
    for v in (ring, np.concatenate([ring, [[40, 40]]])):
        out = delaunay(v)
        np.testing.assert_array_equal(out, perturbed_delaunay(v))
        assert local_rule_holds(v, out, None)


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

