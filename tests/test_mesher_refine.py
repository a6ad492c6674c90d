"""Refinement keeps its triangulation between rounds (codec.triangulate.Triangulation)
and renumbers it at the end: the mesh it returns must still be triangulate()'s own
triangulation of its vertices and walls, in canonical order, as a decoder rebuilds it."""

from __future__ import annotations

import numpy as np
import pytest

import codec
from codec.mesh import segments
from codec.mesher import adaptive, refine
from codec.triangulate import triangulate
from tests.synthetic import range_scene


@pytest.mark.parametrize("seed, points", [(1, 300), (4, 900), (7, 2500)])
def test_the_refined_mesh_is_the_triangulation_of_its_vertices_and_walls(seed: int, points: int) -> None:
    image = range_scene(160, 120, seed=seed)
    meshed = adaptive.build(image, points)
    mesh = meshed.mesh
    assert meshed.delaunay and len(mesh.constraints)
    assert np.array_equal(mesh.triangles, triangulate(mesh.vertices, segments(mesh.constraints)))
    assert len(mesh.vertices) > 0.9 * points


def test_the_cache_of_triangle_statistics_changes_nothing(monkeypatch) -> None:
    # a triangle kept from one round to the next reuses its sums; without the cache
    # (what happens where the keys would overflow) every triangle is measured anew
    image = range_scene(160, 120, seed=5)
    cached = adaptive.build(image, 900).mesh
    monkeypatch.setattr(refine, "_key_base", lambda *args: 0)
    fresh = adaptive.build(image, 900).mesh
    for a, b in ((cached.vertices, fresh.vertices), (cached.triangles, fresh.triangles), (cached.values, fresh.values)):
        assert np.array_equal(a, b)


def test_merging_keeps_the_first_point_of_each_pixel_in_group_order() -> None:
    """#20: merge() finds repeated pixels with a hash table in one pass
    (codec._elements.first_of_each) where np.unique sorted all the keys: the same
    points, in the same order."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        width = int(rng.integers(1, 50))
        groups = [np.stack([rng.integers(0, width, n), rng.integers(0, 40, n)], 1).astype(np.int64)
                  for n in rng.integers(0, 300, int(rng.integers(1, 4)))]
        pts = np.concatenate(groups)
        _, first = np.unique(pts[:, 1] * width + pts[:, 0], return_index=True)
        assert np.array_equal(refine.merge(width, *groups), pts[np.sort(first)])


def test_the_kept_statistics_are_gathered_part_by_part_as_from_the_joined_store() -> None:
    """#20: _Cache.statistics gathers the last triangulation's rows from each round's
    part of the store into one array, with the border lines' rows after them, instead
    of joining the parts and then appending: the same rows in the same order."""
    from codec.mesher.elements import Statistics

    layout = Statistics(range_scene(40, 30, seed=1), "structure")
    rng = np.random.default_rng(8)
    for parts in ([5], [3, 0, 7], [1, 1, 1, 9]):
        cache = refine._Cache(layout)
        cache._parts = [rng.standard_normal((n, layout.width)) for n in parts]
        joined = np.concatenate(cache._parts)
        cache._last = rng.integers(0, len(joined), 23)
        after = rng.standard_normal((4, layout.width))
        assert np.array_equal(cache.statistics(), joined[cache._last])
        assert np.array_equal(cache.statistics(after), np.concatenate([joined[cache._last], after]))


def _kernel_refused(monkeypatch) -> None:
    """Make refinement's kept triangulation refuse to start, so that every round
    triangulates anew and lists its triangles in canonical order (the path taken
    where the kernel refuses the start)."""
    from codec.errors import ATMError

    def refuse(*args, **kwargs):
        raise ATMError("refused")

    monkeypatch.setattr(refine, "_Kept", refuse)


@pytest.mark.parametrize("seed", [5, 6])
def test_refinement_by_slots_gives_what_canonical_lists_give_ties_included(monkeypatch, seed: int) -> None:
    """#20: refinement keeps its triangles' statistics and squared errors by the
    kernel's slot and measures only the slots each insertion rewrote, with no list of
    every triangle a round; ties at the batch's cut go to the first in canonical order
    and the candidates are taken in it. A periodic image on a grid of its period makes
    many triangles of exactly equal error, so the ties decide: the vertices, triangles,
    raster and statistics must be those of refinement on canonical lists (taking the
    tied triangles in slot order instead changes the vertices here)."""
    from codec.mesher.elements import Statistics

    rng = np.random.default_rng(seed)
    gray = np.tile(rng.integers(0, 255, (8, 8)).astype(np.uint8), (9, 9))[:65, :65]
    g = np.r_[0:64:8, 64]
    vertices = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2).astype(np.int64)
    walls = np.zeros((0, 2), np.int64)
    by_slots = refine.refine_to_budget(gray, vertices, walls, 900, Statistics(gray, "structure"))
    _kernel_refused(monkeypatch)
    listed = refine.refine_to_budget(gray, vertices, walls, 900, Statistics(gray, "structure"))
    for a, b in zip(by_slots, listed):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
    for field in ("corners", "origin", "coef", "den", "span_elem"):
        np.testing.assert_array_equal(getattr(by_slots[3], field), getattr(listed[3], field))
    assert by_slots[5] == listed[5] and len(by_slots[0]) == 900


@pytest.mark.parametrize("bands", [1, 3])
def test_refinement_by_slots_gives_the_same_meshes_on_scenes_and_bands(monkeypatch, bands: int) -> None:
    """#20: the same for the adaptive mesher on range scenes with walls, where a band's
    finish changes the mesh before the last triangulation (the kept statistics then
    seed the cache of triangles by their pixels) and the mean squared error it is
    handed is summed in canonical order: the encoded bytes are those of refinement on
    canonical lists."""
    import codec

    images = [range_scene(160, 120, seed=s) for s in (2, 9)]
    options = {"points": 1200, "band_height": 120 // bands + 1} if bands > 1 else {"points": 1200}
    kept = [codec.encode(image, **options) for image in images]
    _kernel_refused(monkeypatch)
    assert [codec.encode(image, **options) for image in images] == kept


def test_the_kept_triangulation_grows_its_tables_and_keeps_each_slots_numbers() -> None:
    """#20: _Kept's tables by slot (corners, statistics, squared errors) start with room
    for a budget's triangles and double when a mesh needs more: after insertions far
    beyond its budget, every slot's numbers are those of its triangle measured afresh,
    and its canonical list with slots is triangulate()'s."""
    from codec.mesher.elements import Statistics

    image = range_scene(90, 70, seed=3)
    gray = image.astype(np.float32)
    layout = Statistics(image, "structure")
    rng = np.random.default_rng(2)
    corners = np.array([[0, 0], [89, 0], [0, 69], [89, 69]])
    kept = refine._Kept(layout, corners, np.zeros((0, 2), np.int64), target=0)
    vertices = corners
    for _ in range(4):
        points = np.stack([rng.integers(0, 90, 150), rng.integers(0, 70, 150)], 1)
        vertices, near = kept.add(vertices, points, np.full(len(points), -1, np.int64))
        z = gray[vertices[:, 1], vertices[:, 0]].astype(np.float64)
        kept.measure(vertices, z)
    assert len(kept.sse) >= kept.m > 2 * 16
    tris, slots = kept.canonical()
    np.testing.assert_array_equal(tris, triangulate(vertices))
    stats, sse = layout.of_triangles(vertices, tris, z)
    np.testing.assert_array_equal(kept.stats[slots], stats)
    np.testing.assert_array_equal(kept.sse[slots], sse)


def test_a_band_too_large_for_triangle_keys_is_seeded_and_measured_again_in_full() -> None:
    """#20 (review): a band of 1,664,511 pixels or more has no triangle keys
    (_key_base 0). Seeding the cache after a finish() kept a row per triangle with no
    key, and the next round's measure raised ValueError from _elements.cached: a
    1300 x 1300 image with holes in one band failed to encode. Now nothing is kept there
    and the round measures every triangle, with the numbers of a fresh measurement."""
    from codec.mesher.elements import Statistics

    w = h = 1300
    assert refine._key_base(w, h) == 0
    yy, xx = np.mgrid[0:h, 0:w]
    image = ((xx * 7 + yy * 3) % 4000 + 100).astype(np.uint16)
    layout = Statistics(image, "structure")
    rng = np.random.default_rng(4)
    inner = np.stack([rng.integers(1, w - 1, 300), rng.integers(1, h - 1, 300)], 1)
    vertices = np.unique(np.concatenate([[[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], inner]), axis=0)
    tris = triangulate(vertices)
    z = image[vertices[:, 1], vertices[:, 0]].astype(np.float64)
    stats, sse = layout.of_triangles(vertices, tris, z)
    cache = refine._Cache(layout)
    cache.seed(vertices, tris, stats, sse, w, h)
    np.testing.assert_array_equal(cache.measure(vertices, tris, z, w, h), sse)
    np.testing.assert_array_equal(cache.statistics(), stats)

    holes = image.copy()
    holes[400:700, 500:900] = 0
    data = codec.encode(holes, nodata=0, band_height=h)
    decoded = codec.decode(data)
    assert decoded.shape == (h, w)
    np.testing.assert_array_equal(decoded == 0, holes == 0)
