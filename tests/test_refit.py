"""Local least squares during refinement to a bound: codec.mesher.values.refit moves
only the vertices it is told to, and refinement refits only what a round changed."""

from __future__ import annotations

import numpy as np
import pytest

import codec
from codec import decoder_cpu, error_bound
from codec.mesh import Mesh
from codec.mesher import values as vertex_values
from codec.triangulate import triangulate


def random_mesh(image: np.ndarray, count: int, seed: int = 0):
    h, w = image.shape[:2]
    rng = np.random.default_rng(seed)
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    pts = np.c_[rng.integers(0, w, count), rng.integers(0, h, count)]
    vertices = np.unique(np.r_[pts, corners], axis=0)
    return vertices, triangulate(vertices, np.zeros((0, 2), np.int64))


def squared_error(image, vertices, triangles, values) -> float:
    h, w = image.shape[:2]
    out = decoder_cpu.render(Mesh(vertices, values, triangles, w, h, [], None))
    return float(((out.astype(np.float64) - image) ** 2).sum())


def test_refit_of_every_vertex_is_the_global_fit(corpus):
    image = corpus["camera"]
    vertices, triangles = random_mesh(image, 2000)
    whole = vertex_values.fit(image, vertices, triangles, "lsq")
    local = vertex_values.refit(image, vertices, triangles, vertex_values.sample(image, vertices),
                                np.ones(len(vertices), bool))
    assert np.array_equal(local, whole)


def test_refit_moves_only_free_vertices_and_lowers_the_error(corpus):
    for image in (corpus["camera"], corpus["astronaut"]):
        vertices, triangles = random_mesh(image, 1500, seed=1)
        start = vertex_values.sample(image, vertices)
        free = np.random.default_rng(2).random(len(vertices)) < 0.2
        out = vertex_values.refit(image, vertices, triangles, start, free)
        assert out.dtype == image.dtype and out.shape == start.shape
        assert np.array_equal(out[~free], start[~free])
        assert not np.array_equal(out[free], start[free])
        assert squared_error(image, vertices, triangles, out) < squared_error(image, vertices, triangles, start)


def test_refinement_refits_only_what_each_round_changed(corpus, monkeypatch):
    shares = []
    refit = vertex_values.refit

    def recording(image, vertices, triangles, previous, free, layout=None):
        shares.append(free.mean())
        return refit(image, vertices, triangles, previous, free, layout)

    def no_global_fit(*args, **kwargs):
        raise AssertionError("refinement refitted the whole mesh")

    monkeypatch.setattr(error_bound.vertex_values, "refit", recording)
    monkeypatch.setattr(error_bound.vertex_values, "fit", no_global_fit)
    image = corpus["camera"][:200, :200]
    out = codec.decode(codec.encode(image, max_error=6, residual=False))  # the mesh's refinement
    assert np.abs(out.astype(int) - image).max() <= 6
    assert len(shares) > 3
    # the late rounds add few vertices: a small part of the mesh is refitted
    assert min(shares) < 0.2


def test_a_max_error_bound_takes_fewer_rounds(corpus, monkeypatch):
    # camera's top-left corner at max_error=6 took 76 rounds when the last pixels
    # beside walls waited a round each (60 now)
    rounds = []
    measure = error_bound._Errors.measure
    monkeypatch.setattr(error_bound._Errors, "measure", lambda *a: rounds.append(1) or measure(*a))
    image = corpus["camera"][:200, :200]
    out = codec.decode(codec.encode(image, max_error=6, residual=False))  # the mesh's refinement
    assert np.abs(out.astype(int) - image).max() <= 6
    assert len(rounds) <= 64


def test_inserting_vertices_changes_only_the_triangles_that_touch_them():
    """The unique triangulation (ATM.md §4.2.5) of more vertices differs from that of
    fewer only in triangles with a new corner, walls or none: what refinement relies on
    to find the triangles a round made without matching all of them."""
    rng = np.random.default_rng(3)
    for trial in range(20):
        w, h = rng.integers(8, 60, 2)
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
        pixels = rng.permutation(w * h)[: rng.integers(10, w * h // 2)]
        pts = np.unique(np.r_[corners, np.c_[pixels % w, pixels // w]], axis=0)
        old = pts[rng.random(len(pts)) < 0.6]
        old = np.unique(np.r_[corners, old], axis=0)
        added = pts[~(pts[:, None] == old[None]).all(axis=2).any(axis=1)]
        before = triangulate(old)
        walls = before[rng.permutation(len(before))[:3], :2] if trial % 2 else np.zeros((0, 2), np.int64)
        before = triangulate(old, walls)
        vertices = np.r_[old, added]
        after = triangulate(vertices, walls)
        made = error_bound._new_triangles(before, after, len(vertices))
        is_new = np.zeros(len(vertices), bool)
        is_new[len(old):] = True
        np.testing.assert_array_equal(made, is_new[after].any(axis=1))


def test_refinement_finds_a_rounds_new_triangles_by_their_new_corners(corpus, monkeypatch):
    """Once the mesh is the unique triangulation, a round's new triangles are found by
    their new corners: matching the old triangles against the new (1.8 s of 16 on a
    512² DEM at max_error=2) is left for a round that drops the walls (the test above
    shows both give the same triangles)."""
    image = corpus["camera"][:160, :160]
    matched = []
    real = error_bound._new_triangles
    monkeypatch.setattr(error_bound, "_new_triangles", lambda *a: matched.append(1) or real(*a))
    rounds = []
    measure = error_bound._Errors.measure
    monkeypatch.setattr(error_bound._Errors, "measure", lambda *a: rounds.append(1) or measure(*a))
    out = codec.decode(codec.encode(image, max_error=8, residual=False))
    assert np.abs(out.astype(int) - image).max() <= 8 and len(rounds) > 5
    assert len(matched) <= 1  # at most the round that gives up the walls


def test_the_kept_triangulation_grows_as_a_full_one_would():
    """Refinement's kept triangulation (error_bound._Growing: inserting each round's
    vertices) gives the triangles meshcode.in_stored_order makes by triangulating them
    all again, with walls, round after round (in the mesh's own numbering: put in stored
    order, the same canonical list)."""
    from codec.coding import canonical_triangles
    from codec import meshcode
    from codec.mesh import segments

    rng = np.random.default_rng(5)
    w, h = 90, 70
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    wall = np.array([[10, 10], [40, 25], [70, 20]])
    start = np.unique(np.r_[corners, wall, rng.integers(0, [w, h], (40, 2))], axis=0)
    keys = start[:, 1] * w + start[:, 0]
    line = [np.searchsorted(np.sort(keys), p[1] * w + p[0]) for p in wall]
    start = start[np.argsort(keys)]
    mesh = meshcode.in_stored_order(Mesh(start, np.zeros(len(start), np.uint8), np.zeros((0, 3), np.int64),
                                         w, h, [np.array(line)]))
    growing = error_bound._Growing(mesh)
    taken = {tuple(p) for p in mesh.vertices.tolist()}
    for _ in range(6):
        pts = [p for p in rng.integers(0, [w, h], (60, 2)).tolist() if tuple(p) not in taken]
        pts = np.unique(np.array(pts), axis=0)
        taken |= {tuple(p) for p in pts.tolist()}
        grown = Mesh(np.r_[mesh.vertices, pts], np.zeros(len(mesh.vertices) + len(pts), np.uint8),
                     mesh.triangles, w, h, mesh.constraints)
        full = meshcode.in_stored_order(grown)
        kept = growing.grow(grown, len(mesh.vertices))
        np.testing.assert_array_equal(kept.vertices, grown.vertices)
        stored = meshcode.in_stored_order(kept, triangulate_again=False)
        np.testing.assert_array_equal(stored.vertices, full.vertices)
        np.testing.assert_array_equal(canonical_triangles(stored.triangles), full.triangles)
        assert [c.tolist() for c in stored.constraints] == [c.tolist() for c in full.constraints]
        assert len(segments(kept.constraints))
        mesh = kept


def test_a_vertex_outside_the_kept_triangulation_is_refused():
    """A vertex beyond the first vertices' hull cannot be inserted: ATMError, which
    refinement answers by triangulating in full (a mesh without its corners)."""
    from codec import meshcode
    from codec.errors import ATMError

    v = np.array([[5, 5], [20, 5], [5, 20], [20, 20]])
    mesh = meshcode.in_stored_order(Mesh(v, np.zeros(4, np.uint8), np.zeros((0, 3), np.int64), 30, 30))
    grown = Mesh(np.r_[mesh.vertices, [[25, 25]]], np.zeros(5, np.uint8), mesh.triangles, 30, 30)
    with pytest.raises(ATMError):
        error_bound._Growing(mesh).grow(grown, 4)


def test_renumbered_triangles_come_in_canonical_order():
    """codec._renumber.canonical_renumbered(t, number) is canonical_triangles(number[t]),
    and refuses corners or numbers out of range."""
    from codec.coding import canonical_triangles
    from codec.native import _renumber

    rng = np.random.default_rng(2)
    for n in (3, 10, 500, 5000):
        v = np.unique(rng.integers(0, 200, (n, 2)), axis=0)
        v = np.r_[[[0, 0], [199, 0], [0, 199], [199, 199]], v[(v % 199 != 0).any(axis=1)]]
        v = np.unique(v, axis=0)
        t = triangulate(v)
        number = rng.permutation(len(v))
        np.testing.assert_array_equal(_renumber.canonical_renumbered(t, number),
                                      canonical_triangles(number[t]))
    with pytest.raises(ValueError):
        _renumber.canonical_renumbered(np.array([[0, 1, 5]]), np.arange(3))
    with pytest.raises(ValueError):
        _renumber.canonical_renumbered(np.array([[0, 1, 2]]), np.array([0, 1, 7]))


def _span_normals(image, vertices, triangles):
    """The numpy route to the triangles' normal equations: row spans, prefix-sum
    statistics per element, then the 3 x 3 products."""
    from codec.mesher.elements import triangle_raster

    h, w = image.shape[:2]
    layout = vertex_values.layout_for(image)
    raster = triangle_raster(vertices, triangles, w, h)
    return vertex_values.normal_equations(raster.coef, raster.den, *layout.fit_part(layout(raster)))


def test_the_compiled_normal_equations_are_those_of_the_triangles_spans(corpus):
    """codec._lsq.triangle_normals sums each triangle's pixels itself, replacing spans,
    prefix sums and products in numpy (most of a max_error encode's refits): the same
    pixels with the same weights, on gray, 16-bit, float and RGB images."""
    from codec.native import _lsq

    rng = np.random.default_rng(4)
    gray = corpus["camera"][:180, :230]
    cases = [gray, gray.astype(np.uint16) * 257, gray.astype(np.float64) / 7, corpus["astronaut"][:150, :170]]
    for k, image in enumerate(cases):
        vertices, triangles = random_mesh(image, [30, 300, 3000, 800][k], seed=k)
        planes = np.ascontiguousarray(image.reshape(image.shape[0], image.shape[1], -1))
        gram, rhs = _lsq.triangle_normals(vertices.astype(np.int64), triangles.astype(np.int64), planes)
        want_gram, want_rhs = _span_normals(image, vertices, triangles)
        np.testing.assert_allclose(gram, want_gram, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(rhs, want_rhs, rtol=1e-9, atol=1e-6)
        # held corners eliminated as refit does it in numpy
        n, c = len(vertices), planes.shape[2]
        free = rng.random(n) < 0.4
        number = np.where(free, np.cumsum(free) - 1, -1).astype(np.int64)
        known = rng.random((n, c)) * 200
        g, r, corners = _lsq.triangle_normals(vertices.astype(np.int64), triangles.astype(np.int64), planes,
                                              number, known)
        touching = free[triangles].any(axis=1)  # only these are summed
        t, want_gram, want_rhs = triangles[touching], want_gram[touching], want_rhs[touching]
        held = ~free[t]
        want_r = want_rhs - np.einsum("eij,ejc->eci", want_gram, np.where(held[:, :, None], known[t], 0.0))
        np.testing.assert_allclose(r, want_r, rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(g, want_gram * (~held)[:, :, None] * (~held)[:, None, :], rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(corners, np.where(held, free.sum(), number[t]))
        # rows left for the caller's own elements: zeros after the same results
        more = _lsq.triangle_normals(vertices.astype(np.int64), triangles.astype(np.int64), planes, number,
                                     known, 7)
        for got, want in zip(more, (g, r, corners)):
            assert len(got) == len(want) + 7 and not got[len(want):].any()
            np.testing.assert_array_equal(got[: len(want)], want)
    vertices, triangles = random_mesh(gray, 50)
    v, t, planes = vertices.astype(np.int64), triangles.astype(np.int64), np.ascontiguousarray(gray[:, :, None])
    beyond = t.copy()
    beyond[len(t) // 2, 1] = len(v)
    for bad_v, bad_t, message in ((v, beyond, "corner index"), (v * 2, t, "outside the image"),
                                  (v, t[:, ::-1].copy(), "counter-clockwise")):
        with pytest.raises(ValueError, match=message):
            _lsq.triangle_normals(bad_v, bad_t, planes)


def test_refit_sums_the_triangles_pixels_in_one_compiled_pass(corpus, monkeypatch):
    """refit no longer cuts the triangles into row spans for prefix-sum statistics."""
    from codec.mesher import elements

    def spans(*args, **kwargs):
        raise AssertionError("refit rasterised the triangles into spans")

    monkeypatch.setattr(elements, "triangle_raster", spans)
    image = corpus["camera"][:120, :140]
    vertices, triangles = random_mesh(image, 600, seed=5)
    start = vertex_values.sample(image, vertices)
    free = np.random.default_rng(6).random(len(vertices)) < 0.3
    out = vertex_values.refit(image, vertices, triangles, start, free)
    assert np.array_equal(out[~free], start[~free])
    assert squared_error(image, vertices, triangles, out) < squared_error(image, vertices, triangles, start)


def _numpy_conjugate_gradients(corners, gram, rhs, start, ridge, anchor, rtol, max_iter):
    """values.solve as it was in numpy: the reference the compiled one follows."""
    n, flat = len(start), corners.ravel()

    def apply(x):
        y = np.einsum("eij,ej->ei", gram, x[corners])
        return np.bincount(flat, weights=y.ravel(), minlength=n) + ridge * x

    diag = np.bincount(flat, weights=np.diagonal(gram, axis1=1, axis2=2).ravel(), minlength=n) + ridge
    out = np.empty(start.shape)
    for ch in range(start.shape[1]):
        b = np.bincount(flat, weights=rhs[:, ch, :].ravel(), minlength=n) + ridge * anchor[:, ch]
        x = start[:, ch].copy()
        r = b - apply(x)
        z = r / diag
        p, rz = z, r @ z
        for _ in range(max_iter):
            if np.linalg.norm(r) <= rtol * np.linalg.norm(b):
                break
            q = apply(p)
            alpha = rz / (p @ q)
            x, r = x + alpha * p, r - alpha * q
            z = r / diag
            rz, previous = r @ z, rz
            p = z + (rz / previous) * p
        out[:, ch] = x
    return out


def test_the_compiled_conjugate_gradients_follow_the_numpy_iteration(corpus):
    from codec.native import _lsq

    image = corpus["astronaut"][:90, :110]
    vertices, triangles = random_mesh(image, 400, seed=8)
    gram, rhs = (np.ascontiguousarray(a) for a in _span_normals(image, vertices, triangles))
    n = len(vertices)
    start = vertex_values.sample(image, vertices).reshape(n, -1).astype(np.float64)
    ridge = np.full(n, vertex_values.RIDGE) + np.random.default_rng(9).random(n)
    anchor = start + 3.0
    for rtol, steps in ((1e-4, 300), (1e-12, 5), (1e-12, 300)):
        got = _lsq.conjugate_gradients(triangles.astype(np.int64), gram, rhs, start, ridge, anchor, rtol, steps)
        want = _numpy_conjugate_gradients(triangles, gram, rhs, start, ridge, anchor, rtol, steps)
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-6)
    bad = triangles.astype(np.int64)
    bad[3, 2] = n
    with pytest.raises(ValueError, match="corner out of range"):
        _lsq.conjugate_gradients(bad, gram, rhs, start, ridge, anchor, 1e-4, 10)


def _numpy_normal_equations(coef, den, moments, image_sums):
    """values.normal_equations as it was written in numpy before codec._lsq.element_normals."""
    m = np.ascontiguousarray(moments.T)
    c = coef.astype(np.float64).transpose(1, 2, 0).copy()
    d = den.astype(np.float64)
    rows = ((m[3], m[4], m[1]), (m[4], m[5], m[2]), (m[1], m[2], m[0]))
    cm = [[sum(c[i, k] * rows[k][l] for k in range(3)) for l in range(3)] for i in range(3)]
    gram = np.empty((3, 3, len(d)))
    for i in range(3):
        for j in range(i, 3):
            gram[i, j] = gram[j, i] = sum(cm[i][l] * c[j, l] for l in range(3))
    gram = gram.transpose(2, 0, 1)
    gram /= (d * d)[:, None, None]
    s = image_sums
    rhs = (c[:, 0].T[:, None, :] * s[:, :, 1:2] + c[:, 1].T[:, None, :] * s[:, :, 2:3]
           + c[:, 2].T[:, None, :] * s[:, :, 0:1]) / d[:, None, None]
    return gram, rhs


def test_the_element_normal_equations_are_the_numpy_ones_to_the_bit(corpus):
    """codec._lsq.element_normals (values.normal_equations) gives the very float64
    numbers of the numpy expressions it replaced, on triangles and border lines of
    gray and RGB images, from strided statistics as the callers pass them."""
    from codec.mesher.elements import rasterize

    for k, image in enumerate([corpus["camera"][:150, :200], corpus["astronaut"][:120, :140]]):
        h, w = image.shape[:2]
        vertices, triangles = random_mesh(image, [500, 300][k], seed=10 + k)
        raster = rasterize(vertices, triangles, w, h)
        layout = vertex_values.layout_for(image)
        moments, sums = layout.fit_part(layout(raster))
        assert not moments.flags.c_contiguous  # a column slice of the statistics
        got = vertex_values.normal_equations(raster.coef, raster.den, moments, sums)
        want = _numpy_normal_equations(raster.coef, raster.den, moments, sums)
        for g, wnt in zip(got, want):
            assert g.shape == wnt.shape and np.array_equal(g.view(np.int64), np.ascontiguousarray(wnt).view(np.int64))


def test_the_planar_share_is_counted_as_numpy_counted_it(corpus):
    """values._planar_share with the compiled squared errors (codec._lsq.plane_errors) counts the
    same elements as the numpy planes and squared errors it replaced: on a photo, on a
    piecewise-planar image where most elements are exact, and with values that make
    some elements miss by just about the limit."""
    from codec.mesher.elements import rasterize, squared_error

    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:120, :160]
    planar = np.where(xx + yy < 130, 2 * xx + yy // 3, 200 - xx // 2).astype(np.uint8)
    for image in (corpus["camera"][:120, :160], planar):
        vertices, triangles = random_mesh(image, 400, seed=5)
        raster = rasterize(vertices, triangles, 160, 120)
        layout = vertex_values.layout_for(image)
        stats = layout(raster)
        moments, _ = layout.fit_part(stats)
        for values in (image[vertices[:, 1], vertices[:, 0]].astype(np.float64),
                       image[vertices[:, 1], vertices[:, 0]] + rng.normal(0, 0.3, len(vertices))):
            values = values[:, None]
            count = moments[:, 0]
            exact = squared_error(raster.affine(values[:, 0]), moments, stats[:, layout.IMG]) <= vertex_values.PLANAR * count
            want = float(count[exact].sum() / max(count.sum(), 1.0))
            assert vertex_values._planar_share(stats, layout, moments, values, raster) == want


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float64])
def test_the_outliers_sums_without_pixel_arrays_are_the_bincount_ones(dtype) -> None:
    """values._planar_refit sums the outlying pixels' terms in a compiled walk over the
    triangles (codec._elements.outlier_sums) instead of from every pixel's element, x
    and y as arrays and np.bincount: the same count and the same sums, bit for bit, on
    piecewise-planar images with steps and noise under planes near and far from them."""
    from codec.mesher.elements import triangle_pixels, triangle_raster
    from codec.native import _elements

    rng = np.random.default_rng(9)
    yy, xx = np.mgrid[:90, :130]
    scale = 1 if dtype == np.uint8 else 200
    for noise in (0.0, 3.0):
        image = np.where(xx * 2 + yy < 150, 40 + xx // 2 + yy // 3, 180 - xx // 4) * scale
        image = np.clip(image + rng.normal(0, noise * scale, image.shape), 0, 65535).astype(dtype)
        vertices, triangles = random_mesh(image, 300, seed=3)
        raster = triangle_raster(vertices, triangles, 130, 90)
        values = image[vertices[:, 1], vertices[:, 0]].astype(np.float64) + rng.normal(0, 2 * scale, len(vertices))
        affine = np.ascontiguousarray(raster.affine(values))
        e, x, y = triangle_pixels(vertices, triangles, 130, 90)
        b = image[y, x].astype(np.float64)
        out = np.abs(b - raster.evaluate(affine, e, x, y)) > vertex_values.OUTLIER
        e, b = e[out], b[out]
        u = (x[out] - raster.origin[e, 0]).astype(np.float64)
        v = (y[out] - raster.origin[e, 1]).astype(np.float64)
        want = np.stack([np.bincount(e, wt, len(triangles)) for wt in (np.ones_like(u), u, v, u * u, u * v, v * v, b, u * b, v * b, b * b)], 1)
        count, got = _elements.outlier_sums(vertices.astype(np.int64), triangles.astype(np.int64), 130, 90, affine,
                                            np.ascontiguousarray(raster.origin, dtype=np.int64), image,
                                            vertex_values.OUTLIER)
        assert 0 < count == out.sum() and np.array_equal(got, want)
    with pytest.raises(ValueError, match="out of range"):
        _elements.outlier_sums(vertices.astype(np.int64), triangles.astype(np.int64) + 1000, 130, 90, affine,
                               np.ascontiguousarray(raster.origin, dtype=np.int64), image, 2.0)


def test_element_squared_errors_are_numpys_to_the_bit(corpus) -> None:
    """elements.element_sse (codec._lsq.plane_errors) gives squared_error(raster.affine(z),
    ...)'s very numbers, on triangles and border lines, for smooth and rough values,
    from the strided statistics the callers pass; it refuses a corner out of range."""
    from codec.mesher.elements import Statistics, element_sse, rasterize, squared_error
    from codec.native import _lsq

    rng = np.random.default_rng(13)
    image = corpus["camera"][:140, :170]
    vertices, triangles = random_mesh(image, 600, seed=4)
    raster = rasterize(vertices, triangles, 170, 140)
    stats = vertex_values.layout_for(image)(raster)
    for z in (image[vertices[:, 1], vertices[:, 0]].astype(np.float64), rng.normal(100, 80, len(vertices))):
        want = squared_error(raster.affine(z), stats[:, Statistics.GEO], stats[:, Statistics.IMG])
        got = element_sse(raster, stats, z)
        assert np.array_equal(got.view(np.int64), want.view(np.int64))
    with pytest.raises(ValueError, match="corner"):
        _lsq.plane_errors(np.full((1, 3), 9, np.int64), np.ones((1, 3, 3), np.int64), np.ones(1, np.int64),
                          np.zeros(3), np.zeros((1, 6)), np.zeros((1, 4)))
