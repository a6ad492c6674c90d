"""The two decoders (CPU scanline, OpenGL z-buffer) against the normative rule and
against each other: on random, sliver and walled meshes, tiny and odd sizes, and the
public corpus. In CI (CI set) the GL tests fail when no context can be made; locally
they are skipped."""

from __future__ import annotations

import contextlib
import importlib

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import codec
from codec import decoder_cpu, decoder_gl
from codec.errors import BackendError, CorruptError
from codec.mesh import Mesh, doubled_areas, orient, validate
from codec.triangulate import triangulate


def reference(mesh: Mesh, chunk: int = 1 << 16) -> np.ndarray:
    """The normative rule by brute force: every pixel against every triangle (meshes
    of few triangles only; pixels a chunk at a time), the value from any triangle that
    contains the pixel centre."""
    if len(mesh.triangles) == 0:
        return decoder_cpu.render_line(mesh)
    w, h, c = mesh.width, mesh.height, mesh.channels
    v = mesh.vertices.astype(np.int64)
    t = mesh.triangles
    vals = mesh.values.astype(np.int64).reshape(len(v), c)
    px, py = v[t, 0], v[t, 1]  # M x 3
    out = np.empty((w * h, c), np.int64)
    for start in range(0, w * h, chunk):
        pix = np.arange(start, min(start + chunk, w * h))
        y, x = np.divmod(pix, w)
        wts = []
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            wts.append((px[:, k] - px[:, j])[:, None] * (y[None, :] - py[:, j][:, None])
                       - (py[:, k] - py[:, j])[:, None] * (x[None, :] - px[:, j][:, None]))
        inside = (wts[0] >= 0) & (wts[1] >= 0) & (wts[2] >= 0)  # M x P
        assert inside.any(axis=0).all(), "reference: a pixel lies in no triangle"
        tri = inside.argmax(axis=0)
        at = np.arange(len(pix))
        ws = [wi[tri, at] for wi in wts]
        den = (ws[0] + ws[1] + ws[2])[:, None]
        num = sum(ws[i][:, None] * vals[t[tri, i]] for i in range(3))
        out[pix] = (2 * num + den) // (2 * den)
    out = out.astype(mesh.dtype)
    return out.reshape(h, w) if c == 1 else out.reshape(h, w, c)


def agreement(a: np.ndarray, b: np.ndarray) -> tuple[int, float]:
    """(max |a - b|, share of identical samples)."""
    diff = np.abs(a.astype(np.int64) - b.astype(np.int64))
    return int(diff.max()), float((diff == 0).mean())


# ---------------------------------------------------------------- mesh strategies

def _values(draw, n: int, dtype, channels: int) -> np.ndarray:
    top = int(np.iinfo(dtype).max)
    shape = (n,) if channels == 1 else (n, channels)
    seed = draw(st.integers(0, 2**32 - 1))
    return np.random.default_rng(seed).integers(0, top + 1, shape).astype(dtype)


def _corners(w: int, h: int) -> list[tuple[int, int]]:
    return [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)]


@st.composite
def meshes(draw) -> Mesh:
    """Valid meshes that stress the decoders' edge cases."""
    kind = draw(st.sampled_from(["random", "sliver", "walls", "line", "tiny", "wide"]))
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    channels = draw(st.sampled_from([1, 3]))
    if kind == "line":
        n = draw(st.integers(1, 60))
        w, h = draw(st.sampled_from([(1, n), (n, 1)]))
    elif kind == "tiny":
        w, h = draw(st.sampled_from([(2, 2), (2, 3), (3, 2), (2, 17), (13, 2)]))
    elif kind == "wide":
        # a few pixels across and tens of thousands along: triangles reach far beyond
        # any GL tile and viewport, where the rasteriser's clipping is inexact
        across, length = draw(st.integers(2, 6)), draw(st.integers(2049, 70000))
        w, h = draw(st.sampled_from([(across, length), (length, across)]))
    else:
        w, h = draw(st.integers(2, 41)), draw(st.integers(2, 41))
    pts = set(_corners(w, h))
    walls: list[list[tuple[int, int]]] = []
    if kind in ("random", "tiny", "line", "wide"):
        for _ in range(min(draw(st.integers(0, w * h)), 12 if kind == "wide" else 60)):
            pts.add((draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1))))
    elif kind == "sliver":
        # points on long, nearly flat lines give triangles thinner than a pixel
        vertical = draw(st.booleans())
        length, across = (h, w) if vertical else (w, h)
        for _ in range(draw(st.integers(1, 3))):
            b0, b1 = draw(st.integers(0, across - 1)), draw(st.integers(0, across - 1))
            for a in range(0, length, draw(st.integers(1, 4))):
                b = int(round(b0 + (b1 - b0) * a / max(length - 1, 1)))
                pts.add((b, a) if vertical else (a, b))
    else:
        # pairs of constraint polylines one pixel apart (walls), horizontal or vertical
        vertical = draw(st.booleans())
        length, across = (h, w) if vertical else (w, h)
        step = draw(st.integers(1, 5))
        along = sorted(set(range(0, length, step)) | {length - 1})
        zig = int(across >= 4 and draw(st.booleans()))
        bases = draw(st.lists(st.integers(0, across - 2 - zig), min_size=1, max_size=2, unique=True))
        for base in bases:
            for off in (0, 1):
                line = [(a, base + off + zig * (i % 2)) for i, a in enumerate(along)]
                line = [(b, a) for a, b in line] if vertical else line
                pts.update(line)
                walls.append(line)
    vertices = np.array(sorted(pts), dtype=np.int64)
    index = {tuple(p): i for i, p in enumerate(vertices.tolist())}
    segs = [(index[a], index[b]) for line in walls for a, b in zip(line, line[1:])]
    try:
        triangles = triangulate(vertices, np.array(segs) if segs else None)
    except codec.ATMError:
        triangles = triangulate(vertices)  # two walls crossed each other: drop them
    values = _values(draw, len(vertices), dtype, channels)
    for i, line in enumerate(walls):  # a steep step across each wall
        values[[index[p] for p in line]] = np.iinfo(dtype).max if i % 2 == 0 else 0
    mesh = Mesh(vertices, values, triangles, w, h)
    validate(mesh)
    return mesh


# ---------------------------------------------------------------- CPU decoder

@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes())
def test_cpu_matches_normative_rule(mesh: Mesh) -> None:
    expected = reference(mesh)
    assert np.array_equal(decoder_cpu.render(mesh), expected)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes())
def test_cpu_takes_either_orientation(mesh: Mesh) -> None:
    """Triangles listed clockwise or counter-clockwise give the same pixels (the kernel
    negates the plane and D together)."""
    if len(mesh.triangles) == 0:
        return
    mirrored = Mesh(mesh.vertices, mesh.values, mesh.triangles[:, ::-1].copy(), mesh.width,
                    mesh.height)
    assert np.array_equal(decoder_cpu.render(mirrored), decoder_cpu.render(mesh))


def test_cpu_extreme_samples_and_a_wide_image() -> None:
    """Full-scale 16-bit ramps on a long, thin image: the largest planes the kernel's
    int64 arithmetic meets at this size, against the brute-force rule."""
    w, h = 4001, 3
    vertices = np.array(_corners(w, h) + [(2000, 1), (1, 1), (3999, 1)])
    values = np.array([0, 65535, 65535, 0, 65535, 0, 65535], np.uint16)
    mesh = Mesh(vertices, values, triangulate(vertices), w, h)
    validate(mesh)
    assert np.array_equal(decoder_cpu.render(mesh), reference(mesh))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes(), st.integers(0, 2**32 - 1))
def test_cpu_vertex_order_does_not_matter(mesh: Mesh, seed: int) -> None:
    """Decoded meshes number their vertices in raster order; others are renumbered."""
    if len(mesh.triangles) == 0:
        return
    perm = np.random.default_rng(seed).permutation(len(mesh.vertices))
    inverse = np.argsort(perm)
    shuffled = Mesh(mesh.vertices[perm], mesh.values[perm], inverse[mesh.triangles],
                    mesh.width, mesh.height)
    assert np.array_equal(decoder_cpu.render(shuffled), decoder_cpu.render(mesh))


def test_cpu_threads() -> None:
    """Renders of different meshes in parallel threads (the kernel runs without the
    GIL, on buffers each call owns) give the pixels of the normative rule."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(11)
    sizes = ((37, 61), (80, 23), (16, 300))
    imgs = [rng.integers(0, 256, (h, w)).astype(np.uint8) for h, w in sizes]
    meshes = [codec.build_mesh(img) for img in imgs] + [codec.build_mesh(imgs[0].astype(np.uint16) * 257)]
    expected = [reference(m) for m in meshes]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(decoder_cpu.render, meshes * 6))
    assert all(np.array_equal(g, e) for g, e in zip(got, expected * 6))


def test_two_threads_decode_different_files_as_one_does(corpus) -> None:
    """codec.decode of different files in two threads at once: the same pixels as
    decoding each alone."""
    from concurrent.futures import ThreadPoolExecutor

    files = [codec.encode(corpus[name]) for name in ("camera", "coins", "text", "motorcycle_disp")]
    alone = [codec.decode(f) for f in files]
    with ThreadPoolExecutor(2) as pool:
        together = list(pool.map(codec.decode, files * 3))
    assert all(np.array_equal(t, a) for t, a in zip(together, alone * 3))


def test_cpu_refuses_indices_outside_the_mesh() -> None:
    """A mesh that skipped validation cannot make the kernel read or write out of
    bounds: vertices outside the image and triangle corners beyond the vertices are
    refused (the kernel checks every index it reads)."""
    m = _grid_mesh()
    outside = m.vertices.copy()
    outside[-1] = (m.width + 5, m.height - 1)
    with pytest.raises(CorruptError, match="outside the 9x7 image"):
        decoder_cpu.render(Mesh(outside, m.values, m.triangles, m.width, m.height))
    for bad in (len(m.vertices), -1, 1 << 40):
        tris = m.triangles.copy()
        tris[3, 1] = bad
        with pytest.raises(CorruptError, match="beyond the"):
            decoder_cpu.render(Mesh(m.vertices, m.values, tris, m.width, m.height))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes())
def test_cpu_tiles_path_matches_normative_rule(mesh: Mesh) -> None:
    """render(tiles=True), what a decode runs on a file's validated bands (only the
    written pixels counted), gives the rule's pixels."""
    assert np.array_equal(decoder_cpu.render(mesh, tiles=True), reference(mesh))


@pytest.mark.parametrize("dtype, w, h, strip, channels", [
    # 16-bit samples: the planes' fixed point holds up to 2|D| = 2**15 (two triangles
    # of legs n - 1 have 2|D| = 2 (n - 1)**2), the exact walk beyond
    *[(np.uint16, n, n, strip, channels) for n in (128, 129, 130)
      for strip, channels in ((False, 1), (True, 1), (True, 3))],
    # 8-bit samples: up to 2|D| = 2**23 (the same arithmetic with other constants;
    # 4 million pixels of brute force each)
    (np.uint8, 4097, 1025, True, 1), (np.uint8, 4098, 1025, True, 1),
])
def test_cpu_fixed_point_at_its_bounds(dtype, w: int, h: int, strip: bool, channels: int) -> None:
    """Triangles at the largest size the kernel reads in fixed point and just beyond,
    with extreme and random samples: the rule's pixels either way. With a strip of one
    more column on the right the two large triangles keep off the last column and take
    the kernel's fixed-point walk (one channel's, or colour's), else its general one."""
    corners = _corners(w, h)
    vertices = np.array(corners + ([(w, 0), (w, h - 1)] if strip else []), np.int64)
    triangles = orient(vertices, [[0, 1, 2], [1, 3, 2]] + ([[1, 4, 3], [4, 5, 3]] if strip else []))
    top = int(np.iinfo(dtype).max)
    rng = np.random.default_rng(w * h)
    for values in ([0, top, top, 0], [top, 0, 1, top - 1], rng.integers(0, top + 1, 4)):
        values = np.resize(np.array(values, dtype), len(vertices))
        if channels == 3:  # the channels in different orders
            values = np.stack([values, values[::-1], np.roll(values, 1)], 1)
        mesh = Mesh(vertices, values, triangles, w + strip, h)
        validate(mesh)
        expected = reference(mesh)
        assert np.array_equal(decoder_cpu.render(mesh, tiles=True), expected)
        assert np.array_equal(decoder_cpu.render(mesh), expected)


def test_cpu_tiles_path_still_counts_the_pixels() -> None:
    """A mesh that does not tile the image, passed as one that does (tiles=True), is
    refused all the same: a missing triangle leaves pixels unwritten and a repeated
    one writes some twice, and the count of written pixels shows either."""
    with pytest.raises(CorruptError, match="uncovered"):
        decoder_cpu.render(_holed(_grid_mesh()), tiles=True)
    m = _grid_mesh()
    doubled = Mesh(m.vertices, m.values, np.concatenate([m.triangles, m.triangles[:1]]), m.width, m.height)
    with pytest.raises(CorruptError, match="twice"):
        decoder_cpu.render(doubled, tiles=True)


def test_cpu_tiles_path_never_returns_stale_memory() -> None:
    """A mesh whose repeated triangle writes exactly as many pixels as its missing one
    leaves unwritten passes the tiles=True count: those pixels must then hold zeros,
    never what the memory held before (the output was np.empty: with a freed buffer of
    the same size filled first, its bytes came back)."""
    v = np.array([[0, 0], [4, 0], [2, 2], [0, 4], [4, 4]])
    values = np.array([10, 20, 30, 40, 50], np.uint8)
    top, left, right = [0, 1, 2], [0, 2, 3], [1, 4, 2]  # the bottom one (2, 4, 3) missing
    mesh = Mesh(v, values, np.array([top, left, right, top]), 5, 5)
    for _ in range(20):
        stale = np.full((25, 1), 0xEE, np.uint8)
        del stale
        out = decoder_cpu.render(mesh, tiles=True)
        assert not (out == 0xEE).any()
        assert (out[3, 1:3] == 0).all() and (out[4] == 0).all() and (out[:3] != 0).all()


def _holed(mesh: Mesh) -> Mesh:
    """The mesh without its first triangle (a hole)."""
    return Mesh(mesh.vertices, mesh.values, mesh.triangles[1:], mesh.width, mesh.height)


def _grid_mesh(w: int = 9, h: int = 7) -> Mesh:
    rng = np.random.default_rng(3)
    pts = {(x, y) for x in range(0, w, 2) for y in range(0, h, 3)} | set(_corners(w, h))
    vertices = np.array(sorted(pts))
    return Mesh(vertices, rng.integers(0, 256, len(vertices)).astype(np.uint8),
                triangulate(vertices), w, h)


def test_cpu_uncovered_pixel_is_corrupt() -> None:
    with pytest.raises(CorruptError, match="uncovered"):
        decoder_cpu.render(_holed(_grid_mesh()))


def test_cpu_overlap_is_corrupt() -> None:
    m = _grid_mesh()
    doubled = Mesh(m.vertices, m.values, np.concatenate([m.triangles, m.triangles[:1]]), m.width, m.height)
    with pytest.raises(CorruptError, match="twice"):
        decoder_cpu.render(doubled)


def test_cpu_overlap_in_many_layers_is_corrupt() -> None:
    """The coverage check counts span starts and ends per row in 16-bit counters: a
    triangle repeated 2**16 times brings them back round to a tiling's values, which
    the per-row span count must catch (it did not without it)."""
    m = _grid_mesh()
    layers = np.concatenate([m.triangles] + [m.triangles[:1]] * (1 << 16))
    with pytest.raises(CorruptError, match="twice"):
        decoder_cpu.render(Mesh(m.vertices, m.values, layers, m.width, m.height))


def test_cpu_rows_of_more_spans_than_the_counters_hold() -> None:
    """A valid mesh whose rows have over 2**15 spans each (a 40,000-pixel-wide strip of
    one-pixel triangles) renders as the rule says: the check falls back to counting
    every pixel's writes."""
    w, h = 40000, 2
    xs = np.arange(w)
    vertices = np.concatenate([np.stack([xs, np.zeros(w, np.int64)], 1), np.stack([xs, np.ones(w, np.int64)], 1)])
    top, bottom = xs[:-1], xs[:-1] + w
    triangles = np.concatenate([np.stack([top, top + 1, bottom], 1), np.stack([top + 1, bottom + 1, bottom], 1)])
    values = (np.arange(2 * w) * 7 % 251).astype(np.uint8)
    mesh = Mesh(vertices, values, triangles, w, h)
    validate(mesh)
    assert np.array_equal(decoder_cpu.render(mesh), values.reshape(h, w))


@st.composite
def flipped(draw) -> Mesh:
    """A valid mesh with some of its diagonals flipped (where the two triangles on an
    edge form a convex quadrilateral): still a tiling, but no longer a Delaunay one, as
    listed triangles may be."""
    mesh = draw(meshes().filter(lambda m: len(m.triangles) > 1))
    v, t = mesh.vertices, mesh.triangles.copy()
    for _ in range(draw(st.integers(1, 12))):  # a loop over flips (test code)
        e = draw(st.integers(0, 3 * len(t) - 1))
        k, i = divmod(e, 3)
        a, b, c = t[k, i], t[k, (i + 1) % 3], t[k, (i + 2) % 3]
        # the triangle on the other side of a -> b has the directed edge b -> a
        other = [(m, j) for m in range(len(t)) for j in range(3)
                 if t[m, j] == b and t[m, (j + 1) % 3] == a]
        if not other:
            continue  # a border edge
        m, j = other[0]
        d = t[m, (j + 2) % 3]
        quad = np.array([[a, d, c], [d, b, c]])
        if (doubled_areas(v, quad) > 0).all():  # convex: the other diagonal works
            t[k], t[m] = quad
    return Mesh(v, mesh.values, t, mesh.width, mesh.height)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flipped())
def test_decoders_agree_on_tilings_that_are_not_delaunay(gl, mesh: Mesh) -> None:
    validate(mesh)
    cpu = decoder_cpu.render(mesh)
    assert np.array_equal(cpu, reference(mesh))
    assert np.array_equal(decoder_gl.render(mesh), cpu)


@st.composite
def sheared(draw) -> Mesh:
    """A valid mesh with one triangle's corner moved to a new vertex along the line
    parallel to the opposite edge: every area and the total stay as they were, but the
    triangles overlap on one side and leave a gap on the other, which may hold no pixel
    centre at all."""
    mesh = draw(meshes().filter(lambda m: len(m.triangles) > 0))
    v, t = mesh.vertices, mesh.triangles.copy()
    k = draw(st.integers(0, len(t) - 1))
    i = draw(st.integers(0, 2))
    a, b, c = t[k, i], t[k, (i + 1) % 3], t[k, (i + 2) % 3]
    d = v[c] - v[b]
    d //= np.gcd(abs(d[0]), abs(d[1]))
    moved = v[a] + draw(st.sampled_from([-2, -1, 1, 2])) * d
    assume(0 <= moved[0] < mesh.width and 0 <= moved[1] < mesh.height)
    assume(not (v == moved).all(axis=1).any())
    t[k, i] = len(v)
    values = np.concatenate([mesh.values, mesh.values[:1]])
    return Mesh(np.vstack([v, moved]), values, t, mesh.width, mesh.height)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sheared(), meshes(), st.booleans())
def test_overlapping_triangles_are_refused_before_either_decoder(bad: Mesh, good: Mesh, keyed: bool) -> None:
    """The area check alone passes such a mesh; left to the decoders, the CPU one
    refused some and the GL one drew them, or the other way round. validate refuses
    them all, so a file's mesh reaches a decoder only if it tiles the image; a mesh
    that tiles it passes. Both ways of sorting the edges (integer keys, and the
    lexsort kept for meshes of over 2**31 vertices) are exercised."""
    assert doubled_areas(bad.vertices, bad.triangles).sum() == 2 * (bad.width - 1) * (bad.height - 1)
    with _keyed_edges(keyed):
        with pytest.raises(CorruptError, match="overlap|tile"):
            validate(bad)
        validate(good)


# the module, which codec.mesh (the function) hides
mesh_module = importlib.import_module("codec.mesh")


@contextlib.contextmanager
def _keyed_edges(keyed: bool):
    saved = mesh_module._KEYED_EDGES
    mesh_module._KEYED_EDGES = saved if keyed else 0
    try:
        yield
    finally:
        mesh_module._KEYED_EDGES = saved


# ---------------------------------------------------------------- GL decoder

@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes())
def test_gl_agrees_with_cpu(gl, mesh: Mesh) -> None:
    cpu = decoder_cpu.render(mesh)
    exact = decoder_gl.render(mesh)
    assert exact.dtype == cpu.dtype and exact.shape == cpu.shape
    assert np.array_equal(exact, cpu)
    # the float32 fallback: within 1 for 8-bit data, 1/2048 of full scale for 16-bit
    worst, _ = agreement(decoder_gl.render(mesh, exact=False), cpu)
    assert worst <= (1 if mesh.dtype == np.uint8 else 32)


def test_gl_covers_border_pixels(gl) -> None:
    """The rasteriser's fill rule leaves two sides of the border empty; the exact
    coverage test includes them, with the mesh's own values (a ramp makes a wrong
    source visible)."""
    w, h = 17, 11
    vertices = np.array(_corners(w, h))
    values = np.array([0, 160, 40, 250], np.uint8)
    mesh = Mesh(vertices, values, triangulate(vertices), w, h)
    out = decoder_gl.render(mesh)
    assert np.array_equal(out, decoder_cpu.render(mesh))
    assert np.array_equal(out, reference(mesh))


@pytest.mark.parametrize("w, h", [(4, 65536), (65536, 4), (20000, 300), (4097, 4097)])
def test_gl_agrees_on_triangles_far_larger_than_a_tile(gl, w: int, h: int) -> None:
    """A few vertices make triangles that reach far beyond the viewport, where GL clips
    them in floating point; before coverage was decided in integers, pixels a
    thousandth of a pixel inside one triangle went to its neighbour."""
    rng = np.random.default_rng(w * h)
    pts = set(_corners(w, h))
    while len(pts) < 10:
        pts.add((int(rng.integers(0, w)), int(rng.integers(0, h))))
    vertices = np.array(sorted(pts), dtype=np.int64)
    values = rng.integers(0, 65536, len(vertices)).astype(np.uint16)
    mesh = Mesh(vertices, values, triangulate(vertices), w, h)
    validate(mesh)
    assert np.array_equal(decoder_gl.render(mesh), decoder_cpu.render(mesh))


def test_gl_tiles(gl, monkeypatch) -> None:
    mesh = codec.build_mesh(np.random.default_rng(5).integers(0, 256, (45, 70, 3)).astype(np.uint8))
    whole = decoder_gl.render(mesh)
    monkeypatch.setattr(decoder_gl.context(), "tile", 16)
    assert np.array_equal(decoder_gl.render(mesh), whole)
    assert np.array_equal(whole, decoder_cpu.render(mesh))


def test_gl_hole_is_corrupt(gl) -> None:
    with pytest.raises(CorruptError):
        decoder_gl.render(_holed(_grid_mesh()))


def test_gl_without_context_raises_backend_error(no_gl) -> None:
    data = codec.encode(np.zeros((8, 8), np.uint8))
    with pytest.raises(BackendError, match="libegl1.*backend='cpu'"):
        codec.decode(data, backend="gl")
    assert np.array_equal(codec.decode(data), np.zeros((8, 8), np.uint8))


# ---------------------------------------------------------------- public corpus

@pytest.fixture(scope="module")
def corpus_meshes(corpus) -> dict[str, Mesh]:
    meshes = {name: codec.build_mesh(img) for name, img in corpus.items()}
    from skimage import data

    rgb = data.astronaut()[::2, ::2]
    meshes["astronaut_rgb"] = codec.build_mesh(rgb)
    meshes["camera_16bit"] = codec.build_mesh(data.camera().astype(np.uint16) * 257 + 3)
    return meshes


def test_corpus_agreement(gl, corpus_meshes) -> None:
    for name, mesh in corpus_meshes.items():
        cpu = decoder_cpu.render(mesh)
        worst, same = agreement(decoder_gl.render(mesh), cpu)
        assert worst <= 1 and same >= 0.99, (name, worst, same)
        assert same == 1.0, (name, same)  # the exact shader reproduces the CPU decoder
        # the float32 fallback (GL < 4.0) interpolates in float: within 1 for 8-bit
        # data; for 16-bit, steep walls cost it up to 1/2048 of full scale
        worst, same = agreement(decoder_gl.render(mesh, exact=False), cpu)
        assert worst <= (1 if mesh.dtype == np.uint8 else 32), (name, worst)


def test_corpus_backends_through_the_api(gl, corpus) -> None:
    img = corpus["coins"]
    data = codec.encode(img)
    assert np.array_equal(codec.decode(data, backend="gl"), codec.decode(data, backend="cpu"))


def test_a_decode_returns_an_array_of_its_own(corpus) -> None:
    """A file of one band decodes to the render itself (no image to copy it into): each
    decode's array is its own, writeable and C-contiguous, with the mesh's pixels."""
    img = corpus["camera"]
    one = codec.encode(img)
    assert codec.info(one)["bands"] == 1
    a, b = codec.decode(one), codec.decode(one)
    assert not np.shares_memory(a, b)
    assert a.flags.writeable and a.flags.c_contiguous and a.shape == img.shape and a.dtype == img.dtype
    a[0, 0] ^= 1
    assert not np.array_equal(a, b)
    whole = codec.decode_mesh(one)
    assert np.array_equal(b, decoder_cpu.render(whole))


def test_rasteriser_refuses_a_size_whose_pixel_count_wraps() -> None:
    """width * height = 2**64 wraps to 0 in int64, which matched an empty output: the
    kernel then wrote far outside it (a crash); the size must be refused."""
    from codec.native import _rasterise

    v = np.array([[0, 0], [3000, 0], [0, 3000]], np.int64)
    values = np.array([[1], [2], [3]], np.uint8)
    t = np.array([[0, 1, 2]], np.int64)
    for check in (_rasterise.Check.CHECK_TOTAL, _rasterise.Check.CHECK_SPANS):
        with pytest.raises(ValueError, match="2\\*\\*32 pixels"):
            _rasterise.rasterise(v, values, t, np.zeros((0, 1), np.uint8), 1 << 32, 1 << 32, check)


def _short_span_meshes(rng: np.random.Generator):
    """Vertex sets of small images: random ones of every density, and two-row bands
    whose top row has a gap of n = 1 .. 19 pixels at every place (one-row triangles
    with a span of n pixels, written 8 samples at a time and a rest; the last row's
    spans at the image's last bytes)."""
    for w in range(2, 14):
        for h in (2, 3, 5):
            for density in (0.1, 0.3, 0.6, 0.9):
                keep = rng.random((h, w)) < density
                yield w, h, {(x, y) for y, x in zip(*np.nonzero(keep))}
    w = 21
    for n in range(1, 20):
        for a in range(0, w - n, 1 if n < 10 else 3):
            for h in (2, 3):
                b = int(rng.integers(0, w))
                yield w, h, {(a, 0), (a + n, 0), (b, 1)}


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_cpu_short_spans_to_the_images_last_bytes(dtype, channels: int) -> None:
    """The kernel writes a short span (up to 8 samples) as one 8-byte word merged
    into the row under a mask, and a narrow triangle without a test per row: spans of
    0 .. 19 pixels, one-row triangles and the last bytes of small images, where the word
    would reach past the image (the kernel must then take the loop), against the rule,
    with both coverage checks. The triangles in a random order: a byte written beyond
    a span shows wherever its pixel's own triangle came first."""
    rng = np.random.default_rng(20 + channels)
    top = int(np.iinfo(dtype).max)
    for w, h, pts in _short_span_meshes(rng):
        vertices = np.array(sorted(pts | set(_corners(w, h))), np.int64)
        values = rng.integers(0, top + 1, (len(vertices), channels)).astype(dtype)
        values[rng.random(len(vertices)) < 0.3] = top  # extreme samples too
        triangles = triangulate(vertices)
        mesh = Mesh(vertices, values if channels > 1 else values[:, 0], triangles, w, h)
        validate(mesh)
        expected = reference(mesh)
        for order in (np.arange(len(triangles)), rng.permutation(len(triangles)), rng.permutation(len(triangles))):
            shuffled = Mesh(mesh.vertices, mesh.values, triangles[order], w, h)
            assert np.array_equal(decoder_cpu.render(shuffled, tiles=True), expected), (w, h, sorted(pts))
            assert np.array_equal(decoder_cpu.render(shuffled), expected), (w, h, sorted(pts))


def _walk_meshes(rng: np.random.Generator):
    """Random vertex sets (8- and 16-bit samples, 1 and 3 channels, images 2 to 5,000
    wide, sparse to dense: spans of 0 to hundreds of samples, flat tops and bottoms,
    triangles on the image's last bytes), a third of them broken (a triangle dropped
    or doubled, a vertex moved), the triangles in a random order half the time."""
    for case in range(160):
        w = int(rng.choice([2, 3, 5, 9, 17, 64, 300, 1000, 5000]))
        h = int(rng.integers(2, 12 if w >= 1000 else 40))
        n = max(1, int(rng.choice([0.002, 0.02, 0.1, 0.4]) * w * h))
        pts = set(zip(rng.integers(0, w, n).tolist(), rng.integers(0, h, n).tolist()))
        vertices = np.array(sorted(pts | set(_corners(w, h)), key=lambda p: (p[1], p[0])), np.int64)
        triangles = np.ascontiguousarray(triangulate(vertices), dtype=np.int64)
        if case % 3 == 0 and len(triangles) > 1:
            kind = case % 9 // 3
            if kind == 0:
                triangles = np.delete(triangles, rng.integers(len(triangles)), 0)
            elif kind == 1:
                triangles = np.concatenate([triangles, triangles[rng.integers(len(triangles))][None]])
            else:
                vertices = vertices.copy()
                vertices[rng.integers(len(vertices))] = [rng.integers(0, w), rng.integers(0, h)]
        if rng.random() < 0.5:
            triangles = triangles[rng.permutation(len(triangles))]
        yield w, h, vertices, triangles


def test_cpu_simd_walk_gives_the_portable_walks_pixels() -> None:
    """Where the processor has AVX-512, rasterise() walks one-channel triangles with
    masked vector stores (codec/_rasterise.pyx); portable=True takes the walk every
    other processor takes. Both give the same pixels (the output's samples outside
    any triangle included: neither writes them) and the same status, with both
    coverage checks, from int64 and from int32 corner indices; a valid mesh's pixels
    are the rule's."""
    from codec.native import _rasterise

    rng = np.random.default_rng(2031)
    checks = (_rasterise.Check.CHECK_TOTAL, _rasterise.Check.CHECK_SPANS)
    for w, h, vertices, triangles in _walk_meshes(rng):
        for dtype, channels in ((np.uint8, 1), (np.uint16, 1), (np.uint8, 3), (np.uint16, 3)):
            top = int(np.iinfo(dtype).max)
            values = rng.integers(0, top + 1, (len(vertices), channels)).astype(dtype)
            values[rng.random(len(vertices)) < 0.2] = top
            first = rng.integers(0, top + 1, (w * h, channels)).astype(dtype)
            for check in checks:
                fast, portable = first.copy(), first.copy()
                status = _rasterise.rasterise(vertices, values, triangles, fast, w, h, check)
                assert _rasterise.rasterise(vertices, values, triangles, portable, w, h, check,
                                            portable=True) == status, (w, h, dtype, channels, check)
                assert np.array_equal(fast, portable), (w, h, dtype, channels, check)
                for simd in (True, False):  # int32 corners: the same as int64 ones
                    narrow = first.copy()
                    assert _rasterise.rasterise(vertices, values, triangles.astype(np.int32), narrow, w, h, check,
                                                portable=not simd) == status, (w, h, dtype, channels, check)
                    assert np.array_equal(narrow, fast), (w, h, dtype, channels, check)
            if status == (0, 0) and w * h * len(triangles) < 1 << 22:
                mesh = Mesh(vertices, values if channels > 1 else values[:, 0], triangles, w, h)
                assert np.array_equal(portable.reshape(h, w, channels), reference(mesh).reshape(h, w, channels))


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_cpu_refuses_a_corner_index_beyond_the_vertices(dtype) -> None:
    """A corner index below 0 or past the vertices, in either index width the kernel
    reads, is refused by name before any pixel is written (CorruptError from
    decoder_cpu.render, the triangle's number in the message)."""
    vertices = np.array([[0, 0], [3, 0], [0, 3], [3, 3]], np.int64)
    values = np.array([1, 2, 3, 4], np.uint8)
    for bad in (-1, 4, np.iinfo(dtype).max, np.iinfo(dtype).min):
        triangles = np.array([[0, 1, 2], [1, 3, bad]], dtype)
        mesh = Mesh(vertices, values, triangles, 4, 4)
        for tiles in (True, False):
            with pytest.raises(CorruptError, match="triangle 1 refers to a vertex beyond the 4 stored"):
                decoder_cpu.render(mesh, tiles=tiles)


@pytest.mark.parametrize("backend", ["cpu", "gl"])
def test_render_writes_into_the_callers_array(backend: str) -> None:
    """render(out=...) renders into the caller's array and returns it, with the pixels
    of a render into a new one (gray, colour, 16-bit, a one-pixel-high image without
    triangles); an array of another shape or type, not C-contiguous or read-only is
    refused by what is wrong with it, before anything is written."""
    from codec import decoding
    from codec.errors import OptionError

    if backend == "gl":
        try:
            decoder_gl.context()
        except BackendError as exc:
            pytest.skip(str(exc))
    rng = np.random.default_rng(5)
    for w, h, channels, dtype in ((37, 23, 1, np.uint8), (37, 23, 3, np.uint8), (64, 9, 1, np.uint16),
                                  (40, 1, 1, np.uint8)):
        pts = {(int(x), int(y)) for x, y in zip(rng.integers(0, w, 60), rng.integers(0, h, 60))}
        vertices = np.array(sorted(pts | set(_corners(w, h)), key=lambda p: (p[1], p[0])), np.int64)
        values = rng.integers(0, np.iinfo(dtype).max + 1, (len(vertices), channels)).astype(dtype)
        triangles = triangulate(vertices) if h > 1 else np.zeros((0, 3), np.int64)
        mesh = Mesh(vertices, values if channels > 1 else values[:, 0], triangles, w, h)
        expected = decoding.render(mesh, backend, tiles=True)
        shape = expected.shape
        out = np.full(shape, 7, dtype)
        assert decoding.render(mesh, backend, tiles=True, out=out) is out
        assert np.array_equal(out, expected)
        wrong = [np.zeros(shape[::-1] if h > 1 else (h + 1, w), dtype),
                 np.zeros(shape, np.int16), np.zeros(shape + (1,) if channels == 1 else shape[:2], dtype),
                 np.zeros((shape[0], shape[1] * 2) + shape[2:], dtype)[:, ::2], [[0] * w] * h]
        ro = np.zeros(shape, dtype)
        ro.flags.writeable = False
        for bad, what in zip(wrong + [ro], ["shape", "dtype", "shape", "C-contiguous", "numpy array", "read-only"]):
            with pytest.raises(OptionError, match=what):
                decoding.render(mesh, backend, tiles=True, out=bad)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 3])
def test_rasterise_zero_clears_the_image_the_triangles_leave(dtype, channels) -> None:
    """rasterise(zero=True) (a decode's new image, zeroed without the GIL) sets every
    pixel to 0 before the triangles are drawn: a pixel no triangle writes is 0, not
    what the memory held."""
    from codec.native import _rasterise

    w, h = 6, 5
    vertices = np.array([[0, 0], [5, 0], [0, 4]], np.int64)  # half the image
    values = np.full((3, channels), 200, dtype)
    triangles = np.array([[0, 1, 2]], np.int64)
    for check in (_rasterise.Check.CHECK_SPANS, _rasterise.Check.CHECK_TOTAL):
        out = np.full((w * h, channels), 7, dtype)
        status, _ = _rasterise.rasterise(vertices, values, triangles, out, w, h, check, zero=True)
        assert status == _rasterise.Status.UNCOVERED
        assert set(np.unique(out).tolist()) == {0, 200}
        kept = np.full((w * h, channels), 7, dtype)  # without zero, the caller's pixels stay
        _rasterise.rasterise(vertices, values, triangles, kept, w, h, check)
        assert set(np.unique(kept).tolist()) == {7, 200}
