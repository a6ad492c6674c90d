"""The compiled walk over each triangle's pixels (codec._elements) gives exactly the
numbers of the span arrays it replaced (codec.mesher.elements.Raster, Statistics), on
meshes with flat tops and bottoms, slivers and ties, for every prefix-sum type."""

from __future__ import annotations

import numpy as np
import pytest

from codec import native
from codec.mesher.elements import Statistics, element_sse, triangle_pixels, triangle_raster, worst_pixels
from codec.triangulate import triangulate


def _mesh(rng: np.random.Generator, width: int, height: int, count: int, grid: bool):
    """Vertices (the corners, then random or lattice pixels) and their triangulation."""
    corners = [[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]]
    if grid:
        # a lattice: many flat-topped and flat-bottomed triangles, cocircular ties
        xs, ys = np.meshgrid(np.arange(0, width, 3), np.arange(0, height, 4))
        pts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    else:
        pts = np.stack([rng.integers(0, width, count), rng.integers(0, height, count)], axis=1)
    v = np.concatenate([corners, pts]).astype(np.int64)
    _, first = np.unique(v[:, 1] * width + v[:, 0], return_index=True)
    v = v[np.sort(first)]
    return v, triangulate(v, np.zeros((0, 2), np.int64))


def _images(rng: np.random.Generator, width: int, height: int):
    """(structure plane, fit) pairs whose prefix sums are int32, int64 and float64."""
    u8 = rng.integers(0, 256, (height, width)).astype(np.uint8)
    u16 = rng.integers(0, 65536, (height, width)).astype(np.uint16)
    rgb = rng.integers(0, 256, (height, width, 3)).astype(np.uint8)
    gray = (rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32))
    return [(u8, "structure"), (u16, "structure"), (u8, None), (gray, rgb), (gray, None)]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("grid", [False, True])
def test_triangle_statistics_are_those_of_the_spans(seed: int, grid: bool) -> None:
    rng = np.random.default_rng(seed)
    width, height = int(rng.integers(3, 90)), int(rng.integers(3, 70))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 200)), grid)
    kinds = set()
    for structure, fit in _images(rng, width, height):
        layout = Statistics(structure, fit)
        kinds.add(layout.planes.table.dtype)
        raster = triangle_raster(v, t, width, height)
        expected = layout(raster)
        got, none = layout.of_triangles(v, t)
        assert got.shape == expected.shape and none is None
        # the same float64 numbers, not just close ones: the encoder's bytes depend on them
        assert np.array_equal(got, expected)
        # any subset, in any order
        pick = rng.permutation(len(t))[: len(t) // 2]
        sub = triangle_raster(v, t[pick], width, height)
        assert np.array_equal(layout.of_triangles(v, t[pick])[0], layout(sub))
        # and the squared errors element_sse gives, bit for bit, against vertex values
        # of the image and off it
        plane = structure.astype(np.float64)
        for z in (plane[v[:, 1], v[:, 0]], rng.normal(100, 80, len(v))):
            stats, sse = layout.of_triangles(v, t[pick], z)
            assert np.array_equal(stats, layout(sub))
            assert np.array_equal(sse, element_sse(sub, layout(sub), z))
    assert kinds == {np.dtype(np.int32), np.dtype(np.int64), np.dtype(np.float64)}


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("grid", [False, True])
def test_worst_pixels_are_those_of_the_spans(seed: int, grid: bool) -> None:
    rng = np.random.default_rng(10 + seed)
    width, height = int(rng.integers(3, 90)), int(rng.integers(3, 70))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 200)), grid)
    # plateaus: many pixels of a triangle tie for its largest error
    plane = (rng.integers(0, 4, (height, width)) * 20).astype(np.float32)
    for z in (plane[v[:, 1], v[:, 0]].astype(np.float64), rng.normal(30, 20, len(v))):
        raster = triangle_raster(v, t, width, height)
        e, x, y, err = raster.worst_pixels(plane, z, np.arange(len(t)))
        got = worst_pixels(plane, v, t, z, width, height)
        for a, b in zip(got, (e, x, y, err)):
            assert np.array_equal(a, b)
        # a float64 plane gives the same
        got = worst_pixels(plane.astype(np.float64), v, t, z, width, height)
        assert np.array_equal(got[3], err)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("grid", [False, True])
def test_pixels_and_plane_values_are_those_of_the_spans(seed: int, grid: bool) -> None:
    rng = np.random.default_rng(20 + seed)
    width, height = int(rng.integers(3, 90)), int(rng.integers(3, 70))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 200)), grid)
    raster = triangle_raster(v, t, width, height)
    e, x, y = raster.pixels()
    got = triangle_pixels(v, t, width, height)
    for a, b in zip(got, (e, x, y)):
        assert np.array_equal(a, b)
    # every pixel of [0, W-1) x [0, H-1) exactly once
    assert np.array_equal(np.sort(y * width + x), np.sort((np.arange(height - 1)[:, None] * width + np.arange(width - 1)).ravel()))
    affine = raster.affine(rng.normal(100, 50, len(v)))
    f = affine[e]
    want = f[:, 0] * (x - raster.origin[e, 0]) + f[:, 1] * (y - raster.origin[e, 1]) + f[:, 2]
    assert np.array_equal(raster.evaluate(affine, e, x, y), want)


@pytest.mark.parametrize("kind", [np.int32, np.int64, np.float64])
@pytest.mark.parametrize("channels", [0, 1, 3])
def test_prefix_sums_are_numpys(kind, channels: int) -> None:
    rng = np.random.default_rng(channels)
    h, w = 7, 33
    b = rng.integers(0, 256, (h, w)).astype(kind)
    if kind is np.float64:
        b = b + rng.random((h, w)).astype(np.float32)  # a luma plane: float32 values
    cs = [rng.integers(0, 65536, (h, w)).astype(kind) for _ in range(channels)]
    xs = np.arange(w, dtype=kind)
    planes = [b, b * xs, b * b] + [p for c in cs for p in (c, c * xs)]
    want = np.zeros((h, w + 1, len(planes)), kind)
    for k, plane in enumerate(planes):
        np.cumsum(plane, axis=1, out=want[:, 1:, k])
    got = native._elements.prefix_table(b, np.stack(cs) if cs else np.zeros((0, h, w), kind))
    assert got.dtype == kind and np.array_equal(got, want.reshape(-1, len(planes)))


def test_span_totals_are_a_sparse_row_sums() -> None:
    import scipy.sparse as sp

    rng = np.random.default_rng(7)
    counts = rng.integers(0, 6, 300)  # elements with no span too
    bounds = np.r_[0, np.cumsum(counts)]
    per_span = rng.normal(0, 1e6, (10, int(bounds[-1]))) * rng.random((10, int(bounds[-1]))) ** 9
    n = per_span.shape[1]
    summing = sp.csr_matrix((np.ones(n), np.arange(n), bounds), shape=(len(counts), n))
    assert np.array_equal(native._elements.span_totals(per_span, bounds), np.asarray(summing @ per_span.T))
    with pytest.raises(ValueError, match="run from 0"):
        native._elements.span_totals(per_span, bounds[:-1])
    with pytest.raises(ValueError, match="not decrease"):
        native._elements.span_totals(per_span, np.r_[0, bounds[2], bounds[1], bounds[3:]])


def test_the_kernels_refuse_what_is_out_of_range() -> None:
    rng = np.random.default_rng(3)
    v, t = _mesh(rng, 20, 10, 30, False)
    layout = Statistics(rng.integers(0, 256, (10, 20)).astype(np.uint8), "structure")
    args = (layout.planes.table, layout._powers[1], layout._powers[2], layout._from_kernel, layout._blocks)
    bad = t.copy()
    bad[-1, 2] = len(v)
    z = np.zeros(len(v))
    with pytest.raises(ValueError, match="out of range"):
        native._elements.triangle_statistics(v, bad, 20, 10, *args, z)
    far = v.copy()
    far[-1] = [20, 0]  # one column past the image
    with pytest.raises(ValueError, match="out of range"):
        native._elements.triangle_statistics(far, t, 20, 10, *args, z)
    with pytest.raises(ValueError, match="do not match"):
        native._elements.triangle_statistics(v, t, 20, 11, *args, z)
    with pytest.raises(ValueError, match="a value per vertex"):
        native._elements.triangle_statistics(v, t, 20, 10, *args, z[:-1])
    for columns, blocks in ((np.r_[layout._from_kernel[:-1], 99], layout._blocks), (layout._from_kernel, np.array([8]))):
        with pytest.raises(ValueError, match="column out of range"):
            native._elements.triangle_statistics(v, t, 20, 10, *args[:3], columns, blocks, z)
    # the walk sums into a fixed array of 6 + 2 * 32 numbers: a wider table is refused,
    # not written past that array's end
    wide = np.zeros((10 * 21, 33), np.int64)
    with pytest.raises(ValueError, match="more planes"):
        native._elements.triangle_statistics(v, t, 20, 10, wide, *args[1:], z)
    plane = np.zeros((10, 20), np.float32)
    f, origin = np.zeros((len(t), 3)), np.zeros((len(t), 2), np.int64)
    with pytest.raises(ValueError, match="out of range"):
        native._elements.worst_pixels(v, bad, 20, 10, z, plane)
    with pytest.raises(ValueError, match="does not match"):
        native._elements.worst_pixels(v, t, 20, 10, z, plane[:9])
    with pytest.raises(ValueError, match="a value per vertex"):
        native._elements.worst_pixels(v, t, 20, 10, z[:-1], plane)
    with pytest.raises(ValueError, match="out of range"):
        native._elements.triangle_pixels(far, t, 20, 10)
    one = np.zeros(1, np.int64)
    with pytest.raises(ValueError, match="out of range"):
        native._elements.evaluate(f, origin, np.array([len(t)]), one, one)


def test_the_cache_finds_the_triangles_it_has_measured() -> None:
    """#20: refinement's cache of triangle statistics is a hash table in the kernel
    (codec._elements.cached) instead of a sort and binary searches of keys: a triangle
    is found whichever corner it is listed from and however its vertices are numbered."""
    rng = np.random.default_rng(8)
    width, height = 60, 50
    v, t = _mesh(rng, width, height, 150, False)
    pixel = v[:, 1] * width + v[:, 0]
    sse = rng.random(len(t))
    keys, rows, _, fresh = native._elements.cached(pixel, t, width * height, np.zeros(0, np.int64),
                                                   np.zeros(0, np.int64), np.zeros(0), 0)
    assert np.array_equal(fresh, np.arange(len(t))) and np.array_equal(rows, np.arange(len(t)))
    assert len(np.unique(keys)) == len(t)
    # the vertices renumbered, the triangles listed from another corner, reordered,
    # and some of them new
    perm = rng.permutation(len(v))
    renumbered = np.empty_like(perm)
    renumbered[perm] = np.arange(len(v))
    order = rng.permutation(len(t))
    later = np.roll(renumbered[t], 1, axis=1)[order]
    new = np.array([[0, 1, 2], [3, 4, 5]], np.int64)
    later = np.concatenate([later[:7], new, later[7:]])
    k2, r2, e2, fresh = native._elements.cached(pixel[perm], later, width * height, keys, rows, sse, len(t))
    assert np.array_equal(fresh, [7, 8]) and np.array_equal(r2[fresh], [len(t), len(t) + 1])
    kept = np.r_[0:7, 9:len(later)]
    assert np.array_equal(r2[kept], rows[order]) and np.array_equal(e2[kept], sse[order])
    assert len(k2) == len(later)
    # no keys (they would overflow): everything is fresh
    assert len(native._elements.cached(pixel, t, 0, keys, rows, sse, 0)[3]) == len(t)
    with pytest.raises(ValueError, match="out of range"):
        native._elements.cached(pixel, np.array([[0, 1, len(v)]]), width * height, keys, rows, sse, 0)
    with pytest.raises(ValueError, match="overflow"):
        native._elements.cached(pixel, t, 2**21, keys, rows, sse, 0)
    with pytest.raises(ValueError, match="per old key"):
        native._elements.cached(pixel, t, width * height, keys, rows[:-1], sse, 0)


def _weights_in_numpy(v: np.ndarray, t: np.ndarray, width: int):
    """elements.triangle_raster's origins and coefficients as numpy computed them."""
    p = np.take(v, t, axis=0)
    first = (p[:, :, 1] * width + p[:, :, 0]).argmin(axis=1)
    origin = np.take_along_axis(p, first[:, None, None], axis=1)[:, 0]
    px, py = np.ascontiguousarray(p[:, :, 0].T), np.ascontiguousarray(p[:, :, 1].T)
    ox, oy = origin[:, 0], origin[:, 1]
    coef = np.empty((3, 3, len(p)), dtype=np.int64)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        ex, ey = px[k] - px[j], py[k] - py[j]
        coef[i, 0], coef[i, 1], coef[i, 2] = -ey, ex, ex * (oy - py[j]) - ey * (ox - px[j])
    return origin, coef.transpose(2, 0, 1), coef[:, 2].sum(axis=0)


@pytest.mark.parametrize("seed", range(3))
def test_the_triangle_weights_kernel_gives_numpys_integers(seed: int) -> None:
    """#20: triangle_raster's origins and weight coefficients come from a compiled pass
    (codec._elements.triangle_weights) instead of numpy's gathers: the same integers,
    whichever corner a triangle is listed from."""
    rng = np.random.default_rng(20 + seed)
    width, height = int(rng.integers(3, 300)), int(rng.integers(3, 200))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 400)), bool(seed % 2))
    t = np.roll(t, int(rng.integers(0, 3)), axis=1)
    raster = triangle_raster(v, t, width, height, spans=False)
    for got, expected in zip((raster.origin, raster.coef, raster.den), _weights_in_numpy(v, t, width)):
        assert got.dtype == np.int64 and np.array_equal(got, expected)
    with pytest.raises(ValueError, match="out of range"):
        native._elements.triangle_weights(v, np.array([[0, 1, len(v)]]), width, height)


def test_first_of_each_marks_the_first_of_every_value() -> None:
    rng = np.random.default_rng(12)
    for n in (0, 1, 7, 1000):
        keys = rng.integers(-5, 40, n).astype(np.int64)
        _, first = np.unique(keys, return_index=True)
        expected = np.zeros(n, bool)
        expected[first] = True
        assert np.array_equal(native._elements.first_of_each(keys), expected)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("kind", [np.uint8, np.uint16])
def test_one_narrow_plane_is_summed_without_a_prefix_table(seed: int, kind) -> None:
    import copy

    # an 8- or 16-bit plane alone: the kernels sum its spans pixel by pixel, and must
    # give the numbers of its prefix table (the encoder's bytes depend on them), up to
    # the largest values and on widths where the table needs int64
    rng = np.random.default_rng(40 + seed)
    top = np.iinfo(kind).max
    width, height = (int(rng.integers(3, 90)), int(rng.integers(3, 70))) if seed else (3000, 5)
    v, t = _mesh(rng, width, height, int(rng.integers(1, 200)), grid=seed == 1)
    plane = rng.integers(0, top + 1, (height, width)).astype(kind)
    plane[0, : width // 2] = top
    for fit in ("structure", None):
        layout = Statistics(plane, fit)
        assert layout._plane is not None and layout._planes is None  # no table made
        z = rng.normal(top / 2, top / 4, len(v))
        stats, sse = layout.of_triangles(v, t, z)
        raster = triangle_raster(v, t, width, height)
        by_spans = layout(raster)
        table = layout.planes.table
        assert table.dtype == (np.int32 if kind is np.uint8 and width < 2000 else np.int64)
        want = native._elements.triangle_statistics(v, t, width, height, table, layout._powers[1], layout._powers[2],
                                                    layout._from_kernel, layout._blocks, z)
        assert np.array_equal(stats, want[0]) and np.array_equal(sse, want[1])
        assert np.array_equal(by_spans, stats)
        by_table = copy.copy(layout)
        by_table._plane = None  # numpy's columns from the prefix table
        assert np.array_equal(by_table(raster), stats)


def _lines_by_hand(v: np.ndarray, width: int, height: int):
    """elements.line_raster's elements, piece by piece in plain Python: the bottom row,
    then the right column (pixels 0 .. H-2), cut between consecutive vertices on each."""
    corners, origin, coef, den, spans = [], [], [], [], []
    for axis, fixed, length in ((0, height - 1, width), (1, width - 1, height - 1))[: 2 if height > 1 else 1]:
        on = sorted((int(v[i, axis]), i) for i in range(len(v)) if v[i, 1 - axis] == fixed)
        for (p, a), nxt in zip(on, on[1:] + [None]):
            b, la = (a, 0) if nxt is None else (nxt[1], nxt[0] - p)
            w = np.zeros((3, 3), np.int64)
            if la:
                w[0, axis], w[0, 2], w[1, axis] = -1, la, 1
            else:
                w[0, 2] = 1
            e = len(corners)
            corners.append([a, b, b])
            origin.append(v[a])
            coef.append(w)
            den.append(max(la, 1))
            for q in range(p, min(p + max(la, 1), length)):
                if axis == 0 and q == p:
                    spans.append((e, fixed, p, min(max(la, 1), length - p)))
                elif axis == 1:
                    spans.append((e, q, fixed, 1))
    return corners, origin, coef, den, np.array(spans, np.int64).reshape(-1, 4).T


@pytest.mark.parametrize("seed", range(20))
def test_the_border_lines_elements_are_those_made_by_hand(seed: int) -> None:
    from codec.mesher.elements import line_raster

    rng = np.random.default_rng(60 + seed)
    width, height = (int(rng.integers(1, 40)), int(rng.integers(1, 40))) if seed > 2 else [(1, 9), (9, 1), (2, 2)][seed]
    v, _ = _mesh(rng, width, height, int(rng.integers(0, 60)), False) if width > 2 and height > 2 else (None, None)
    if v is None:
        v = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.int64)
        v = v[np.unique(v[:, 1] * width + v[:, 0], return_index=True)[1]]
    # more vertices on the two lines, in no order
    extra = np.concatenate([np.stack([rng.integers(0, width, 6), np.full(6, height - 1)], 1),
                            np.stack([np.full(6, width - 1), rng.integers(0, height, 6)], 1)])
    v = np.concatenate([v, rng.permutation(extra)])
    v = v[np.sort(np.unique(v[:, 1] * width + v[:, 0], return_index=True)[1])]
    got = line_raster(v, width, height)
    corners, origin, coef, den, (elem, ys, xs, ns) = _lines_by_hand(v, width, height)
    assert np.array_equal(got.corners, np.array(corners, np.int64).reshape(-1, 3))
    assert np.array_equal(got.origin, np.array(origin, np.int64).reshape(-1, 2))
    assert np.array_equal(got.coef, np.array(coef, np.int64).reshape(-1, 3, 3))
    assert np.array_equal(got.den, np.array(den, np.int64))
    for a, b in zip((got.span_elem, got.span_y, got.span_x, got.span_n), (elem, ys, xs, ns)):
        assert a.dtype == np.int64 and np.array_equal(a, b)
    # with the triangles', every pixel owned once
    if width > 1 and height > 1:
        t = triangle_raster(v, triangulate(v), width, height)
        _, x, y = t.pixels()
        e, lx, ly = got.pixels()
        owned = np.sort(np.r_[y * width + x, ly * width + lx])
        assert np.array_equal(owned, np.arange(width * height))


def test_the_border_lines_refuse_vertices_off_the_image() -> None:
    v = np.array([[0, 0], [4, 0], [0, 3], [4, 3]], np.int64)
    with pytest.raises(ValueError, match="outside the image"):
        native._elements.line_elements(v, 4, 4)
    with pytest.raises(ValueError, match="without a vertex"):
        native._elements.line_elements(v[:2], 5, 4)


def test_rows_gathered_from_parts_are_those_of_the_parts_stacked() -> None:
    rng = np.random.default_rng(5)
    parts = [rng.normal(size=(int(rng.integers(0, 40)), 10)) for _ in range(6)]
    stacked = np.concatenate(parts)
    rows = rng.integers(0, len(stacked), 300)
    out = np.full((300, 10), np.nan)
    native._elements.gather_rows(parts, rows, out)
    assert np.array_equal(out, stacked[rows])
    with pytest.raises(ValueError, match="beyond the parts"):
        native._elements.gather_rows(parts, np.array([len(stacked)]), np.empty((1, 10)))
    with pytest.raises(ValueError, match="beyond the parts"):
        native._elements.gather_rows(parts, np.array([-1]), np.empty((1, 10)))
    with pytest.raises(ValueError, match="do not match"):
        native._elements.gather_rows(parts + [np.zeros((2, 9))], rows, out)
    with pytest.raises(ValueError, match="per row"):
        native._elements.gather_rows(parts, rows, out[:-1])


def _worst_in_numpy(raster, plane: np.ndarray, z: np.ndarray, elements: np.ndarray):
    """Raster.worst_pixels as numpy computed it, pixel arrays and all."""
    from codec.mesher.elements import _segments

    spans = raster._spans_of(elements)
    spans = spans[raster.span_n[spans] > 0]
    e, y, x0, n = raster.span_elem[spans], raster.span_y[spans], raster.span_x[spans], raster.span_n[spans]
    if len(e) == 0:
        return e, x0, y, np.zeros(0)
    f = raster.affine(z, elements)[np.searchsorted(elements, e)]
    u = _segments(x0 - raster.origin[e, 0], n)
    index = np.repeat(y * plane.shape[1] + x0, n) + u - np.repeat(u[np.r_[0, np.cumsum(n)[:-1]]], n)
    mesh = np.repeat(f[:, 0], n) * u
    mesh += np.repeat(f[:, 1] * (y - raster.origin[e, 1]), n)
    mesh += np.repeat(f[:, 2], n)
    err = np.abs(np.take(plane, index) - mesh)
    elem_first = np.flatnonzero(np.r_[True, e[1:] != e[:-1]])
    peak = np.maximum.reduceat(err, np.r_[0, np.cumsum(n)[:-1]][elem_first])
    owner = np.repeat(np.cumsum(np.r_[True, e[1:] != e[:-1]]) - 1, n)
    at_peak = np.flatnonzero(err == peak[owner])
    best = at_peak[np.r_[True, owner[at_peak][1:] != owner[at_peak][:-1]]]
    w = plane.shape[1]
    return e[elem_first], index[best] % w, index[best] // w, err[best]


@pytest.mark.parametrize("seed", range(6))
def test_the_worst_pixels_of_any_elements_are_numpys(seed: int) -> None:
    from codec.mesher.elements import line_raster, rasterize

    rng = np.random.default_rng(70 + seed)
    width, height = int(rng.integers(3, 80)), int(rng.integers(3, 60))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 150)), seed % 2 == 1)
    plane = (rng.integers(0, 4, (height, width)) * 20).astype(np.float32)  # plateaus: ties
    for raster in (rasterize(v, t, width, height), line_raster(v, width, height)):
        for z in (plane[v[:, 1], v[:, 0]].astype(np.float64), rng.normal(30, 20, len(v))):
            for which in (np.arange(len(raster)), np.sort(rng.choice(len(raster), len(raster) // 3, replace=False))):
                want = _worst_in_numpy(raster, plane, z, which)
                for p in (plane, plane.astype(np.float64)):
                    got = raster.worst_pixels(p, z, which)
                    for a, b in zip(got, want):
                        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="out of range"):
        raster.worst_pixels(plane, z, np.array([len(raster)]))


@pytest.mark.parametrize("seed", range(4))
def test_span_statistics_are_the_numpy_columns_summed(seed: int) -> None:
    # Statistics of a raster's spans in one compiled pass (one narrow plane: pixel by
    # pixel; any layout: from its prefix table) against the numpy columns and row sums
    # the table path still takes, on triangle and border-line rasters
    import copy

    from codec.mesher.elements import line_raster, rasterize

    rng = np.random.default_rng(80 + seed)
    width, height = int(rng.integers(3, 90)), int(rng.integers(3, 70))
    v, t = _mesh(rng, width, height, int(rng.integers(1, 200)), seed % 2 == 1)
    for structure, fit in _images(rng, width, height):
        layout = Statistics(structure, fit)
        by_table = copy.copy(layout)
        by_table._plane = None  # the numpy path, from the prefix table
        for raster in (rasterize(v, t, width, height), line_raster(v, width, height)):
            want = by_table(raster)
            assert np.array_equal(layout(raster), want)
            got = native._elements.span_statistics(
                layout.planes.table, raster.bounds, raster.span_y, raster.span_x, raster.span_n, raster.origin,
                layout._powers[1], layout._powers[2], layout._from_kernel, layout._blocks)
            assert np.array_equal(got, want)
    raster = line_raster(v, width, height)
    args = (layout._powers[1], layout._powers[2], layout._from_kernel, layout._blocks)
    plane = np.zeros((height, width), np.uint8)
    outside = raster.span_y.copy()
    outside[0] = height
    with pytest.raises(ValueError, match="outside the image"):
        native._elements.span_statistics(plane, raster.bounds, outside, raster.span_x, raster.span_n, raster.origin, *args)
    late = raster.bounds.copy()
    late[0] = 1
    with pytest.raises(ValueError, match="from 0 to the number of spans"):
        native._elements.span_statistics(plane, late, raster.span_y, raster.span_x, raster.span_n, raster.origin, *args)


def test_the_border_lines_refuse_two_vertices_at_one_pixel() -> None:
    # each would count an element while the line's table keeps one: rows of the result
    # were left unwritten
    v = np.array([[0, 0], [4, 0], [0, 3], [4, 3], [2, 3], [2, 3]], np.int64)
    with pytest.raises(ValueError, match="two vertices at one border pixel"):
        native._elements.line_elements(v, 5, 4)
    with pytest.raises(ValueError, match="two vertices at one border pixel"):
        native._elements.line_elements(np.r_[v[:4], [[4, 1], [4, 1]]], 5, 4)


def test_triangle_statistics_of_chosen_rows_go_to_those_rows() -> None:
    """#20: Statistics.of_triangles(rows=, into=, sse_into=) measures only the rows
    asked for, each into its own row of the caller's arrays (refinement's statistics
    kept by slot), with the numbers of the plain call; a row beyond the triangles or
    arrays too small are refused."""
    from codec.triangulate import triangulate

    rng = np.random.default_rng(4)
    for dtype in (np.uint8, np.uint16, np.float32):
        image = (rng.random((40, 52)) * 200).astype(dtype)
        layout = Statistics(image, "structure")
        pts = np.unique(np.stack([rng.integers(0, 52, 90), rng.integers(0, 40, 90)], 1), axis=0)
        v = np.concatenate([[[0, 0], [51, 0], [0, 39], [51, 39]], pts])
        v = v[np.unique(v[:, 1] * 52 + v[:, 0], return_index=True)[1]]
        t = triangulate(v, None)
        z = image[v[:, 1], v[:, 0]].astype(np.float64)
        stats, sse = layout.of_triangles(v, t, z)
        rows = rng.permutation(len(t))[: len(t) // 3]
        into = np.full_like(stats, -7.0)
        sse_into = np.full(len(t), -7.0)
        layout.of_triangles(v, t, z, rows, into, sse_into)
        np.testing.assert_array_equal(into[rows], stats[rows])
        np.testing.assert_array_equal(sse_into[rows], sse[rows])
        others = np.setdiff1d(np.arange(len(t)), rows)
        assert (into[others] == -7).all() and (sse_into[others] == -7).all()
        with pytest.raises(ValueError, match="beyond the triangles"):
            layout.of_triangles(v, t, z, np.array([len(t)]), into, sse_into)
        with pytest.raises(ValueError, match="a row per triangle"):
            layout.of_triangles(v, t, z, rows, into[:-1], sse_into)
        with pytest.raises(ValueError, match="a row per triangle"):
            layout.of_triangles(v, t, z, rows, into, None)


def test_mesh_elements_are_the_triangles_joined_with_the_lines() -> None:
    """#20: mesh_elements has the kernel write the triangles' weights into arrays with
    room for the border lines' rows: the raster concat() of the two gives, field by
    field, with no copy of the triangles' rows."""
    from codec.mesher.elements import concat, line_raster, mesh_elements

    rng = np.random.default_rng(21)
    for w, h in ((45, 37), (2, 9), (64, 3)):
        pts = np.stack([rng.integers(0, w, 60), rng.integers(0, h, 60)], 1)
        v = np.concatenate([[[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], pts])
        v = v[np.sort(np.unique(v[:, 1] * w + v[:, 0], return_index=True)[1])]
        t = triangulate(v, None)
        lines = line_raster(v, w, h)
        joined = concat([triangle_raster(v, t, w, h, spans=False), lines])
        made = mesh_elements(v, t, lines)
        assert len(made) == len(joined) == len(t) + len(lines)
        for field in ("corners", "origin", "coef", "den", "span_elem", "span_y", "span_x", "span_n", "bounds"):
            np.testing.assert_array_equal(getattr(made, field), getattr(joined, field))
