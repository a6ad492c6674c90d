"""The encoder's front and writing kernels give exactly what the code they replace
gave: Canny and Otsu's threshold without OpenCV's thread pool (codec._gradients.canny,
.otsu_level), the chain ordering's word scan and code tables, compiled varints."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from codec import native
from codec.image import structure
from codec.mesher import adaptive, edges
from tests.corpus import load_corpus


def _cases(seed: int, count: int):
    """(ix, iy, low, high): random derivatives (small, full int16 range, and those of
    smoothed noise) with thresholds on their scale."""
    rng = np.random.default_rng(seed)
    for t in range(count):
        h, w = (int(v) for v in rng.integers(1, 48, 2))
        kind = t % 3
        if kind == 0:
            ix, iy = (rng.integers(-400, 400, (h, w)).astype(np.int16) for _ in range(2))
            scale = 300
        elif kind == 1:
            img = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 2.0)
            _, ix, iy = edges.gradient(img, 255.0)
            scale = 300
        else:
            ix, iy = (rng.integers(-32768, 32768, (h, w)).astype(np.int16) for _ in range(2))
            scale = 40000
        low, high = sorted(float(v) for v in rng.random(2) * scale)
        yield ix, iy, low, high


def test_canny_gives_opencvs_edges_on_random_derivatives():
    for ix, iy, low, high in _cases(20, 1500):
        want = cv2.Canny(ix, iy, low, high, L2gradient=True) > 0
        got = native._gradients.canny(ix, iy, low, high)
        assert got.dtype == bool and np.array_equal(got, want), (ix.shape, low, high)


@pytest.mark.parametrize("name", ["camera", "coins", "moon", "text", "astronaut", "motorcycle_disp"])
def test_detect_gives_opencvs_edges_and_threshold_on_the_corpus(name):
    gray = structure(load_corpus()[name])
    mag, ix, iy = edges.gradient(gray, 255.0)
    top = float(mag.max())
    levels = np.clip(np.multiply(mag, np.float32(255.0 / top)), 0, 255).astype(np.uint8)
    otsu, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    assert native._gradients.otsu_level(mag, np.float32(255.0 / top)) == otsu
    found, _, (low, high) = edges.detect(gray, 255.0)
    assert np.array_equal(found, cv2.Canny(ix, iy, low * 16, high * 16, L2gradient=True) > 0)
    # and with the thresholds swapped, as OpenCV swaps them
    assert np.array_equal(native._gradients.canny(ix, iy, high * 16, low * 16),
                          cv2.Canny(ix, iy, high * 16, low * 16, L2gradient=True) > 0)


def test_otsu_level_gives_opencvs_threshold_on_random_magnitudes():
    rng = np.random.default_rng(21)
    for t in range(1500):
        h, w = (int(v) for v in rng.integers(1, 64, 2))
        mag = (rng.random((h, w)) ** (1 + 3 * (t % 3))).astype(np.float32) * float(rng.random() * 100 + 1e-3)
        if t % 3 == 2:
            mag[rng.random((h, w)) < 0.5] = 0
        top = float(mag.max())
        if top <= 0:
            continue
        levels = np.clip(np.multiply(mag, np.float32(255.0 / top)), 0, 255).astype(np.uint8)
        want, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        assert native._gradients.otsu_level(mag, np.float32(255.0 / top)) == want


def test_kernels_refuse_mismatched_or_empty_planes():
    with pytest.raises(ValueError):
        native._gradients.canny(np.zeros((3, 4), np.int16), np.zeros((4, 3), np.int16), 1.0, 2.0)
    with pytest.raises(ValueError):
        native._gradients.canny(np.zeros((3, 4), np.int16), np.zeros((3, 4), np.int16), -1.0, 2.0)
    assert native._gradients.canny(np.zeros((0, 4), np.int16), np.zeros((0, 4), np.int16), 1.0, 2.0).shape == (0, 4)
    with pytest.raises(ValueError):
        native._gradients.otsu_level(np.zeros((0, 3), np.float32), np.float32(1))


@pytest.mark.parametrize("seed", range(12))
def test_order_chains_word_scan_and_code_tables_walk_as_by_hand(seed):
    """order_chains finds its pixels eight bytes at a time (any width: the tail too)
    and each pixel's two neighbours by its neighbourhood code's tables: the chains a
    walk by hand gives, on masks wider than a word and of every width modulo 8."""
    from tests.test_mesher_polylines import OFFSETS, _chains_by_hand, _simple_mask

    rng = np.random.default_rng(300 + seed)
    mask = _simple_mask(rng, int(rng.integers(20, 60)), int(rng.integers(17, 90)))
    offsets = np.array([dy * mask.shape[1] + dx for dy, dx in OFFSETS], np.int64)
    got = native._polylines.order_chains(mask.ravel().view(np.uint8), offsets)
    for a, b in zip(got, _chains_by_hand(mask)):
        assert np.array_equal(a, b)


def _varints_by_numpy(values) -> bytes:
    """codec.coding.varints as it was written in numpy (repeat, shift, mask)."""
    v = np.asarray(values, dtype=np.uint64).ravel()
    if v.size == 0:
        return b""
    nbytes = np.ones(v.size, dtype=np.int64)
    for k in range(1, 10):
        nbytes += v >= (np.uint64(1) << np.uint64(7 * k))
    rep = np.repeat(v, nbytes)
    ends = np.cumsum(nbytes)
    k = np.arange(ends[-1]) - np.repeat(ends - nbytes, nbytes)
    out = (rep >> (np.uint64(7) * k.astype(np.uint64))) & np.uint64(0x7F)
    more = k < np.repeat(nbytes - 1, nbytes)
    return (out | (more.astype(np.uint64) << np.uint64(7))).astype(np.uint8).tobytes()


def test_compiled_varints_are_the_numpy_ones():
    from codec import coding

    rng = np.random.default_rng(23)
    for t in range(1000):
        v = rng.integers(0, 2**63, int(rng.integers(0, 40)), dtype=np.uint64) >> rng.integers(0, 64, dtype=np.uint64)
        if t % 4 == 0:
            v = np.r_[v, np.array([2**64 - 1, 0, 127, 128, 2**35], np.uint64)]
        assert coding.varints(v) == _varints_by_numpy(v)
    for v in (np.arange(300, dtype=np.int64), [1, 2, 300], np.zeros((3, 2), np.int64), np.array([-1], np.int64), []):
        assert coding.varints(v) == _varints_by_numpy(v)
    assert native._samples.varints(np.zeros(0, np.uint64)) == b""


def _trace_by_numpy(edge_map, magnitude, segment_length=4, segment_error=1.0, min_pixels=3, max_pixels=None):
    """polylines.trace as it was before codec._polylines.chain_walks: the chain ends
    attached and the chains chosen and summed by numpy."""
    from codec.mesher import polylines as P

    grid = P._Grid(edge_map.astype(bool))
    junction, simple = P.thin_split(grid)
    flat_order, chain, closed = P._order_chains(simple, grid.offsets)
    offsets = grid.offsets
    nchains = int(chain.max()) + 1 if len(chain) else 0
    first = np.searchsorted(chain, np.arange(nchains), side="left")
    last = np.searchsorted(chain, np.arange(nchains), side="right") - 1

    def adjacent_junction(p):
        q = p[:, None] + offsets[None, :]
        hit = junction[q]
        return np.where(hit.any(axis=1), q[np.arange(len(p)), np.argmax(hit, axis=1)], -1)

    head = np.where(closed, -1, adjacent_junction(flat_order[first]))
    tail = np.where(closed, flat_order[first], adjacent_junction(flat_order[last]))
    hk, tk = head >= 0, tail >= 0
    pix = np.concatenate([flat_order, head[hk], tail[tk]])
    ch = np.concatenate([chain, np.flatnonzero(hk), np.flatnonzero(tk)])
    key = np.concatenate([np.arange(len(flat_order)) * 3, first[hk] * 3 - 1, last[tk] * 3 + 1])
    order = np.argsort(key, kind="stable")
    pix, ch = pix[order], ch[order]

    def unpad(p):
        return (p // grid.stride - 1) * grid.w + (p % grid.stride - 1)

    if len(pix):
        sizes = np.bincount(ch)
        wanted = sizes >= max(2, min_pixels)
        if max_pixels is not None and sizes[wanted].sum() > max_pixels:
            mean = np.bincount(ch, weights=magnitude.ravel()[unpad(pix)].astype(np.float64) ** 2) / sizes
            order = np.argsort(-np.where(wanted, mean, -1.0), kind="stable")
            fits = np.cumsum(np.where(wanted, sizes, 0)[order]) <= max_pixels
            wanted = np.zeros_like(wanted)
            wanted[order[fits]] = True
        keep = wanted[ch]
        pix, ch = pix[keep], (np.cumsum(wanted) - 1)[ch[keep]]
    xy = np.stack([pix % grid.stride - 1, pix // grid.stride - 1], axis=1).astype(np.int64)
    nchains = int(ch.max()) + 1 if len(ch) else 0
    first = np.searchsorted(ch, np.arange(nchains), side="left")
    last = np.searchsorted(ch, np.arange(nchains), side="right") - 1
    ctrl = P._control_points(xy.astype(np.float64), first, last, int(segment_length), float(segment_error))
    starts = np.concatenate([[0], np.cumsum(np.bincount(ch[ctrl], minlength=nchains))])
    strength = np.bincount(ch, weights=magnitude.ravel()[unpad(pix)].astype(np.float64) ** 2, minlength=nchains)
    return xy[ctrl], starts, xy, ch, strength


def _same_trace(edge_map, magnitude, **options):
    from codec.mesher import polylines as P

    got = P.trace(edge_map, magnitude, **options)
    want = _trace_by_numpy(edge_map, magnitude, **options)
    for a, b in zip((got.points, got.starts, got.pixels, got.pixel_line, got.strength), want):
        assert a.shape == b.shape and np.array_equal(a, b)


@pytest.mark.parametrize("seed", range(20))
def test_chain_walks_trace_as_numpy_did_on_random_edges(seed):
    rng = np.random.default_rng(400 + seed)
    h, w = (int(v) for v in rng.integers(1, 70, 2))
    edge_map = rng.random((h, w)) < rng.uniform(0.02, 0.5)
    magnitude = (rng.random((h, w)) * 50).astype(np.float32)
    for options in ({}, {"max_pixels": int(rng.integers(0, 60))}, {"min_pixels": 5, "segment_length": 2}):
        _same_trace(edge_map, magnitude, **options)


@pytest.mark.parametrize("name", ["camera", "astronaut", "motorcycle_disp"])
def test_chain_walks_trace_as_numpy_did_on_the_corpus(name):
    found, magnitude, _ = edges.detect(structure(load_corpus()[name]), 255.0)
    _same_trace(found, magnitude)
    _same_trace(found, magnitude, max_pixels=8 * int(0.3 * 0.028 * found.size))


def test_chain_walks_refuses_what_does_not_fit():
    offsets = np.array([-6, -5, -4, 1, 6, 5, 4, -1], np.int64)
    junction = np.zeros(25, np.uint8)
    mag = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="fit together"):
        native._polylines.chain_walks(np.array([6], np.int64), np.array([0], np.int64), np.zeros(1, np.uint8),
                                      junction, offsets, mag, 4)
    with pytest.raises(ValueError, match="outside the mask"):
        native._polylines.chain_walks(np.array([0], np.int64), np.array([0], np.int64), np.zeros(1, np.uint8),
                                      junction, offsets, mag, 5)
    with pytest.raises(ValueError, match="out of order"):
        native._polylines.chain_walks(np.array([6, 7], np.int64), np.array([1, 0], np.int64), np.zeros(2, np.uint8),
                                      junction, offsets, mag, 5)


def _walls_by_numpy(left, right, starts, width):
    """unfold's merge of the feet and its wall segments as numpy made them before
    codec._polylines.wall_segments."""
    n = len(left)
    points = np.concatenate([left, right])
    key = points[:, 1] * width + points[:, 0]
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    ids = rank[inverse.ravel()]
    merged = points[first[order]]
    line_of = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
    step = np.flatnonzero(line_of[1:] == line_of[:-1])
    segs = np.concatenate([np.stack([ids[step], ids[step + 1]], 1), np.stack([ids[n + step], ids[n + step + 1]], 1)])
    rank = np.concatenate([line_of[step] * 2, line_of[step] * 2 + 1])
    order = np.argsort(rank, kind="stable")
    segs, rank = segs[order], rank[order]
    real = segs[:, 0] != segs[:, 1]
    segs, rank = segs[real], rank[real]
    key = np.minimum(segs[:, 0], segs[:, 1]) * len(merged) + np.maximum(segs[:, 0], segs[:, 1])
    once = np.sort(np.unique(key, return_index=True)[1])
    return merged, segs[once], rank[once]


@pytest.mark.parametrize("seed", range(25))
def test_wall_segments_are_numpys(seed):
    rng = np.random.default_rng(500 + seed)
    w, h = (int(v) for v in rng.integers(1, 12, 2))  # small images: many feet share a pixel
    sizes = rng.integers(1, 8, int(rng.integers(1, 30)))
    starts = np.r_[0, np.cumsum(sizes)].astype(np.int64)
    n = int(starts[-1])
    left = np.stack([rng.integers(0, w, n), rng.integers(0, h, n)], 1).astype(np.int64)
    right = np.stack([rng.integers(0, w, n), rng.integers(0, h, n)], 1).astype(np.int64)
    if seed % 3 == 0:  # walls that retrace each other: segments met twice, both ways
        right = left[::-1].copy()
    got = native._polylines.wall_segments(left, right, starts, w, h)
    for a, b in zip(got, _walls_by_numpy(left, right, starts, w)):
        assert a.shape == b.shape and np.array_equal(a, b)


def test_wall_segments_refuse_what_does_not_fit():
    feet = np.zeros((3, 2), np.int64)
    with pytest.raises(ValueError, match="cover"):
        native._polylines.wall_segments(feet, feet, np.array([0, 2], np.int64), 4, 4)
    with pytest.raises(ValueError, match="cover"):
        native._polylines.wall_segments(feet, feet, np.array([0, 2, 1, 3], np.int64), 4, 4)
    with pytest.raises(ValueError, match="outside"):
        native._polylines.wall_segments(feet + [[4, 0]], feet, np.array([0, 3], np.int64), 4, 4)
    with pytest.raises(ValueError, match="fit together"):
        native._polylines.wall_segments(feet, feet[:2], np.array([0, 3], np.int64), 4, 4)
    empty = native._polylines.wall_segments(feet[:0], feet[:0], np.array([0], np.int64), 4, 4)
    assert [a.shape for a in empty] == [(0, 2), (0, 2), (0,)]


def _select_lines_by_numpy(lines, budget):
    """adaptive._select_lines as it was: Polylines.select() (the kept polylines in
    scan-line order), then _reorder by
    worth (a double argsort and a stable argsort of every pixel's polyline)."""
    from codec.mesher import polylines as P

    feet = 2 * np.diff(lines.starts)
    worth = lines.strength / np.maximum(feet, 1)
    order = np.argsort(-worth, kind="stable")
    fits = np.cumsum(feet[order]) <= budget
    keep = np.zeros(len(lines), dtype=bool)
    keep[order[fits]] = True
    sizes = np.diff(lines.starts)
    renum = np.cumsum(keep) - 1
    px_keep = keep[lines.pixel_line]
    picked = P.Polylines(lines.points[np.repeat(keep, sizes)], np.concatenate([[0], np.cumsum(sizes[keep])]),
                         lines.pixels[px_keep], renum[lines.pixel_line[px_keep]], lines.strength[keep])
    rank = np.argsort(np.argsort(-worth[keep], kind="stable"), kind="stable")
    order = np.argsort(rank, kind="stable")
    sizes = np.diff(picked.starts)
    chosen = sizes[order]
    idx = np.repeat(picked.starts[:-1][order] - (np.cumsum(chosen) - chosen), chosen) + np.arange(int(chosen.sum()))
    new_of_old = np.empty(len(order), dtype=np.int64)
    new_of_old[order] = np.arange(len(order))
    px_order = np.argsort(new_of_old[picked.pixel_line], kind="stable")
    return P.Polylines(picked.points[idx], np.concatenate([[0], np.cumsum(sizes[order])]), picked.pixels[px_order],
                       new_of_old[picked.pixel_line][px_order], picked.strength[order])


@pytest.mark.parametrize("name", ["camera", "astronaut", "motorcycle_disp", "text"])
def test_select_lines_takes_the_worthiest_as_select_and_reorder_did(name):
    from codec.mesher import polylines as P

    found, magnitude, _ = edges.detect(structure(load_corpus()[name]), 255.0)
    lines = P.trace(found, magnitude)
    for budget in (0, 10, 500, 2202, 10**9):
        got, want = adaptive._select_lines(lines, budget), _select_lines_by_numpy(lines, budget)
        for field in ("points", "starts", "pixels", "pixel_line", "strength"):
            a, b = getattr(got, field), getattr(want, field)
            assert a.shape == b.shape and np.array_equal(a, b), field


def test_a_layout_makes_its_vertex_steps_once_for_quantise_and_encode_band(monkeypatch):
    """quantise and encode_band both ask the band's Layout for its vertex steps with
    the same (step, top_pinned): made once (0.15 ms a 512² band), read-only, and the
    same bytes as fresh steps give."""
    from codec import meshcode
    from codec.mesh import Mesh

    rng = np.random.default_rng(24)
    w = h = 40
    keys = np.sort(rng.choice(w * h, 60, replace=False))
    keys = np.union1d(keys, [0, w - 1, (h - 1) * w, h * w - 1])
    vertices = np.stack([keys % w, keys // w], 1).astype(np.int64)
    from codec.triangulate import triangulate

    mesh = Mesh(vertices, rng.integers(0, 256, len(vertices)).astype(np.uint8), triangulate(vertices), w, h, [])
    mesh = meshcode.in_stored_order(mesh)
    fresh = meshcode.encode_band(0, meshcode.quantise(mesh, 5, False), 5, True)
    made = []
    real = meshcode.vertex_steps
    monkeypatch.setattr(meshcode, "vertex_steps", lambda *a, **k: made.append(1) or real(*a, **k))
    lay = meshcode.layout(mesh)
    quantised = meshcode.quantise(mesh, 5, False, lay)
    fields = meshcode.encode_band(0, quantised, 5, True, lay)
    assert len(made) == 1 and not lay.steps(5, False).flags.writeable
    assert fields == fresh


def test_profile_encode_prints_a_cpu_budget_per_stage_and_puts_the_stages_back():
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    run = subprocess.run([sys.executable, "benchmarks/profile_encode.py", "--stages", "1", "--sides", "64"],
                         cwd=root, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    rows = {line.split()[0]: [float(v) for v in line.split()[-2:]] for line in run.stdout.splitlines()[2:]}
    assert run.stdout.split()[5:7] == ["camera@64", "astronaut@64"]
    for stage in ("detect", "trace", "unfold", "refine_to_budget", "write_band", "encode_band", "compress_parts"):
        assert all(v > 0 for v in rows[stage]), stage
    sys.path.insert(0, str(root / "benchmarks"))
    try:
        import profile_encode
    finally:
        sys.path.remove(str(root / "benchmarks"))
    from codec import container
    from codec.mesher import polylines as P

    before = (P.trace, container.Writer.write_band, container.frames.compress_parts)
    with profile_encode.StageTimer():
        assert P.trace is not before[0]
    assert (P.trace, container.Writer.write_band, container.frames.compress_parts) == before


def test_chain_walks_refuses_pixels_in_the_border_columns():
    # the row bounds let the padded border's columns through: their magnitude would be
    # another pixel's, and with a width of 0 there is none (the read crashed)
    offsets = np.array([-6, -5, -4, 1, 6, 5, 4, -1], np.int64)
    for p in (9, 10):  # row 1's right and row 2's left border pixels of a 3 x 3 image (stride 5)
        with pytest.raises(ValueError, match="outside the mask"):
            native._polylines.chain_walks(np.array([p], np.int64), np.array([0], np.int64), np.zeros(1, np.uint8),
                                          np.zeros(25, np.uint8), offsets, np.zeros((3, 3), np.float32), 5)
    with pytest.raises(ValueError, match="outside the mask"):
        native._polylines.chain_walks(np.array([3], np.int64), np.array([0], np.int64), np.ones(1, np.uint8),
                                      np.zeros(10, np.uint8), np.array([-3, -2, -1, 1, 3, 2, 1, -1], np.int64),
                                      np.zeros((3, 0), np.float32), 2)


def test_density_gives_numpys_numbers_from_two_compiled_passes(corpus):
    """#20: sampling.density's numpy steps (a square root, a masked gather, a divide,
    an add and a masked store over float64 planes) were 1.5 ms of the disparity map's
    encode; _gradients.density_roots and density_scale give the same numbers (numpy
    still takes the mean, of the same values in the same order) as the numpy steps,
    which float64 curvatures still take."""
    import cv2

    from codec.mesher import edges, sampling

    rng = np.random.default_rng(8)
    for name, image in corpus.items():
        gray = structure(image if image.ndim == 2 else image[..., 0])
        found, _, _ = edges.detect(gray, 255.0)
        near = cv2.dilate(found.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        curv = sampling.curvature(gray)
        for excluded in (near, np.zeros_like(near), np.ones_like(near), rng.random(near.shape) < 0.5):
            numpy_steps = sampling.density(curv.astype(np.float64), excluded)
            assert np.array_equal(sampling.density(curv, excluded), numpy_steps), name
    zero = np.zeros((5, 9), np.float32)  # no curvature: the floor alone
    assert np.array_equal(sampling.density(zero, zero > 0), np.full((5, 9), 0.25))
    with pytest.raises(ValueError, match="differ in size"):
        native._gradients.density_roots(zero, np.zeros((5, 8), np.uint8))
    with pytest.raises(ValueError, match="differ in size"):
        native._gradients.density_scale(np.zeros((5, 9)), np.zeros((4, 9), np.uint8), 1.0, 0.25)


def test_the_front_writes_into_planes_it_owns_and_frees_them_before_refinement(monkeypatch):
    """#20: a 741 x 500 encode faulted in about 3,300 fresh pages (2 us each) as its heap
    grew past the last peak: the gradient magnitude and the Hessian's norm are written
    into a derivative's plane, the same numbers, and the front's image-sized planes
    (edges, magnitude, density) are gone before refinement makes its own."""
    import weakref

    from codec.mesher import sampling

    rng = np.random.default_rng(11)
    sx, sy, sxy = (rng.normal(0, 300, (23, 31)).astype(np.float32) for _ in range(3))
    mag, ix, iy = native._gradients.edge_gradient(sx, sy, 32767 / edges._SCALE, edges._SCALE)
    into = sx.copy()
    got = native._gradients.edge_gradient(into, sy, 32767 / edges._SCALE, edges._SCALE, out=into)
    assert got[0] is into and np.array_equal(into, mag)
    assert np.array_equal(got[1], ix) and np.array_equal(got[2], iy)
    norm = native._gradients.hessian_norm(sx, sy, sxy)
    into = sx.copy()
    assert native._gradients.hessian_norm(into, sy, sxy, out=into) is into and np.array_equal(into, norm)
    for bad in (np.zeros((23, 30), np.float32), np.zeros((23, 31)), np.zeros((31, 23), np.float32).T,
                np.zeros((23, 31), np.float32)[::-1], [[0.0] * 31] * 23):
        with pytest.raises(ValueError, match="out must be"):
            native._gradients.hessian_norm(sx, sy, sxy, out=bad)
        with pytest.raises(ValueError, match="out must be"):
            native._gradients.edge_gradient(sx, sy, 100.0, edges._SCALE, out=bad)
    frozen = np.zeros((23, 31), np.float32)
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="out must be"):
        native._gradients.hessian_norm(sx, sy, sxy, out=frozen)

    planes = []
    for module, name in ((edges, "detect"), (sampling, "density")):
        real = getattr(module, name)

        def kept(*args, _real=real, **kwargs):
            out = _real(*args, **kwargs)
            planes.extend(weakref.ref(p) for p in (out[:2] if isinstance(out, tuple) else (out,)))
            return out

        monkeypatch.setattr(module, name, kept)
    refine = adaptive.refine_to_budget
    alive = []

    def refine_to_budget(*args, **kwargs):
        alive.append(sum(p() is not None for p in planes))
        return refine(*args, **kwargs)

    monkeypatch.setattr(adaptive, "refine_to_budget", refine_to_budget)
    image = load_corpus()["camera"][:200, :240]
    adaptive.build(image, 1000)
    assert len(planes) == 3 and alive == [0]


def test_the_density_mean_is_numpys_pairwise_sum_without_the_array():
    """#20: sampling.density's mean of the free pixels' roots took an array of them (up
    to 3 MB at 741 x 500, fresh pages each encode) for numpy to sum: the kernel sums
    them as numpy's pairwise sum does (blocks of 8 running sums up to 128 values, halves
    cut at multiples of 8), read from the roots in raster order, the same bits."""
    rng = np.random.default_rng(13)
    sizes = [(1, n) for n in (1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 256, 257, 1000)]
    sizes += [(91, 90), (64, 128), (97, 211), (300, 401)]  # 8,190 .. 120,300 pixels
    for h, w in sizes:
        curv = (rng.random((h, w)) ** 3 * 1e4).astype(np.float32)
        for share in (0.0, 0.01, 0.3, 0.9, 1.0):
            excluded = rng.random((h, w)) < share
            d, mean = native._gradients.density_roots(curv, excluded.view(np.uint8))
            roots = np.sqrt(curv.astype(np.float64))
            assert np.array_equal(d, roots)
            free = roots[~excluded]
            assert mean == (free.mean() if len(free) else 0.0), (h, w, share)
    # non-finite curvatures reach the mean as numpy's would
    curv = np.array([[np.inf, 4.0, np.nan, 9.0]], np.float32)
    for keep in ([1, 1, 0, 1], [0, 1, 1, 1], [1, 1, 1, 1]):
        excluded = np.array([keep], np.uint8) == 0
        mean = native._gradients.density_roots(curv, excluded.view(np.uint8))[1]
        assert np.array_equal(mean, np.sqrt(curv.astype(np.float64))[~excluded].mean(), equal_nan=True)


def _whole_plane_gradient(gray: np.ndarray):
    """edges.gradient of an 8-bit-scale float32 plane as whole planes made it."""
    g = cv2.GaussianBlur(gray, (0, 0), edges.SIGMA, borderType=cv2.BORDER_REPLICATE)
    sx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    sy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    return native._gradients.edge_gradient(sx, sy, 32767 / edges._SCALE, edges._SCALE)


def _whole_plane_curvature(gray: np.ndarray) -> np.ndarray:
    from codec.mesher import sampling

    g = cv2.GaussianBlur(gray, (0, 0), sampling.SIGMA, borderType=cv2.BORDER_REPLICATE)
    return native._gradients.hessian_norm(*(cv2.Sobel(g, cv2.CV_32F, dx, dy, ksize=3, borderType=cv2.BORDER_REPLICATE)
                                            for dx, dy in ((2, 0), (0, 2), (1, 1))))


def test_the_filter_chains_in_strips_give_the_whole_planes_numbers(monkeypatch):
    """#20: edges.gradient and sampling.curvature smooth and differentiate a strip of
    rows at a time (codec.mesher.strips), with the rows of context their filters read:
    the same numbers as whole planes, at every strip boundary, for images shorter and
    taller than a strip, and the kernels' int16 planes checked."""
    from codec.mesher import sampling, strips

    for sigma in (edges.SIGMA, sampling.SIGMA, 0.8, 2.0, 3.3):
        # OpenCV's own kernel size for float data at this sigma: a delta's spread
        delta = np.zeros((1, 61), np.float32)
        delta[0, 30] = 1
        spread = np.flatnonzero(cv2.GaussianBlur(delta, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)[0])
        assert spread.max() - 30 == strips.gaussian_radius(sigma) == 30 - spread.min()
    assert list(strips.strips(5, 2, rows=2)) == [(0, 2, 0, 4), (2, 4, 0, 5), (4, 5, 2, 5)]
    assert [(y0, y1, len(s), k) for y0, y1, s, k in strips.smoothed(np.zeros((5, 3), np.float32), 1.0)] == [
        (0, 5, 5, slice(0, 5))]
    rng = np.random.default_rng(14)
    monkeypatch.setattr(strips, "ROWS", 7)  # many boundaries in small images
    corpus = load_corpus()
    images = [structure(corpus["motorcycle_disp"]), structure(corpus["camera"])[:40, :53]]
    images += [(rng.random((h, w)) * 255).astype(np.float32) for h, w in ((1, 9), (2, 5), (6, 11), (7, 7), (8, 30), (23, 4))]
    for rows in (7, 128):
        monkeypatch.setattr(strips, "ROWS", rows)
        for gray in images:
            for got, want in zip(edges.gradient(gray, 255.0), _whole_plane_gradient(gray)):
                assert got.dtype == want.dtype and np.array_equal(got, want), gray.shape
            assert np.array_equal(sampling.curvature(gray), _whole_plane_curvature(gray)), gray.shape
    sx = np.zeros((4, 5), np.float32)
    with pytest.raises(ValueError, match="int16"):
        native._gradients.edge_gradient(sx, sx, 100.0, edges._SCALE, ix_out=np.zeros((4, 5), np.int32))
    with pytest.raises(ValueError, match="share no memory"):
        native._gradients.edge_gradient(sx, sx, 100.0, edges._SCALE, ix_out=sx.view(np.int16).reshape(-1)[:20].reshape(4, 5))
    shared = np.zeros((4, 5), np.int16)
    with pytest.raises(ValueError, match="share no memory"):
        native._gradients.edge_gradient(sx, sx, 100.0, edges._SCALE, ix_out=shared, iy_out=shared)


def test_order_chains_finds_neighbours_without_an_image_sized_table():
    """#20: order_chains found each chain pixel's neighbours' places through a table as
    large as the padded image (int64: 3 MB at 741 x 500, read at random, its pages
    faulted in each encode); a ring of slots ahead of the pixel read does, the same
    chains, with memory in proportion to the chain pixels and the row length."""
    import tracemalloc

    from tests.test_mesher_polylines import OFFSETS, _chains_by_hand, _simple_mask

    rng = np.random.default_rng(31)
    sparse = np.zeros((900, 1100), bool)
    sparse[200:262, 300:422] = _simple_mask(rng, 60, 120)
    for mask in (sparse, _simple_mask(rng, 37, 1000), _simple_mask(rng, 300, 9)):
        offsets = np.array([dy * mask.shape[1] + dx for dy, dx in OFFSETS], np.int64)
        flat = mask.ravel().view(np.uint8)
        tracemalloc.start()
        got = native._polylines.order_chains(flat, offsets)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        for a, b in zip(got, _chains_by_hand(mask)):
            assert np.array_equal(a, b)
        assert peak < 200 * int(mask.sum()) + 64 * mask.shape[1] + 65536, (mask.shape, peak)


def test_otsu_level_in_four_histograms_gives_opencvs_threshold_on_wide_flat_rows():
    """#20: otsu_level counts its histogram in four parts, the levels of up to 256
    pixels of a row at a time (a flat region's run of one level made each count wait
    for the one before): OpenCV's threshold still, on rows wider than a block, of every
    width modulo 4, mostly at one level."""
    rng = np.random.default_rng(41)
    for w in (1, 3, 255, 256, 257, 258, 259, 741, 1030):
        h = int(rng.integers(1, 9))
        mag = np.zeros((h, w), np.float32)
        some = rng.random((h, w)) < 0.2
        mag[some] = (rng.random(int(some.sum())) * 40).astype(np.float32)
        mag[0, -1] = 41.0
        top = float(mag.max())
        levels = np.clip(np.multiply(mag, np.float32(255.0 / top)), 0, 255).astype(np.uint8)
        want, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        assert native._gradients.otsu_level(mag, np.float32(255.0 / top)) == want, w
