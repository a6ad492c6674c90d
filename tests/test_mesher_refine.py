"""Refinement keeps its triangulation between rounds (codec.triangulate.Triangulation)
and renumbers it at the end: the mesh it returns must still be triangulate()'s own
triangulation of its vertices and walls, in canonical order, as a decoder rebuilds it."""

from __future__ import annotations

import numpy as np
import pytest

from codec.mesh import segments
from codec.mesher import adaptive
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
