"""Refinement keeps its triangulation between rounds (codec.triangulate.Triangulation)
and renumbers it at the end: the mesh it returns must still be triangulate()'s own
triangulation of its vertices and walls, in canonical order, as a decoder rebuilds it."""

from __future__ import annotations

import numpy as np
import pytest

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
