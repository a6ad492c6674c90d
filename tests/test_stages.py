"""Each stage of the encoder on small hand-made inputs whose right answer is known:
edges, polylines, unfolding into walls, region sampling, vertex values, refinement
to the budget, and the rows bands share."""

from __future__ import annotations

import numpy as np
import pytest

from codec import banding
from codec.mesh import Mesh
from codec.mesher import edges, polylines, refine, sampling, unfold, values
from codec.mesher.elements import Statistics
from codec.triangulate import triangulate


def _step(height: int = 20, width: int = 24, at: int = 12, low: float = 0, high: float = 200) -> np.ndarray:
    image = np.full((height, width), low, np.float32)
    image[:, at:] = high
    return image


def _flat_magnitude(mask: np.ndarray) -> np.ndarray:
    return np.ones(mask.shape, np.float32)


# edges ---------------------------------------------------------------------------


def test_a_vertical_step_is_one_edge_column_on_its_dark_side():
    found, magnitude, (low, high) = edges.detect(_step(), 255.0)
    assert found[:, 11].all()  # the last dark column, every row
    found[:, 11] = False
    assert not found.any()
    assert 0 < low <= high and magnitude[:, 11].min() > magnitude[:, 5].max()


def test_a_flat_image_has_no_edges():
    found, _, _ = edges.detect(np.full((16, 16), 90, np.float32), 255.0)
    assert not found.any()


# polylines ---------------------------------------------------------------------------


def test_a_straight_edge_is_one_segment_between_its_ends():
    mask = np.zeros((12, 24), bool)
    mask[5, 2:20] = True
    lines = polylines.trace(mask, _flat_magnitude(mask))
    assert len(lines) == 1
    assert lines.line(0).tolist() == [[2, 5], [19, 5]]
    assert sorted(map(tuple, lines.pixels.tolist())) == [(x, 5) for x in range(2, 20)]


def _distance_to_polyline(p: np.ndarray, line: np.ndarray) -> float:
    a, b = line[:-1].astype(float), line[1:].astype(float)
    d = b - a
    t = np.clip(((p - a) * d).sum(1) / np.maximum((d * d).sum(1), 1e-12), 0, 1)
    return float(np.min(np.hypot(*(a + t[:, None] * d - p).T)))


def test_a_bent_edge_keeps_every_pixel_within_the_segment_error():
    mask = np.zeros((20, 20), bool)
    mask[3, 3:15] = True
    mask[3:16, 14] = True
    lines = polylines.trace(mask, _flat_magnitude(mask), segment_length=4, segment_error=1.0)
    assert len(lines) == 1
    line = lines.line(0)
    assert line[0].tolist() == [3, 3] and line[-1].tolist() == [14, 15]  # the chain's ends
    assert len(line) > 2  # the bend needs control points between them
    # the rule's promise: no edge pixel further than segment_error from the polyline
    assert max(_distance_to_polyline(p.astype(float), line) for p in lines.pixels) <= 1.0 + 1e-9


def test_edges_shorter_than_min_pixels_are_dropped():
    mask = np.zeros((10, 10), bool)
    mask[4, 4:6] = True  # two pixels
    assert len(polylines.trace(mask, _flat_magnitude(mask), min_pixels=3)) == 0


# unfolding ------------------------------------------------------------------------


def test_an_edge_unfolds_into_one_wall_on_each_side():
    image = _step()
    mask = np.zeros(image.shape, bool)
    mask[2:18, 11] = True
    lines = polylines.trace(mask, _flat_magnitude(mask))
    walls = unfold.unfold(lines, image)
    assert sorted(walls.wall.tolist()) == [0, 1]  # the left and the right wall of polyline 0
    for k in (0, 1):
        feet = walls.points[np.unique(walls.segments[walls.wall == k])]
        side = image[feet[:, 1], feet[:, 0]]
        assert len(set(side.tolist())) == 1  # each wall stands on one side only
        assert sorted(feet[:, 1].tolist()) == [2, 17]  # as long as the edge
    dark = walls.points[np.unique(walls.segments[walls.wall == 0])]
    bright = walls.points[np.unique(walls.segments[walls.wall == 1])]
    assert {image[p[1], p[0]] for p in dark} != {image[p[1], p[0]] for p in bright}
    assert np.abs(dark[:, 0] - bright[:, 0]).max() == 1  # a pixel apart: the step between


# region sampling ----------------------------------------------------------------


def test_no_samples_where_the_density_is_excluded():
    curv = np.ones((40, 40))
    excluded = np.zeros((40, 40), bool)
    excluded[:, :20] = True
    dens = sampling.density(curv, excluded)
    assert (dens[:, :20] == 0).all() and (dens[:, 20:] > 0).all()
    pts = sampling.sample(dens, (2, 2), (3, 3))
    assert len(pts) and (pts[:, 0] >= 20).all()


def test_samples_follow_the_density():
    dens = np.zeros((30, 30))
    dens[:, 7] = 1.0  # all the density in one column
    pts = sampling.sample(dens, (1, 1), (2, 4))
    assert len(pts) and (pts[:, 0] == 7).all()


def test_curvature_is_where_the_surface_bends():
    assert np.abs(sampling.curvature(np.full((20, 20), 50, np.float32))).max() < 1e-3
    yy, xx = np.mgrid[0:40, 0:40].astype(np.float32)
    plane = sampling.curvature(3 * xx + 2 * yy)[8:-8, 8:-8]
    bowl = sampling.curvature(0.1 * ((xx - 20) ** 2 + (yy - 20) ** 2))[8:-8, 8:-8]
    assert plane.max() < 0.2 * bowl.min()


# vertex values ----------------------------------------------------------------------


def _grid_mesh(width: int, height: int, step: int):
    xs = np.unique(np.r_[np.arange(0, width, step), width - 1])
    ys = np.unique(np.r_[np.arange(0, height, step), height - 1])
    vertices = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2).astype(np.int64)
    return vertices, triangulate(vertices)


def test_least_squares_values_of_a_plane_are_the_plane():
    yy, xx = np.mgrid[0:21, 0:25]
    image = (2 * xx + 3 * yy + 10).astype(np.uint8)
    vertices, triangles = _grid_mesh(25, 21, 6)
    fitted = values.fit(image, vertices, triangles, "lsq")
    np.testing.assert_array_equal(fitted, image[vertices[:, 1], vertices[:, 0]])


def test_sampled_values_are_the_pixels_and_least_squares_beats_them_on_noise():
    rng = np.random.default_rng(1)
    image = np.clip(100 + rng.normal(0, 20, (21, 25)), 0, 255).astype(np.uint8)
    vertices, triangles = _grid_mesh(25, 21, 6)
    sampled = values.fit(image, vertices, triangles, "sample")
    np.testing.assert_array_equal(sampled, image[vertices[:, 1], vertices[:, 0]])
    from codec.decoder_cpu import render

    def sse(v):
        return float(((render(Mesh(vertices, v, triangles, 25, 21)).astype(float) - image) ** 2).sum())

    assert sse(values.fit(image, vertices, triangles, "lsq")) < sse(sampled)


# refinement to the budget --------------------------------------------------------


def test_refinement_puts_the_vertex_at_the_worst_pixel():
    gray = np.full((15, 20), 40, np.float32)
    gray[5, 7] = 240  # the only pixel the corners' mesh gets wrong
    corners = np.array([[0, 0], [19, 0], [0, 14], [19, 14]], np.int64)
    vertices, segments, triangles, _, _, delaunay = refine.refine_to_budget(
        gray, corners, np.zeros((0, 2), np.int64), 5, Statistics(gray, None)
    )
    assert sorted(map(tuple, vertices.tolist())) == sorted([(0, 0), (19, 0), (0, 14), (19, 14), (7, 5)])
    keys = vertices[:, 1] * 20 + vertices[:, 0]
    assert (np.diff(keys) > 0).all() and delaunay  # stored order, the decoder's triangles
    np.testing.assert_array_equal(triangles, triangulate(vertices))


def test_refinement_stops_early_when_nothing_is_wrong():
    gray = np.full((15, 20), 40, np.float32)
    corners = np.array([[0, 0], [19, 0], [0, 14], [19, 14]], np.int64)
    vertices, _, _, _, _, _ = refine.refine_to_budget(gray, corners, np.zeros((0, 2), np.int64), 50, Statistics(gray, None))
    assert len(vertices) == 4  # a flat image: the corners are exact


# the rows bands share ----------------------------------------------------------------


def test_default_band_height_is_about_a_megapixel():
    assert banding.default_band_height(1024, 5000) == 1024
    assert banding.default_band_height(1 << 20, 10) == banding.MIN_BAND_HEIGHT


def test_pinned_first_row_is_exactly_the_row_given():
    vertices = np.array([[0, 0], [5, 0], [9, 0], [0, 6], [9, 6], [4, 3]], np.int64)
    mesh = Mesh(vertices, np.arange(6, dtype=np.uint8) * 10, triangulate(vertices), 10, 7)
    pinned = banding.pin_top_row(mesh, np.array([0, 3, 9]), np.array([7, 8, 9], np.uint8))
    xs, vals = banding.bottom_row(Mesh(pinned.vertices[::-1] * [1, -1] + [0, 6], pinned.values[::-1],
                                       np.zeros((0, 3), np.int64), 10, 7))
    assert xs.tolist() == [0, 3, 9] and vals.tolist() == [7, 8, 9]
    below = pinned.vertices[:, 1] > 0
    assert sorted(map(tuple, pinned.vertices[below].tolist())) == [(0, 6), (4, 3), (9, 6)]
    assert len(pinned.triangles) == 0  # triangulated once, when the band is final


def test_pinned_first_row_renumbers_the_walls_below_it():
    """#20: pin_top_row renumbers the walls left below the first row all at once: each
    is its kept vertices' new numbers, as an addition per wall gave them."""
    from codec.mesh import without_vertices

    vertices = np.array([[0, 0], [9, 0], [0, 6], [9, 6], [2, 0], [2, 3], [6, 3], [6, 5], [4, 2]], np.int64)
    walls = [np.array([4, 5, 6]), np.array([6, 7]), np.array([8, 5])]
    mesh = Mesh(vertices, np.arange(9, dtype=np.uint8), np.zeros((0, 3), np.int64), 10, 7, walls)
    pinned = banding.pin_top_row(mesh, np.array([0, 3, 5, 9]), np.array([1, 2, 3, 4], np.uint8))
    base = without_vertices(mesh, vertices[:, 1] > 0)
    assert [c.tolist() for c in pinned.constraints] == [(c + 4).tolist() for c in base.constraints]
    # the same positions through the walls as before the pinning
    assert [pinned.vertices[c].tolist() for c in pinned.constraints] == [[[2, 3], [6, 3]], [[6, 3], [6, 5]],
                                                                           [[4, 2], [2, 3]]]


def test_last_row_gets_a_vertex_where_it_bends_and_none_where_it_is_straight():
    vertices = np.array([[0, 0], [15, 0], [0, 4], [15, 4]], np.int64)
    band = np.tile(np.arange(16, dtype=np.uint8) * 10, (5, 1))  # linear along x
    mesh = Mesh(vertices, band[vertices[:, 1], vertices[:, 0]], triangulate(vertices), 16, 5)
    assert banding.sample_last_row(mesh, band, 1.0) is mesh
    band[4, 6] = 250  # a spike on the last row
    grown = banding.sample_last_row(mesh, band, 1.0)
    xs, vals = banding.bottom_row(grown)
    assert 6 in xs.tolist() and vals[xs.tolist().index(6)] == 250


def test_the_last_rows_new_vertices_split_the_walls_along_that_row_and_only_those():
    """#20: sample_last_row splits only the walls with a step along the last row (the
    only steps a new vertex of that row can lie inside), not every wall of the band:
    the walls along the row pass through the new vertices as before; the others are
    left as given (here one passes an older vertex, which the band's last
    triangulation splits it at, as it splits every wall), so that split at every
    vertex all walls are what splitting all of them here gave."""
    from codec.mesh import segments
    from codec.triangulate import through_vertices

    rng = np.random.default_rng(12)
    band = rng.integers(0, 256, (9, 40), dtype=np.uint8)  # rough: the row gets many vertices
    vertices = np.array([[0, 0], [39, 0], [0, 8], [39, 8], [3, 8], [30, 8], [10, 2], [16, 4], [13, 3],
                         [25, 1], [15, 7]], np.int64)
    walls = [np.array([4, 5]), np.array([6, 7]), np.array([9, 7, 10]), np.array([0, 10, 2])]
    mesh = Mesh(vertices, band[vertices[:, 1], vertices[:, 0]], triangulate(vertices, segments(walls)), 40, 9, walls)
    grown = banding.sample_last_row(mesh, band, 0.5)
    new = grown.vertices[len(vertices):]
    assert len(new) and (new[:, 1] == 8).all()
    on_wall = new[(new[:, 0] > 3) & (new[:, 0] < 30), 0]
    assert len(on_wall)
    # the wall along the row now steps through each new vertex on it, in order
    along = grown.vertices[grown.constraints[0]]
    assert along[:, 0].tolist() == sorted([3, 30] + on_wall.tolist()) and (along[:, 1] == 8).all()
    for k in (1, 2, 3):
        assert np.array_equal(grown.constraints[k], walls[k])  # (13, 3) still inside wall 1
    everything = through_vertices(grown.vertices, walls)
    assert [c.tolist() for c in through_vertices(grown.vertices, grown.constraints)] == [c.tolist() for c in everything]


def _derivative_planes(rng: np.random.Generator, h: int, w: int) -> list[np.ndarray]:
    """float32 planes as Sobel gives them, with what the rounding rules meet: halves
    after scaling (Canny's fixed point rounds them to even), values past the int16
    clip, exact zeros, negatives, tiny and huge numbers."""
    plain = rng.normal(0, 40, (h, w)).astype(np.float32)
    halves = (rng.integers(-200, 200, (h, w)) / 8 + 1 / 32).astype(np.float32) * 4  # dx * 16 = k + 0.5
    wide = rng.normal(0, 20000, (h, w)).astype(np.float32)
    odd = rng.choice(np.array([0, -0.0, 1e-30, -1e-30, 3e30, 8191.75, -8191.75, 8191.8, 0.125], np.float32), (h, w))
    return [plain, halves, wide, odd.astype(np.float32)]


def test_the_gradient_kernel_gives_numpys_numbers() -> None:
    """#20: codec._gradients.edge_gradient replaced numpy's passes over the Sobel
    derivatives (divide by 4, magnitude, clip, scale, round to even, int16): the same
    float32 and int16 values, so the same thresholds, edges and bytes."""
    from codec.native import _gradients

    rng = np.random.default_rng(4)
    planes = _derivative_planes(rng, 37, 53)
    limit = 32767 / edges._SCALE
    with np.errstate(over="ignore", invalid="ignore"):
        _compare_gradients(_gradients, planes, limit)
    with pytest.raises(ValueError, match="differ"):
        _gradients.edge_gradient(planes[0], planes[1][:-1], limit, edges._SCALE)
    with pytest.raises(ValueError, match="int16"):
        _gradients.edge_gradient(planes[0], planes[1], 4096.0, edges._SCALE)


def _compare_gradients(_gradients, planes: list[np.ndarray], limit: float) -> None:
    for sx in planes:
        for sy in planes:
            mag, ix, iy = _gradients.edge_gradient(sx, sy, limit, edges._SCALE)
            dx, dy = sx / 4, sy / 4
            assert np.array_equal(mag, np.sqrt(dx * dx + dy * dy))
            assert mag.dtype == np.float32
            assert np.array_equal(ix, np.round(np.clip(dx, -limit, limit) * edges._SCALE).astype(np.int16))
            assert np.array_equal(iy, np.round(np.clip(dy, -limit, limit) * edges._SCALE).astype(np.int16))


def test_the_hessian_kernel_gives_numpys_numbers() -> None:
    from codec.native import _gradients

    rng = np.random.default_rng(5)
    planes = _derivative_planes(rng, 29, 41)
    dyy = planes[1]
    with np.errstate(over="ignore"):
        for dxx in planes:
            for dxy in planes[::-1]:
                assert np.array_equal(_gradients.hessian_norm(dxx, dyy, dxy),
                                      np.sqrt(dxx * dxx + 2 * dxy * dxy + dyy * dyy))
    with pytest.raises(ValueError, match="differ"):
        _gradients.hessian_norm(planes[0], planes[1], np.ascontiguousarray(planes[2][:, :-1]))


def _off_edge_by_numpy(lap: np.ndarray, found: np.ndarray) -> float:
    """adaptive._off_edge_curvature's share as its numpy steps made it."""
    import cv2

    energy = np.square(lap, dtype=np.float64)
    total = float(energy.sum())
    if total == 0:
        return 0.0
    near = cv2.dilate(found.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return float(energy[~near].sum()) / total


def test_the_off_edge_share_kernel_gives_numpys_share() -> None:
    """#20: codec._gradients.off_edge_share replaced the squared, dilated and masked
    images; the share is numpy's to rounding (its sums are pairwise), with the 3 x 3
    neighbourhood clipped at every border as cv2.dilate's is."""
    from codec.native import _gradients

    rng = np.random.default_rng(11)
    for h, w in ((1, 1), (1, 7), (6, 1), (2, 2), (17, 23), (64, 300)):
        lap = (rng.standard_normal((h, w)) * 40).astype(np.float32)
        for density in (0.0, 0.03, 0.3, 1.0):
            found = rng.random((h, w)) < density
            share = _gradients.off_edge_share(lap, found.view(np.uint8))
            assert share == pytest.approx(_off_edge_by_numpy(lap, found), rel=1e-12, abs=1e-15)
    # an edge on each border pixel in turn: only its clipped neighbourhood is near
    lap = np.ones((5, 6), np.float32)
    for y in range(5):
        for x in range(6):
            found = np.zeros((5, 6), bool)
            found[y, x] = True
            assert _gradients.off_edge_share(lap, found.view(np.uint8)) == _off_edge_by_numpy(lap, found)
    assert _gradients.off_edge_share(np.zeros((4, 4), np.float32), np.zeros((4, 4), np.uint8)) == 0.0
    with pytest.raises(ValueError, match="differ"):
        _gradients.off_edge_share(lap, np.zeros((5, 5), np.uint8))


def _without_in_a_loop(mesh: Mesh, keep: np.ndarray) -> list[np.ndarray]:
    """codec.mesh.without_vertices' walls as its loop over the polylines made them."""
    remap = np.full(len(mesh.vertices), -1, dtype=np.int64)
    remap[keep] = np.arange(int(np.count_nonzero(keep)))
    out = []
    for line in mesh.constraints:
        mapped = remap[line]
        for piece in np.split(mapped, np.flatnonzero(mapped < 0)):
            piece = piece[piece >= 0]
            if len(piece) >= 2:
                out.append(piece)
    return out


def test_dropping_vertices_splits_the_walls_as_the_loop_did() -> None:
    """#20: mesh.without_vertices (a band's pinned first row, holes) finds the runs of
    kept wall vertices for all walls at once; a loop over a 2048² band's walls took
    20 ms. The same pieces in the same order, also where every vertex of a wall goes."""
    from codec.mesh import without_vertices

    rng = np.random.default_rng(9)
    for _ in range(200):
        n = int(rng.integers(3, 60))
        vertices = np.stack([rng.permutation(1000)[:n], rng.integers(0, 30, n)], 1).astype(np.int64)
        walls = [rng.choice(n, int(rng.integers(2, min(8, n + 1))), replace=False).astype(np.int64)
                 for _ in range(int(rng.integers(0, 6)))]
        mesh = Mesh(vertices, np.zeros(n, np.uint8), np.zeros((0, 3), np.int64), 1000, 30, walls)
        keep = rng.random(n) < rng.random()
        got = without_vertices(mesh, keep)
        expected = _without_in_a_loop(mesh, keep)
        assert len(got.constraints) == len(expected)
        assert all(np.array_equal(a, b) for a, b in zip(got.constraints, expected))
        assert np.array_equal(got.vertices, vertices[keep])


def test_region_sampling_sums_only_the_columns_it_samples() -> None:
    """#20: sampling.sample takes each band's column sums and the cumulative sums of the
    chosen columns only, where it summed every column down the band (half its time).
    The same numbers, bit for bit: a sum over axis 0 adds the rows in turn, as the last
    row of the cumulative sums does, and a column's cumulative sums do not depend on
    the other columns. So the same samples."""
    rng = np.random.default_rng(6)
    for _ in range(300):
        h, w = int(rng.integers(1, 120)), int(rng.integers(2, 600))
        block = rng.gamma(0.5, 1.0, (h, w)) * (rng.random((h, w)) > 0.2) + 0.25 * (rng.random() > 0.5)
        whole = np.cumsum(block, axis=0)
        assert np.array_equal(block.sum(axis=0), whole[-1])
        cols = np.unique(rng.integers(0, w, int(rng.integers(1, 20))))
        assert np.array_equal(np.cumsum(block[:, cols], axis=0), whole[:, cols])
    # one column: cumsum itself
    dens = rng.gamma(0.5, 1.0, (50, 1))
    assert len(sampling.sample(dens, (1, 3), (1, 5))) > 0


def test_walls_through_vertices_are_regrouped_as_the_loop_did() -> None:
    """#20: triangulate.through_vertices (a band's sampled last row, holes' rims)
    regroups the cut steps into walls all at once; a loop over a 2048² band's walls took
    16 ms. The same walls, in the same order."""
    from codec.mesh import segments
    from codec.triangulate import split_at_vertices, through_vertices

    rng = np.random.default_rng(10)
    for _ in range(100):
        n = int(rng.integers(2, 40))
        xy = rng.choice(20 * 20, n, replace=False)
        vertices = np.stack([xy % 20, xy // 20], 1).astype(np.int64)
        walls = [rng.choice(n, int(rng.integers(2, min(6, n + 1))), replace=False).astype(np.int64)
                 for _ in range(int(rng.integers(0, 5)))]
        # vertices put on the walls' steps, so that they are cut
        for wall in walls[:2]:
            a, b = vertices[wall[0]], vertices[wall[1]]
            middle = (a + b) // 2
            if (2 * middle == a + b).all() and not (vertices == middle).all(axis=1).any():
                vertices = np.vstack([vertices, middle])
        got = through_vertices(vertices, walls)
        expected = []
        if walls:
            pieces, source = split_at_vertices(vertices, segments(walls), int(vertices[:, 0].max()) + 1, origin=True)
            owner = np.repeat(np.arange(len(walls)), [len(c) - 1 for c in walls])[source]
            for run in np.split(np.arange(len(pieces)), np.flatnonzero(np.diff(owner)) + 1):
                if len(run):
                    expected.append(np.append(pieces[run, 0], pieces[run[-1], 1]))
        assert len(got) == len(expected)
        assert all(np.array_equal(a, b) for a, b in zip(got, expected))


def test_without_vertices_takes_empty_polylines():
    """An empty polyline keeps nothing; the vectorised runs indexed past the end on it
    (IndexError) where the loop it replaced skipped it."""
    from codec.mesh import Mesh, without_vertices

    v = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    empty = np.array([], np.int64)
    for walls in ([np.array([0, 1, 3]), empty], [empty], [empty, np.array([0, 1, 3]), empty]):
        mesh = Mesh(v, np.zeros(4, np.uint8), np.zeros((0, 3), np.int64), 2, 2, walls, None)
        kept = without_vertices(mesh, np.array([1, 1, 0, 1], bool))
        assert [c.tolist() for c in kept.constraints] == ([[0, 1, 2]] if len(walls) > 1 else [])


def _inverse_cdf(cum, lo, hi, k):
    """sampling's inverse-CDF step as numpy computed it before codec._gradients.tile_samples."""
    k = np.broadcast_to(np.asarray(k, dtype=np.int64), lo.shape)
    base = np.where(lo > 0, cum[np.maximum(lo - 1, 0)], 0.0)
    total = cum[hi - 1] - base
    which = np.repeat(np.arange(len(lo)), k)
    j = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    targets = base[which] + (j + 0.5) / k[which] * total[which]
    pos = np.searchsorted(cum, targets, side="left")
    return which, np.clip(pos, lo[which], hi[which] - 1)


def _numpy_sample(dens, tiles, per_tile):
    """sampling.sample as numpy computed it, tile row by tile row."""
    h, w = dens.shape
    nh, nv = min(tiles[0], w), min(tiles[1], h)
    r, z = per_tile
    xb = np.round(np.linspace(0, w, nh + 1)).astype(np.int64)
    yb = np.round(np.linspace(0, h, nv + 1)).astype(np.int64)
    out = []
    for y0, y1 in zip(yb[:-1], yb[1:]):
        block = dens[y0:y1]
        colsum = block.sum(axis=0) if block.shape[1] > 1 else np.cumsum(block, axis=0)[-1]
        _, cols = _inverse_cdf(np.cumsum(colsum), xb[:-1], xb[1:], r)
        cols = cols[colsum[cols] > 0]
        if len(cols) == 0:
            continue
        cols, mult = np.unique(cols, return_counts=True)
        height = y1 - y0
        col_cum = np.cumsum(block[:, cols], axis=0).T
        offset = np.cumsum(np.concatenate([[0.0], col_cum[:-1, -1] + 1.0]))
        lo = np.arange(len(cols)) * height
        which, pos = _inverse_cdf((col_cum + offset[:, None]).ravel(), lo, lo + height, mult * z)
        out.append(np.stack([cols[which], pos - lo[which] + y0], axis=1))
    if not out:
        return np.zeros((0, 2), np.int64)
    pts = np.concatenate(out)
    pts = pts[dens[pts[:, 1], pts[:, 0]] > 0]
    key = np.unique(pts[:, 1] * w + pts[:, 0])
    return np.stack([key % w, key // w], axis=1).astype(np.int64)


def test_region_sampling_in_one_compiled_pass_picks_the_numpy_pixels(corpus) -> None:
    """#20: sampling.sample's tile rows in one compiled pass (codec._gradients.tile_samples)
    give the pixels the numpy code gave: random densities with empty patches, one-column
    and one-row images, many samples per tile, and the density of a corpus image."""
    rng = np.random.default_rng(11)
    cases = []
    for _ in range(200):
        h, w = int(rng.integers(1, 90)), int(rng.integers(1, 200))
        dens = rng.gamma(0.5, 1.0, (h, w)) * (rng.random((h, w)) > 0.3) + 0.25 * (rng.random() > 0.5)
        if rng.random() < 0.2:
            dens[:, : w // 2] = 0.0
        tiles = (int(rng.integers(1, 9)), int(rng.integers(1, 9)))
        cases.append((dens, tiles, (int(rng.integers(1, 12)), int(rng.integers(1, 30)))))
    gray = corpus["camera"].astype(np.float32)
    found, _, _ = edges.detect(gray, 255.0)
    cases.append((sampling.density(sampling.curvature(gray), found), (6, 6), (9, 22)))
    for dens, tiles, per_tile in cases:
        assert np.array_equal(sampling.sample(dens, tiles, per_tile), _numpy_sample(dens, tiles, per_tile))


def test_tile_sampling_refuses_bounds_that_do_not_tile_the_image() -> None:
    from codec import native

    dens = np.ones((4, 6))
    for xb, yb in (([0, 3, 5], [0, 4]), ([0, 3, 3, 6], [0, 4]), ([0, 6], [1, 4]), ([0], [0, 4])):
        with pytest.raises(ValueError, match="tile"):
            native._gradients.tile_samples(dens, np.array(xb, np.int64), np.array(yb, np.int64), 1, 1)
    with pytest.raises(ValueError, match="r and z"):
        native._gradients.tile_samples(dens, np.array([0, 6], np.int64), np.array([0, 4], np.int64), 0, 1)


def test_reordered_polylines_keep_their_points_together() -> None:
    """Polylines.take (adaptive._reorder before it) gathers each polyline's points in
    the new order without a Python loop: the same points as one arange per polyline,
    including empty orders; its pixels by polyline in the new order, as a stable sort
    of their new polyline numbers gave them."""
    rng = np.random.default_rng(2)
    for count in (0, 1, 7, 60):
        sizes = rng.integers(2, 9, count)
        starts = np.r_[0, np.cumsum(sizes)].astype(np.int64)
        points = rng.integers(0, 100, (int(starts[-1]), 2))
        pixel_line = rng.integers(0, max(count, 1), 3 * count)
        lines = polylines.Polylines(points, starts, rng.integers(0, 100, (3 * count, 2)), pixel_line, rng.random(count))
        order = rng.permutation(count)
        got = lines.take(order)
        want = np.concatenate([points[starts[k] : starts[k + 1]] for k in order]) if count else points[:0]
        assert np.array_equal(got.points, want)
        assert np.array_equal(got.starts, np.r_[0, np.cumsum(sizes[order])])
        new_of_old = np.empty(count, np.int64)
        new_of_old[order] = np.arange(count)
        px_order = np.argsort(new_of_old[pixel_line], kind="stable")
        assert np.array_equal(got.pixels, lines.pixels[px_order])
        assert np.array_equal(got.pixel_line, new_of_old[pixel_line][px_order])
        assert np.array_equal(got.strength, lines.strength[order])


def _numpy_opposite_points(lines, gray, reach=3, min_step=4.0):
    """unfold.opposite_points as numpy computed it before codec._polylines.opposite_feet."""
    h, w = gray.shape
    p = lines.points.astype(np.int64)
    _, normal = unfold._directions(lines)
    steps = np.arange(1, reach + 1, dtype=np.float64)
    sides = []
    for sign in (1.0, -1.0):
        q = np.rint(p[:, None, :] + sign * steps[None, :, None] * normal[:, None, :]).astype(np.int64)
        q[..., 0] = np.clip(q[..., 0], 0, w - 1)
        q[..., 1] = np.clip(q[..., 1], 0, h - 1)
        change = np.abs(gray[q[..., 1], q[..., 0]] - gray[p[:, 1], p[:, 0]][:, None])
        change[(q == p[:, None, :]).all(axis=2)] = -1.0
        limit = np.maximum(0.5 * change.max(axis=1), min_step)
        hit = change >= limit[:, None]
        sides.append((q, change, np.where(hit.any(axis=1), np.argmax(hit, axis=1), reach)))
    (qa, ca, fa), (qb, cb, fb) = sides
    rows = np.arange(len(p))
    take_a = (fa < fb) | ((fa == fb) & (ca[rows, np.minimum(fa, reach - 1)] >= cb[rows, np.minimum(fb, reach - 1)]))
    none = (fa == reach) & (fb == reach)
    take_a = np.where(none, ca[:, 0] >= cb[:, 0], take_a)
    ia = np.where(none, 0, np.minimum(fa, reach - 1))
    ib = np.where(none, 0, np.minimum(fb, reach - 1))
    opp = np.where(take_a[:, None], qa[rows, ia], qb[rows, ib])
    rel = opp - p
    on_left = rel[:, 0] * normal[:, 0] + rel[:, 1] * normal[:, 1] > 0
    return np.where(on_left[:, None], opp, p), np.where(on_left[:, None], p, opp)


def test_opposite_points_in_one_compiled_pass_are_the_numpy_ones(corpus) -> None:
    """#20: unfold.opposite_points (codec._polylines.opposite_feet) finds the feet the
    numpy code found: random polylines over random float32 and float64 images and flat
    ones (ties), points on the border (clipped steps), other reaches and steps, and
    camera's own polylines."""
    rng = np.random.default_rng(12)
    cases = []
    for _ in range(150):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        gray = (rng.random((h, w)) * rng.choice([1, 20, 255])).astype(rng.choice([np.float32, np.float64]))
        if rng.random() < 0.2:
            gray = np.round(gray / 50) * 50  # plateaus: equal changes
        sizes = rng.integers(2, 8, int(rng.integers(1, 6)))
        points = np.stack([rng.integers(0, w, sizes.sum()), rng.integers(0, h, sizes.sum())], 1)
        lines = polylines.Polylines(points, np.r_[0, np.cumsum(sizes)], points, np.zeros(len(points), np.int64),
                                    np.ones(len(sizes)))
        cases.append((lines, gray, int(rng.integers(1, 6)), float(rng.choice([0.1, 4.0, 30.0]))))
    gray = corpus["camera"].astype(np.float32)
    found, mag, _ = edges.detect(gray, 255.0)
    cases.append((polylines.trace(found, mag), gray, 3, 4.0))
    for lines, gray, reach, step in cases:
        got = unfold.opposite_points(lines, gray, reach=reach, min_step=step)
        want = _numpy_opposite_points(lines, gray, reach, step)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_opposite_feet_refuses_points_outside_the_image() -> None:
    from codec import native

    gray = np.zeros((4, 5), np.float32)
    normal = np.array([[1.0, 0.0]])
    with pytest.raises(ValueError, match="outside"):
        native._polylines.opposite_feet(np.array([[5, 0]], np.int64), normal, gray, 3, 4.0)
    with pytest.raises(ValueError, match="reach"):
        native._polylines.opposite_feet(np.array([[1, 1]], np.int64), normal, gray, 0, 4.0)
    with pytest.raises(ValueError, match="64"):
        native._polylines.opposite_feet(np.array([[1, 1]], np.int64), normal, gray, 65, 4.0)


def test_8bit_planes_go_to_the_gradient_unscaled_and_untouched(corpus) -> None:
    """#20: an 8-bit image's structure plane is already on the 255 scale, so
    edges.gradient blurs it as it is (its product by 1 was a copy): the same numbers
    as through the product, and the plane is left as it was."""
    import cv2

    from codec.image import structure

    gray = structure(corpus["camera"])
    before = gray.copy()
    mag, ix, iy = edges.gradient(gray, 255.0)
    assert np.array_equal(gray, before)
    g = cv2.GaussianBlur(np.multiply(gray, np.float32(1.0), dtype=np.float32), (0, 0), edges.SIGMA,
                         borderType=cv2.BORDER_REPLICATE)
    sx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    sy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    for a, b in zip((mag, ix, iy), _gradients_of(sx, sy)):
        assert np.array_equal(a, b)


def _gradients_of(sx: np.ndarray, sy: np.ndarray):
    from codec.native import _gradients

    return _gradients.edge_gradient(sx, sy, 32767 / edges._SCALE, edges._SCALE)


def test_the_gradient_kernel_in_blocks_gives_numpys_numbers_in_place() -> None:
    """#20: edge_gradient works in blocks (each block's inputs read before its outputs
    are written, so that the arithmetic vectorises: 0.74 -> 0.49 ms on a 741 x 500
    plane): the same numbers at every block boundary, with NaN and infinities, and with
    the magnitude written over sx's own plane."""
    from codec.native import _gradients

    rng = np.random.default_rng(12)
    limit = 32767 / edges._SCALE
    for h, w in ((1, 1), (1, 255), (1, 256), (1, 257), (3, 171), (17, 61)):
        planes = _derivative_planes(rng, h, w)
        special = rng.choice(np.array([np.nan, np.inf, -np.inf, 0.0, 9e3, -9e3], np.float32), (h, w))
        planes.append(np.where(rng.random((h, w)) < 0.3, special, planes[0]).astype(np.float32))
        for sx in planes:
            for sy in planes[::-1]:
                with np.errstate(over="ignore", invalid="ignore"):
                    dx, dy = sx / 4, sy / 4
                    mag = np.sqrt(dx * dx + dy * dy)
                    clipped = [np.clip(d, -limit, limit) * edges._SCALE for d in (dx, dy)]
                    ix, iy = (np.where(np.isnan(c), 0, np.round(c)).astype(np.int16) for c in clipped)
                into = sx.copy()
                got = _gradients.edge_gradient(into, sy, limit, edges._SCALE, out=into)
                assert got[0] is into
                assert np.array_equal(into, mag, equal_nan=True)
                assert np.array_equal(got[1], ix) and np.array_equal(got[2], iy)
