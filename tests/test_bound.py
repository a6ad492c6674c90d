"""codec._bound: refinement's kept per-pixel error (measured again only where a round
changed the mesh) and its choice of new vertices, against the decoder and the numpy
rules they replace."""

from __future__ import annotations

import math

import numpy as np
import pytest

import codec
from codec import decoder_cpu, error_bound
from codec.mesh import Mesh
from codec.native import _bound
from codec.triangulate import Triangulation, delaunay


def _random_mesh(rng, w: int, h: int, channels: int, dtype) -> Mesh:
    pts = {(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)}
    for _ in range(int(rng.integers(0, w * h // 3 + 1))):
        pts.add((int(rng.integers(w)), int(rng.integers(h))))
    v = np.array(sorted(pts, key=lambda p: (p[1], p[0])), np.int64)
    values = rng.integers(0, np.iinfo(dtype).max + 1, (len(v), channels)).astype(dtype)
    return Mesh(v, values if channels > 1 else values[:, 0], delaunay(v), w, h, [], None)


def _decoded_errors(mesh: Mesh, reference: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    c = reference.shape[1]
    sq = (decoder_cpu.render(mesh).reshape(-1, c).astype(np.float64) - reference) ** 2
    if valid is not None:
        sq[valid == 0] = 0.0
    return sq


def test_measure_gives_the_decoders_squared_errors():
    """Every pixel's squared error per channel and their largest, holes 0: exactly what
    the decoder's image gives (a triangle's closed area is measured, so edge pixels
    come from either triangle; the decoder gives them the same value)."""
    rng = np.random.default_rng(5)
    for trial in range(150):
        w, h = (int(x) for x in rng.integers(2, 40, 2))
        c = 3 if trial % 3 == 0 else 1
        dtype = np.uint16 if trial % 2 else np.uint8
        mesh = _random_mesh(rng, w, h, c, dtype)
        reference = rng.integers(0, np.iinfo(dtype).max + 1, (h * w, c)).astype(np.float64)
        valid = (rng.random(h * w) < 0.8).astype(np.uint8) if trial % 4 == 1 else None
        worst, sq = np.full(h * w, -1.0), np.full((h * w, c), -1.0)
        values = np.asarray(mesh.values, np.int64).reshape(len(mesh.vertices), c)
        # the image as the kernel takes it: in its own sample type, or as float64
        given = reference.astype(dtype) if trial % 5 < 3 else reference
        measured = _bound.measure(mesh.vertices, values, mesh.triangles, None, given, valid, worst, sq, w, h)
        assert measured == len(mesh.triangles)
        want = _decoded_errors(mesh, reference, valid)
        np.testing.assert_array_equal(sq, want)
        np.testing.assert_array_equal(worst, want.max(axis=1))


def test_measuring_the_changed_triangles_keeps_every_pixel_exact():
    """After vertices are inserted and some values change, measuring only the triangles
    with a new or changed corner leaves the kept errors equal to a whole new measure:
    the unique triangulation of more vertices differs only in triangles at the new
    ones."""
    rng = np.random.default_rng(8)
    for trial in range(40):
        w, h = (int(x) for x in rng.integers(8, 50, 2))
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
        pixels = rng.permutation(w * h)[: rng.integers(10, w * h // 2)]
        pts = np.unique(np.r_[corners, np.c_[pixels % w, pixels // w]], axis=0)
        keep = rng.random(len(pts)) < 0.5
        old = np.unique(np.r_[corners, pts[keep]], axis=0)
        added = pts[~(pts[:, None] == old[None]).all(axis=2).any(axis=1)]
        tri = Triangulation(old)
        values = rng.integers(0, 65536, (len(old), 1)).astype(np.int64)
        reference = rng.integers(0, 65536, (h * w, 1)).astype(np.float64)
        worst = np.zeros(h * w)
        _bound.measure(old.astype(np.int64), values, tri.triangles(), None, reference, None, worst, None, w, h)
        tri.insert(added)
        vertices = np.r_[old, added].astype(np.int64)
        new_values = np.r_[values, rng.integers(0, 65536, (len(added), 1))].astype(np.int64)
        moved = rng.random(len(old)) < 0.1
        new_values[: len(old)][moved] = rng.integers(0, 65536, (int(moved.sum()), 1))
        changed = np.r_[moved, np.ones(len(added), bool)].astype(np.uint8)
        triangles = tri.triangles()
        measured = _bound.measure(vertices, new_values, triangles, changed, reference, None, worst, None, w, h)
        assert measured == int(changed[triangles].any(axis=1).sum())
        want = np.zeros(h * w)
        _bound.measure(vertices, new_values, triangles, None, reference, None, want, None, w, h)
        np.testing.assert_array_equal(worst, want)



def _random_case(rng, trial: int, channels: tuple[int, ...]):
    """(w, h, c, dtype, the corners and some pixels, a part of them with the corners,
    samples H*W x C, valid or None) for a kept-error test."""
    w, h = (int(x) for x in rng.integers(4, 45, 2))
    c = channels[trial % len(channels)]
    dtype = np.uint16 if trial % 2 else np.uint8
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    pixels = rng.permutation(w * h)[: rng.integers(4, w * h // 2)]
    pts = np.unique(np.r_[corners, np.c_[pixels % w, pixels // w]], axis=0)
    old = np.unique(np.r_[corners, pts[rng.random(len(pts)) < 0.5]], axis=0)
    reference = rng.integers(0, np.iinfo(dtype).max + 1, (h * w, c)).astype(dtype)
    valid = (rng.random(h * w) < 0.8).astype(np.uint8) if trial % 4 == 1 else None
    return w, h, c, dtype, pts, old, reference, valid


def test_the_kept_row_sums_are_the_errors_sums_round_after_round():
    """rows (H x C) holds each row's sum of the kept squared errors per channel, through
    whole measures and measures of the changed triangles only (a pixel on an edge two
    measured triangles share is counted once), holes 0, gray (worst only) and colour."""
    rng = np.random.default_rng(11)
    for trial in range(60):
        w, h, c, dtype, pts, old, reference, valid = _random_case(rng, trial, (1, 3, 4))
        top = np.iinfo(dtype).max + 1
        added = pts[~(pts[:, None] == old[None]).all(axis=2).any(axis=1)]
        worst, rows = np.zeros(h * w), np.zeros((h, c), np.int64)
        sq = np.zeros((h * w, c)) if c > 1 else None
        tri = Triangulation(old)
        values = rng.integers(0, top, (len(old), c)).astype(np.int64)
        _bound.measure(old.astype(np.int64), values, tri.triangles(), None, reference, valid, worst, sq, w, h, rows)
        kept = worst[:, None] if sq is None else sq
        np.testing.assert_array_equal(rows, kept.reshape(h, w, c).sum(axis=1))
        tri.insert(added)
        vertices = np.r_[old, added].astype(np.int64)
        values = np.r_[values, rng.integers(0, top, (len(added), c))].astype(np.int64)
        moved = rng.random(len(old)) < 0.2
        values[: len(old)][moved] = rng.integers(0, top, (int(moved.sum()), c))
        changed = np.r_[moved, np.ones(len(added), bool)].astype(np.uint8)
        _bound.measure(vertices, values, tri.triangles(), changed, reference, valid, worst, sq, w, h, rows)
        stored = values.astype(dtype)
        want = _decoded_errors(Mesh(vertices, stored if c > 1 else stored[:, 0], tri.triangles(), w, h, [], None),
                               reference.astype(np.float64), valid)
        np.testing.assert_array_equal(rows, want.reshape(h, w, c).sum(axis=1))




def test_the_decoded_store_keeps_the_sums_the_errors_keep():
    """With `decoded` (the pixels' decoded values, the samples until measured) in place
    of `sq`, the row sums and the largest errors stay those of the kept errors round
    after round, and `decoded` is the decoder's image where measured."""
    rng = np.random.default_rng(17)
    for trial in range(60):
        w, h, c, dtype, _, old, reference, valid = _random_case(rng, trial, (3, 4, 1))
        top = np.iinfo(dtype).max + 1
        kept = dict(worst=np.zeros(h * w), rows=np.zeros((h, c), np.int64), sq=np.zeros((h * w, c)))
        store = dict(worst=np.zeros(h * w), rows=np.zeros((h, c), np.int64), decoded=reference.copy())
        tri = Triangulation(old)
        vertices = old.astype(np.int64)
        values = rng.integers(0, top, (len(old), c)).astype(np.int64)
        changed = None
        for _ in range(3):
            for state in (kept, store):
                _bound.measure(vertices, values, tri.triangles(), changed, reference, valid, state["worst"],
                               state.get("sq"), w, h, state["rows"], state.get("decoded"))
            np.testing.assert_array_equal(store["worst"], kept["worst"])
            np.testing.assert_array_equal(store["rows"], kept["rows"])
            mesh = Mesh(vertices, (values if c > 1 else values[:, 0]).astype(dtype), tri.triangles(), w, h, [], None)
            np.testing.assert_array_equal(store["decoded"], decoder_cpu.render(mesh).reshape(h * w, c))
            added = np.unique(np.c_[rng.integers(0, w, 5), rng.integers(0, h, 5)], axis=0)
            added = added[~(added[:, None] == vertices[None]).all(axis=2).any(axis=1)]
            tri.insert(added)
            moved = rng.random(len(vertices)) < 0.2
            values = np.r_[values, rng.integers(0, top, (len(added), c))].astype(np.int64)
            values[: len(vertices)][moved] = rng.integers(0, top, (int(moved.sum()), c))
            changed = np.r_[moved, np.ones(len(added), bool)].astype(np.uint8)
            vertices = np.r_[vertices, added].astype(np.int64)


def test_measure_does_not_depend_on_the_triangles_order():
    """The kernel measures the triangles by their top row, not as listed: any order of
    the list, corners rotated or not, gives the same errors and row sums (a pixel two
    triangles share gets the same value from either)."""
    rng = np.random.default_rng(21)
    for trial in range(40):
        w, h = (int(x) for x in rng.integers(3, 60, 2))
        c = (1, 3)[trial % 2]
        mesh = _random_mesh(rng, w, h, c, np.uint8)
        values = np.asarray(mesh.values, np.int64).reshape(len(mesh.vertices), c)
        reference = rng.integers(0, 256, (h * w, c)).astype(np.uint8)
        got = []
        for order in (np.arange(len(mesh.triangles)), rng.permutation(len(mesh.triangles))):
            triangles = np.roll(mesh.triangles[order], int(rng.integers(3)), axis=1)
            worst, rows = np.zeros(h * w), np.zeros((h, c), np.int64)
            sq = np.zeros((h * w, c)) if c > 1 else None
            _bound.measure(mesh.vertices, values, np.ascontiguousarray(triangles), None, reference, None,
                           worst, sq, w, h, rows)
            got.append((worst, sq, rows))
        for a, b in zip(*got):
            np.testing.assert_array_equal(a, b)


def test_refinement_tests_rms_on_the_errors_sums(monkeypatch):
    """The RMS test of every round reads the same per channel sums from the kept rows
    as from adding every kept error, for colour and gray, one band and several."""
    rng = np.random.default_rng(4)
    totals = []
    real = error_bound._Errors.total

    def total(self, rows):
        got = real(self, rows)
        totals.append(1)
        np.testing.assert_array_equal(got, self.per_channel()[rows].sum(axis=(0, 1)))
        return got

    image = np.clip(rng.normal(128, 40, (70, 90, 3)).cumsum(axis=1) / 9, 0, 255).astype(np.uint8)
    monkeypatch.setattr(error_bound._Errors, "total", total)
    for img, options in ((image, {}), (image[:, :, 0], {}), (image, {"band_height": 24})):
        out = codec.decode(codec.encode(img, quality=60, **options))
        assert out.shape == img.shape
    assert len(totals) > 10


def _numpy_spread(score: np.ndarray, count: int) -> np.ndarray:
    """The per-cell choice refinement made in numpy before: the highest positive score
    of each cell of a grid of about `count` cells, the first in the cell's raster order
    among equals (np.argmax), cells in raster order."""
    h, w = score.shape
    cell = max(1, int(math.sqrt(h * w / max(count, 1))))
    ph, pw = -(-h // cell) * cell, -(-w // cell) * cell
    padded = np.zeros((ph, pw))
    padded[:h, :w] = score
    blocks = padded.reshape(ph // cell, cell, pw // cell, cell).transpose(0, 2, 1, 3).reshape(-1, cell * cell)
    best = blocks.argmax(axis=1)
    keep = blocks[np.arange(len(blocks)), best] > 0
    cells = np.flatnonzero(keep)
    by, bx = np.divmod(cells, pw // cell)
    oy, ox = np.divmod(best[keep], cell)
    return np.stack([bx * cell + ox, by * cell + oy], 1).astype(np.int64)


def test_spread_and_count_choose_as_the_numpy_rule():
    """spread() takes per cell the pixel np.argmax took (ties included: the errors are
    small whole numbers), of the candidates: over their row's limit (pinned rows: never),
    no vertex, off the walls unless told; count() counts what refinement tested."""
    rng = np.random.default_rng(2)
    for trial in range(60):
        h, w = (int(x) for x in rng.integers(1, 70, 2))
        worst = rng.integers(0, 5, (h, w)).astype(np.float64)
        is_vertex = (rng.random((h, w)) < 0.2).astype(np.uint8)
        walls = (rng.random((h, w)) < 0.1).astype(np.uint8) if trial % 2 else None
        row_limit = np.where(rng.random(h) < 0.2, 0.5, 1.0 + 1e-9)
        row_limit[: int(rng.integers(0, 3))] = np.inf
        over_limit = 2.0
        bad = worst > row_limit[:, None]
        wall = np.zeros((h, w), bool) if walls is None else walls.astype(bool)
        candidates = bad & ~is_vertex.astype(bool) & ~wall
        assert _bound.count(worst, row_limit, over_limit, is_vertex, walls) == (
            int((worst > over_limit).sum()), int(bad.sum()), int(candidates.sum()),
            int((bad & wall & ~is_vertex.astype(bool)).sum()))
        count = int(rng.integers(1, h * w + 5))
        cell = max(1, int(math.sqrt(h * w / max(count, 1))))
        np.testing.assert_array_equal(_bound.spread(worst, row_limit, is_vertex, walls, cell),
                                      _numpy_spread(np.where(candidates, worst, 0.0), count))


def test_the_kernels_refuse_what_does_not_fit():
    v = np.array([[0, 0], [3, 0], [0, 3]], np.int64)
    values = np.zeros((3, 1), np.int64)
    reference, worst = np.zeros((16, 1)), np.zeros(16)
    with pytest.raises(ValueError, match="corner index"):
        _bound.measure(v, values, np.array([[0, 1, 3]], np.int64), None, reference, None, worst, None, 4, 4)
    with pytest.raises(ValueError, match="outside the image"):
        _bound.measure(v + 1, values, np.array([[0, 1, 2]], np.int64), None, reference, None, worst, None, 4, 4)
    with pytest.raises(ValueError, match="reference"):
        _bound.measure(v, values, np.array([[0, 1, 2]], np.int64), None, reference[:8], None, worst, None, 4, 4)
    with pytest.raises(ValueError, match="changed"):
        _bound.measure(v, values, np.array([[0, 1, 2]], np.int64), np.ones(2, np.uint8), reference, None,
                       worst, None, 4, 4)
    with pytest.raises(ValueError, match="rows H x C"):
        _bound.measure(v, values, np.array([[0, 1, 2]], np.int64), None, reference, None, worst, None, 4, 4,
                       np.zeros((4, 1), np.int64))  # float samples: no exact sums
    with pytest.raises(ValueError, match="rows H x C"):
        _bound.measure(v, values, np.array([[0, 1, 2]], np.int64), None, reference.astype(np.uint8), None,
                       worst, None, 4, 4, np.zeros((3, 1), np.int64))
    with pytest.raises(ValueError, match="samples' range"):
        _bound.measure(v, values + 256, np.array([[0, 1, 2]], np.int64), None, reference.astype(np.uint8), None,
                       worst, None, 4, 4, np.zeros((4, 1), np.int64), np.zeros((16, 1), np.uint8))
    with pytest.raises(ValueError, match="decoded H"):
        _bound.measure(v, values, np.array([[0, 1, 2]], np.int64), None, reference.astype(np.uint8), None,
                       worst, None, 4, 4, None, np.zeros((15, 1), np.uint8))
    with pytest.raises(ValueError, match="cell"):
        _bound.spread(np.zeros((4, 4)), np.zeros(4), np.zeros((4, 4), np.uint8), None, 0)
    with pytest.raises(ValueError, match="must fit"):
        _bound.count(np.zeros((4, 4)), np.zeros(3), 1.0, np.zeros((4, 4), np.uint8), None)


def test_refinement_measures_only_what_a_round_changed(monkeypatch):
    """Under max_error on a float DEM (mesh only) the first round measures every
    triangle and later rounds only those a round changed, far fewer in all than every
    triangle every round; the bound holds on the decoded image."""
    from benchmarks.speed import dem

    terrain = dem(256)
    rounds = []
    real = _bound.measure

    def measure(vertices, values, triangles, changed, *rest):
        rounds.append((len(triangles), real(vertices, values, triangles, changed, *rest)))
        return rounds[-1][1]

    monkeypatch.setattr(_bound, "measure", measure)
    out = codec.decode(codec.encode(terrain, max_error=10.0, residual=False))
    assert np.abs(out.astype(np.float64) - terrain).max() <= 10.0
    assert len(rounds) > 5 and rounds[0][0] == rounds[0][1]
    assert sum(m for _, m in rounds) < 0.5 * sum(t for t, _ in rounds)
    assert rounds[-1][1] < 0.1 * rounds[-1][0]


def test_measure_refuses_a_size_whose_pixel_count_wraps():
    """width * height = 2**64 wraps to 0 in int64: the kernel took that for a small
    image and wrote far outside its buffers (a crash); it must refuse the size."""
    from codec.native import _bound

    v = np.array([[0, 0], [3000, 0], [0, 3000]], np.int64)
    values = np.array([[1], [2], [3]], np.int64)
    t = np.array([[0, 1, 2]], np.int64)
    with pytest.raises(ValueError, match="2\\*\\*32 pixels"):
        _bound.measure(v, values, t, None, np.zeros((0, 1), np.uint8), None, np.zeros(0), None, 1 << 32, 1 << 32)
