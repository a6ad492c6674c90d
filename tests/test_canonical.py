"""The triangulation of format version 6 (ATM.md §4.2.5): whatever Triangle returns, with
its input in any order and by any of its algorithms, the codec uses the unique
triangulation that the perturbed lifting defines."""

from __future__ import annotations

import itertools
import struct

import numpy as np
import pytest
import triangle
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import canonical, encoder, meshcode
from codec import triangulate as triangulate_module
from codec.coding import canonical_triangles, triangle_crc
from codec.errors import ATMError, UnsupportedError
from codec.mesh import Mesh, segments
from codec.triangulate import triangulate


def shuffled_triangle(rng: np.random.Generator, algorithm: str):
    """triangle.triangulate as called with the vertices and segments in a random order,
    each segment in a random direction, by one of Triangle's algorithms ('' divide and
    conquer, 'i' incremental, 'F' sweepline; 'l' vertical cuts only): the triangles and
    segments come back in the caller's numbering."""
    plain = triangle.triangulate

    def call(data: dict, switches: str) -> dict:
        n = len(data["vertices"])
        perm = rng.permutation(n)  # new position i holds old vertex perm[i]
        where = np.empty(n, np.int64)
        where[perm] = np.arange(n)
        moved = {"vertices": np.asarray(data["vertices"])[perm]}
        if "segments" in data:
            seg = where[np.asarray(data["segments"], np.int64)][rng.permutation(len(data["segments"]))]
            flip = rng.random(len(seg)) < 0.5
            seg[flip] = seg[flip][:, ::-1]
            moved["segments"] = seg.astype(np.int32)
        out = dict(plain(moved, switches + algorithm))
        for key in ("triangles", "segments"):
            if key in out:
                out[key] = perm[np.asarray(out[key], np.int64)]
        return out

    return call


def decode_by_triangle(monkeypatch) -> None:
    """Within the test, codec.decode rebuilds Delaunay bands by Triangle and the
    canonical pass (codec.triangulate.by_triangle) instead of the compiled kernel (the
    CRC too: zlib's of their u32 list, not the kernel's)."""
    def by_triangle(v, w, strict=False):
        triangles = canonical_triangles(triangulate_module.by_triangle(v, w))
        return triangles, triangle_crc(triangles)

    monkeypatch.setattr(meshcode, "delaunay_and_crc", by_triangle)
    # a Reader triangulates in its own Delaunay's buffers: that route too
    monkeypatch.setattr(triangulate_module.Delaunay, "triangles_and_crc",
                        lambda self, v, w=None, strict=False: by_triangle(v, w, strict))


def lattice(w: int, h: int, sx: int = 1, sy: int = 1) -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(0, w, sx), np.arange(0, h, sy))
    return np.stack([gx.ravel(), gy.ravel()], 1)


def raw_triangle(vertices: np.ndarray, segs: np.ndarray | None, rng, algorithm: str) -> np.ndarray:
    data = {"vertices": vertices.astype(np.float64)}
    switches = "Q"
    if segs is not None:
        data["segments"] = segs.astype(np.int32)
        switches = "pcQ"
    return np.asarray(shuffled_triangle(rng, algorithm)(data, switches)["triangles"], np.int64)


def local_rule_holds(vertices: np.ndarray, tris: np.ndarray, segs: np.ndarray | None) -> bool:
    """Brute force over every edge in Python integers: each edge shared by two
    triangles and not a segment is kept by the rule (incircle < 0, or = 0 with the
    first corner of its quadrilateral in raster order off it)."""
    fixed = set() if segs is None else {frozenset(s) for s in segs.tolist()}
    sides: dict[frozenset, list[tuple[int, int, int]]] = {}
    for t in tris.tolist():
        for i in range(3):
            a, b, c = t[i], t[(i + 1) % 3], t[(i + 2) % 3]
            sides.setdefault(frozenset((a, b)), []).append((a, b, c))
    pts = vertices.tolist()
    for key, side in sides.items():
        if key in fixed or len(side) == 1:
            continue
        (a, b, c), (_, _, d) = side
        m = [[pts[p][0] - pts[d][0], pts[p][1] - pts[d][1]] for p in (a, b, c)]
        m = [[x, y, x * x + y * y] for x, y in m]
        det = (m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
               - m[1][2] * (m[0][0] * m[2][1] - m[0][1] * m[2][0])
               + m[2][2] * (m[0][0] * m[1][1] - m[0][1] * m[1][0]))
        first = min((a, b, c, d), key=lambda p: (pts[p][1], pts[p][0]))
        if det > 0 or (det == 0 and first in (a, b)):
            return False
    return True


def perturbed_delaunay(vertices: np.ndarray) -> np.ndarray:
    """The definition itself, by brute force: lift p to x^2 + y^2 + eps^(r+1) for its
    raster place r, with eps = 2^-40 (small enough to dominate here, for coordinates
    below 100), in exact integers scaled by 2^(40 (N + 1)); a triangle is in the
    triangulation iff every other lifted point lies above its plane."""
    n = len(vertices)
    rank = np.lexsort((vertices[:, 0], vertices[:, 1])).tolist()
    place = {v: r for r, v in enumerate(rank)}
    scale = 1 << (40 * (n + 1))
    pts = vertices.tolist()
    lift = [(x * x + y * y) * scale + (1 << (40 * (n - place[i]))) for i, (x, y) in enumerate(pts)]

    def orient(a, b, c):
        return (pts[b][0] - pts[a][0]) * (pts[c][1] - pts[a][1]) - (pts[b][1] - pts[a][1]) * (pts[c][0] - pts[a][0])

    def below(a, b, c, d):
        # 4x4 determinant of rows (x, y, lift, 1), positive iff d is below the plane of
        # a, b, c (abc positively oriented): d "inside the circle"
        rows = [[pts[p][0] - pts[d][0], pts[p][1] - pts[d][1], lift[p] - lift[d]] for p in (a, b, c)]
        (ax, ay, al), (bx, by, bl), (cx, cy, cl) = rows
        return al * (bx * cy - by * cx) - bl * (ax * cy - ay * cx) + cl * (ax * by - ay * bx) > 0

    out = []
    for a, b, c in itertools.combinations(range(n), 3):
        o = orient(a, b, c)
        if o == 0:
            continue
        if o < 0:
            b, c = c, b
        if not any(below(a, b, c, d) for d in range(n) if d not in (a, b, c)):
            out.append((a, b, c))
    return canonical_triangles(np.array(out, np.int64))


ALGORITHMS = ["", "i", "F", "l"]


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_uniform_lattice_has_the_one_answer(algorithm):
    """Every square of a unit lattice ties; each is split by the diagonal that avoids
    its top-left corner (the first in raster order), whatever Triangle did."""
    w, h = 9, 7
    v = lattice(w, h)
    expected = []
    for y in range(h - 1):
        for x in range(w - 1):
            p, q, r, s = y * w + x, y * w + x + 1, (y + 1) * w + x, (y + 1) * w + x + 1
            expected += [(p, q, r), (q, s, r)]  # diagonal q - r, positively oriented
    expected = canonical_triangles(np.array(expected))
    rng = np.random.default_rng(7)
    for _ in range(3):
        raw = raw_triangle(v, None, rng, algorithm)
        out = canonical_triangles(canonical.canonicalise(v, raw, check=True))
        np.testing.assert_array_equal(out, expected)
        assert local_rule_holds(v, out, None)


@pytest.mark.parametrize("r2", [25, 325, 1105])
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_cocircular_rings_match_the_definition(r2, algorithm):
    """All lattice points of a circle (12, 24 or 32 of them) tie at once; with the
    centre or not, the pass gives exactly the perturbed Delaunay triangulation the
    definition describes, computed here by brute force on lifted points."""
    r = int(np.sqrt(r2)) + 1
    ring = [(x + 40, y + 40) for x in range(-r, r + 1) for y in range(-r, r + 1) if x * x + y * y == r2]
    rng = np.random.default_rng(r2)
    for extra in ([], [(40, 40)]):
        v = np.array(sorted(ring + extra, key=lambda p: (p[1], p[0])), np.int64)
        expected = perturbed_delaunay(v)
        raw = raw_triangle(v, None, rng, algorithm)
        out = canonical_triangles(canonical.canonicalise(v, raw, check=True))
        np.testing.assert_array_equal(out, expected)
        assert local_rule_holds(v, out, None)


def test_the_pass_flips_ties_triangle_breaks_otherwise():
    """Triangle's own choices differ from the rule on a lattice (so the pass has work to
    do), and the self-check refuses a triangulation left unflipped."""
    v = lattice(12, 9)
    raw = raw_triangle(v, None, np.random.default_rng(1), "")
    tris, flips = canonical.flip_to_canonical(v, raw)
    assert flips > 0
    assert not local_rule_holds(v, raw, None)
    with pytest.raises(ATMError, match="not locally Delaunay"):
        canonical.verify(v, raw)
    canonical.verify(v, tris)


def test_a_long_segment_over_a_vertex_stays_an_edge():
    """A segment (0, 0) - (4, 4) passes over three lattice vertices along the diagonal
    the tie rule would not choose: its pieces are constraints, never flipped."""
    v = lattice(6, 6)
    index = {tuple(p): i for i, p in enumerate(v.tolist())}
    tris = triangulate_module.by_triangle(v, np.array([[index[0, 0], index[4, 4]]]))
    edges = {frozenset(e) for t in tris.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    for k in range(4):
        assert frozenset((index[k, k], index[k + 1, k + 1])) in edges


@pytest.mark.parametrize("scale", [3, 1 << 10, 1 << 17])
def test_incircle_is_exact_for_large_extents(scale):
    """Points of circles far beyond binary64's exact range (extent up to 2^20): exact
    ties give 0 and one-unit moves off the circle the sign Python integers give."""
    rng = np.random.default_rng(scale)
    # x^2 + y^2 = (5^k)^2 has many integer solutions; scaled circles keep them
    r = 5**4
    ring = np.array([(x, y) for x in range(-r, r + 1) for y in (int(round(np.sqrt(r * r - x * x))),)
                     if x * x + y * y == r * r], np.int64)
    ring = np.concatenate([ring, ring * [1, -1]])
    quads = ring[rng.integers(0, len(ring), (400, 4))] * scale + 600000
    quads[200:, 3] += rng.integers(-1, 2, (200, 2))
    a, b, c, d = (quads[:, i] for i in range(4))
    got = canonical.incircle_sign(a, b, c, d)
    want = [
        canonical._exact_incircle_sign((p - s).tolist(), (q - s).tolist(), (t - s).tolist())
        for p, q, t, s in quads
    ]
    np.testing.assert_array_equal(got, want)
    assert (got[:200] == 0).sum() > 100  # most first-half quads are exact ties


def _mesh_with_wall(cols: list[int], rows: list[int], keep: list[bool], wall_x: int, seed: int) -> Mesh:
    w, h = max(cols) + 1, max(rows) + 1
    pts = [(x, y) for x, y in itertools.product(cols, rows)]
    corners = {(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)}
    chosen = [p for p, k in zip(pts, keep) if k or p in corners or p[0] == wall_x]
    v = np.array(sorted(set(chosen), key=lambda p: (p[1], p[0])), np.int64)
    wall = np.flatnonzero(v[:, 0] == wall_x)
    wall = wall[np.argsort(v[wall, 1])]
    tris = triangulate(v, segments([wall]))
    values = np.random.default_rng(seed).integers(0, 256, len(v)).astype(np.uint8)
    return Mesh(v, values, tris, w, h, [wall])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    keep=st.lists(st.booleans(), min_size=80, max_size=80),
    wall_at=st.integers(1, 7),
    seed=st.integers(0, 2**32 - 1),
    algorithm=st.sampled_from(ALGORITHMS),
)
def test_decoding_does_not_depend_on_how_triangle_is_called(monkeypatch, keep, wall_at, seed, algorithm):
    """A file with ties and a wall decodes to the same pixels (the compiled kernel's)
    when the decoder uses Triangle instead and Triangle gets the vertices and segments
    in another order, segments reversed, or runs another of its algorithms: the
    canonical pass undoes every difference."""
    cols, rows = [0, 2, 4, 6, 8, 10, 12, 14, 16, 17], [0, 2, 4, 6, 8, 10, 12, 13]
    mesh = _mesh_with_wall(cols, rows, keep, cols[wall_at], seed)
    data = encoder.pack(mesh)
    expected = codec.decode(data)
    decode_by_triangle(monkeypatch)
    monkeypatch.setattr(triangle, "triangulate",
                        shuffled_triangle(np.random.default_rng(seed), algorithm))
    np.testing.assert_array_equal(codec.decode(data), expected)


def test_the_pass_ends_locally_delaunay_on_random_walled_lattices():
    """Seeded: 200 lattice subsets with a wall, Triangle's output in random order by
    each algorithm; the self-check and the brute-force local rule both hold after the
    pass (flips move constraint marks and neighbours; a slip shows here)."""
    cols, rows = [0, 2, 4, 6, 8, 10, 12, 14, 16, 17], [0, 2, 4, 6, 8, 10, 12, 13]
    rng = np.random.default_rng(190)
    for trial in range(200):
        mesh = _mesh_with_wall(cols, rows, list(rng.random(80) < 0.5), cols[rng.integers(1, 8)], 0)
        walls = segments(mesh.constraints)
        raw = raw_triangle(mesh.vertices, walls, rng, ALGORITHMS[trial % 4])
        out = canonical.canonicalise(mesh.vertices, raw, walls, check=True)
        assert local_rule_holds(mesh.vertices, out, walls)
        np.testing.assert_array_equal(canonical_triangles(out), canonical_triangles(mesh.triangles))


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_conformance_files_decode_alike_by_any_triangle_call(monkeypatch, algorithm):
    """Every conformance file (ties in all its two-dimensional Delaunay bands) decodes to
    its stored image with Triangle's input shuffled and by each of its algorithms."""
    from pathlib import Path

    from codec.files import read_image

    here = Path(__file__).resolve().parent.parent / "format_spec" / "conformance"
    decode_by_triangle(monkeypatch)
    monkeypatch.setattr(triangle, "triangulate",
                        shuffled_triangle(np.random.default_rng(len(algorithm)), algorithm))
    for path in sorted(here.glob("*.atm")):
        npy = path.with_suffix(".npy")
        expected = np.load(npy) if npy.exists() else read_image(path.with_suffix(".png"))
        np.testing.assert_array_equal(codec.decode(path.read_bytes()), expected)


@pytest.mark.parametrize("mesher", ["adaptive", "uniform"])
def test_a_corpus_image_decodes_alike_by_any_triangle_call(monkeypatch, mesher):
    """skimage's text image at the default density (walls, thousands of ties): the
    same pixels, and the self-check holds, whichever way Triangle is called."""
    from tests.corpus import load_corpus

    data = codec.encode(load_corpus()["text"], mesher=mesher)
    expected = codec.decode(data)
    mesh = codec.decode_mesh(data)
    walls = segments(mesh.constraints) if mesh.constraints else None
    assert canonical.tie_count(mesh.vertices, mesh.triangles, walls)[1] > 100
    decode_by_triangle(monkeypatch)
    for k, algorithm in enumerate(ALGORITHMS):
        call = shuffled_triangle(np.random.default_rng(k), algorithm)
        monkeypatch.setattr(triangle, "triangulate", call)
        np.testing.assert_array_equal(codec.decode(data), expected)
        raw = raw_triangle(mesh.vertices, walls, np.random.default_rng(k), algorithm)
        canonical.canonicalise(mesh.vertices, raw, walls, check=True)


def test_conformance_files_catch_a_decoder_without_the_rule(monkeypatch):
    """ATM.md §9: on every conformance file with a two-dimensional Delaunay band, the
    triangles of Triangle alone (input in file order) fail the CRC; listed and
    one-pixel files decode as before."""
    from pathlib import Path

    from codec.errors import CorruptError

    here = Path(__file__).resolve().parent.parent / "format_spec" / "conformance"
    decode_by_triangle(monkeypatch)
    monkeypatch.setattr(canonical, "canonicalise", lambda v, t, c: np.asarray(t, np.int64))
    caught = set()
    for path in sorted(here.glob("*.atm")):
        try:
            codec.decode(path.read_bytes())
        except CorruptError as exc:
            assert "CRC mismatch" in str(exc)
            caught.add(path.stem)
    assert caught == {p.stem for p in here.glob("*.atm")} - {"line_1x9", "listed_ties", "listed_not_delaunay"}


def test_the_pass_reaches_the_one_answer_from_any_triangulation():
    """ATM.md §4.2.5, construction: flips from any triangulation with the walls as
    edges, not only from a constrained Delaunay one, end at the same triangles."""
    cols, rows = [0, 2, 4, 6, 8, 10, 12, 14, 16, 17], [0, 2, 4, 6, 8, 10, 12, 13]
    rng = np.random.default_rng(6)
    for _ in range(40):
        mesh = _mesh_with_wall(cols, rows, list(rng.random(80) < 0.6), cols[rng.integers(1, 8)], 0)
        walls = segments(mesh.constraints)
        start = mesh.triangles
        for _ in range(6):
            start = canonical.random_flips(mesh.vertices, start, walls, rng, 0.5)
        assert not local_rule_holds(mesh.vertices, start, walls)
        out = canonical.canonicalise(mesh.vertices, start, walls, check=True)
        np.testing.assert_array_equal(canonical_triangles(out), canonical_triangles(mesh.triangles))


def test_version_5_files_are_refused_naming_both_versions():
    """Version 5 has version 6's bytes but Triangle's tie-breaking: not decoded."""
    data = codec.encode(np.arange(64, dtype=np.uint8).reshape(8, 8), points=10)
    old = data[:8] + struct.pack("<H", 5) + data[10:]
    with pytest.raises(UnsupportedError, match="version 5; this codec reads version 6 .*re-encode the source image"):
        codec.decode(old)
