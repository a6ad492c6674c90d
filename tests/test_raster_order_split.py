"""refine's raster order cuts the walls at the vertices on them in one compiled pass
(codec._renumber.split_in_raster_order): the pieces of triangulate.split_at_vertices,
in its order, on lattices of vertices with walls along rows, columns, diagonals and
slopes that pass over vertices, backwards, of length zero and repeated."""

from __future__ import annotations

import numpy as np
import pytest

from codec import native
from codec.triangulate import split_at_vertices


@pytest.mark.parametrize("seed", range(30))
def test_the_walls_are_cut_as_split_at_vertices_cuts_them(seed: int) -> None:
    rng = np.random.default_rng(seed)
    width, height = int(rng.integers(1, 50)), int(rng.integers(1, 50))
    count = int(rng.integers(1, min(width * height, 400) + 1))
    pixels = np.sort(rng.choice(width * height, count, replace=False))
    v = np.stack([pixels % width, pixels // width], 1).astype(np.int64)
    segments = rng.integers(0, count, (int(rng.integers(0, 60)), 2)).astype(np.int64)
    if count > 1:
        # walls along a row and a column of the lattice: many vertices on them
        row = np.flatnonzero(v[:, 1] == v[count // 2, 1])
        col = np.flatnonzero(v[:, 0] == v[count // 3, 0])
        segments = np.concatenate([segments, [[row[0], row[-1]], [col[-1], col[0]], [0, count - 1]]])
    want = split_at_vertices(v, segments, width)
    got = native._renumber.split_in_raster_order(v, segments, width)
    assert got.dtype == np.int64 and np.array_equal(got, want.reshape(-1, 2))


def test_the_cut_refuses_what_it_cannot_cut() -> None:
    v = np.array([[0, 0], [3, 0], [1, 2]], np.int64)
    split = native._renumber.split_in_raster_order
    with pytest.raises(ValueError, match="names no vertex"):
        split(v, np.array([[0, 3]], np.int64), 4)
    with pytest.raises(ValueError, match="raster order"):
        split(v[::-1].copy(), np.zeros((0, 2), np.int64), 4)
    with pytest.raises(ValueError, match="out of range"):
        split(v, np.zeros((0, 2), np.int64), 3)  # a vertex past the last column
    assert split(v, np.array([[1, 1], [0, 1]], np.int64), 4).tolist() == [[0, 1]]
