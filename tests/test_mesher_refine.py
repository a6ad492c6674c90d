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
