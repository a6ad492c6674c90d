"""The rasteriser's corner order (codec/_rasterise.pyx): a triangle's corners are
taken in raster order (row, then column). Where the vertices' raster keys increase
with their index (a decoder's vertices are stored in raster order) the walk orders
corners by index and makes no key; any other vertex order must give the same pixels
and status by the keys."""

from __future__ import annotations

import numpy as np

from codec.mesh import Mesh
from codec.native import _rasterise
from codec.triangulate import triangulate
from tests.test_decoders import reference

_CHECKS = (_rasterise.Check.CHECK_TOTAL, _rasterise.Check.CHECK_SPANS)


def _mesh(rng: np.random.Generator, w: int, h: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices in raster order (the image's corners among them) and their Delaunay
    triangles."""
    pts = set(zip(rng.integers(0, w, n).tolist(), rng.integers(0, h, n).tolist()))
    pts |= {(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)}
    vertices = np.array(sorted(pts, key=lambda p: (p[1], p[0])), np.int64)
    return vertices, np.ascontiguousarray(triangulate(vertices), dtype=np.int64)


def _render(vertices, values, triangles, w: int, h: int, check, portable: bool) -> tuple[tuple, np.ndarray]:
    out = np.full((w * h, values.shape[1]), 7, values.dtype)
    return _rasterise.rasterise(vertices, values, triangles, out, w, h, check, portable=portable), out


def test_vertices_in_any_order_give_the_raster_orders_pixels() -> None:
    """The same mesh with its vertices in raster order, shuffled, and with only two
    neighbours swapped (one pair out of order), 8- and 16-bit, both walks and both
    coverage checks: the same pixels and status, and a valid mesh's are the rule's.
    A walk that took index order for raster order without checking it would take the
    wrong corner for the top one."""
    rng = np.random.default_rng(4021)
    for case in range(40):
        w, h = int(rng.integers(2, 90)), int(rng.integers(2, 60))
        vertices, triangles = _mesh(rng, w, h, int(rng.integers(1, w * h // 3 + 2)))
        n = len(vertices)
        for dtype in (np.uint8, np.uint16):
            top = int(np.iinfo(dtype).max)
            values = rng.integers(0, top + 1, (n, 1)).astype(dtype)
            expected = reference(Mesh(vertices, values[:, 0], triangles, w, h)).reshape(w * h, 1)
            swap = np.arange(n)
            k = int(rng.integers(0, n - 1))
            swap[[k, k + 1]] = swap[[k + 1, k]]
            for perm in (np.arange(n), rng.permutation(n), swap):
                place = np.empty(n, np.int64)
                place[perm] = np.arange(n)  # vertex perm[j] is now vertex j
                v2 = np.ascontiguousarray(vertices[perm])
                t2 = np.ascontiguousarray(place[triangles])
                for check in _CHECKS:
                    for portable in (False, True):
                        status, out = _render(v2, np.ascontiguousarray(values[perm]), t2, w, h, check, portable)
                        assert status == (0, 0), (case, w, h, check, portable)
                        assert np.array_equal(out, expected), (case, w, h, dtype, check, portable)


def test_repeated_vertex_keys_are_not_taken_for_raster_order() -> None:
    """Two vertices at one pixel (a vertex's copy appended, and a triangle moved onto
    it: the keys no longer increase, though the mesh still tiles the image): the
    corners are ordered by their keys, and the pixels are the rule's, whichever walk
    and coverage check."""
    rng = np.random.default_rng(4022)
    for _ in range(20):
        w, h = int(rng.integers(4, 40)), int(rng.integers(4, 40))
        vertices, triangles = _mesh(rng, w, h, w * h // 4)
        n = len(vertices)
        # a copy of a vertex appended, and one triangle moved onto it
        j = int(rng.integers(0, n))
        vertices = np.concatenate([vertices, vertices[j][None]])
        t = np.array(triangles)
        k = int(np.nonzero((t == j).any(1))[0][0])
        t[k][t[k] == j] = n
        values = rng.integers(0, 256, (n + 1, 1)).astype(np.uint8)
        values[n] = values[j]
        expected = reference(Mesh(vertices, values[:, 0], t, w, h)).reshape(w * h, 1)
        for check in _CHECKS:
            for portable in (False, True):
                status, out = _render(vertices, values, t, w, h, check, portable)
                assert status == (0, 0)  # the same pixel: the mesh still tiles the image
                assert np.array_equal(out, expected)
