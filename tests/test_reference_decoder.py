"""The independent reference decoder (format_spec/reference_decoder.py), written from
ATM.md alone: it decodes the conformance files, random files of every kind and the
corpus exactly as codec.decode does, and its triangulation follows the rule of §4.2.5
(checked here by brute force, with predicates of the test's own)."""

from __future__ import annotations

import ast
import importlib.util
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import container
from codec.files import read_image
from codec.mesh import Mesh
from codec.triangulate import triangulate
from codec.format_spec import schema
from tests.conftest import chunks, random_mesh
from tests.synthetic import range_scene

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "format_spec" / "reference_decoder.py"
VECTORS = ROOT / "format_spec" / "conformance"
CASES = sorted(p.stem for p in VECTORS.glob("*.atm"))


def load_reference():
    """The decoder loaded from its path, as a stranger would use the file."""
    spec = importlib.util.spec_from_file_location("atm_reference_decoder", REFERENCE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ref = load_reference()


def make_chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<I", len(payload)) + kind + payload + struct.pack("<I", zlib.crc32(kind + payload))


def assert_same_image(out: np.ndarray, expected: np.ndarray) -> None:
    assert out.dtype == expected.dtype and out.shape == expected.shape
    np.testing.assert_array_equal(out, expected)  # NaN where expected has NaN


# ---------------------------------------------------------------------------
# The rule of §4.2.5 by brute force, independent of the decoder's own code


def orient(p, q, r) -> int:
    return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])


def incircle(a, b, c, d) -> int:
    rows = [(p[0] - d[0], p[1] - d[1]) for p in (a, b, c)]
    (ax, ay), (bx, by), (cx, cy) = rows
    return ((ax * ax + ay * ay) * (bx * cy - cx * by) - (bx * bx + by * by) * (ax * cy - cx * ay)
            + (cx * cx + cy * cy) * (ax * by - bx * ay))


def assert_follows_the_rule(points: list[tuple[int, int]], segments, triangles) -> None:
    """The triangles tile the points' bounding box with every point a corner, every
    segment is an edge, and every free edge is locally Delaunay under the perturbed
    rule (I < 0, or I = 0 and the first of the four corners in raster order is c or d)."""
    assert all(orient(*(points[i] for i in t)) > 0 for t in triangles)
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    area = sum(orient(*(points[i] for i in t)) for t in triangles)
    assert area == 2 * (max(xs) - min(xs)) * (max(ys) - min(ys))
    apex = {}
    for a, b, c in triangles:
        for e, w in (((a, b), c), ((b, c), a), ((c, a), b)):
            assert e not in apex, "two triangles on one side of an edge"
            apex[e] = w
    assert {i for t in triangles for i in t} == set(range(len(points)))
    fixed = {frozenset(s) for s in segments}
    for s in fixed:
        a, b = tuple(s)
        assert (a, b) in apex or (b, a) in apex, f"segment {points[a]}-{points[b]} is not an edge"
    for (a, b), c in apex.items():
        if (b, a) not in apex or frozenset((a, b)) in fixed:
            continue
        d = apex[(b, a)]
        det = incircle(points[a], points[b], points[c], points[d])
        first = min((a, b, c, d), key=lambda v: (points[v][1], points[v][0]))
        assert det < 0 or (det == 0 and first in (c, d)), f"edge {points[a]}-{points[b]} breaks the rule"


def canonical(triangles) -> list[tuple[int, int, int]]:
    out = []
    for t in triangles:
        i = min(range(3), key=lambda k: t[k])
        out.append(tuple(int(t[(i + k) % 3]) for k in range(3)))
    return sorted(out)


# ---------------------------------------------------------------------------
# Independence


def test_shares_no_code_with_the_codec():
    """Only the standard library, numpy and zstandard: no codec, no schema.py, no
    triangulation library."""
    tree = ast.parse(REFERENCE.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "a relative import"
            imported.add(node.module.split(".")[0])
    assert imported <= set(sys.stdlib_module_names) | {"numpy", "zstandard"}, imported


def test_runs_standalone(tmp_path):
    """`python reference_decoder.py in.atm out.npy`, in a fresh interpreter that loads
    neither the codec nor a triangulation library; bad input: one line, exit 1."""
    out = tmp_path / "out.npy"
    src = VECTORS / "walls_ties.atm"
    run = subprocess.run([sys.executable, str(REFERENCE), str(src), str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert_same_image(np.load(out), read_image(VECTORS / "walls_ties.png"))
    bad = tmp_path / "bad.atm"
    bad.write_bytes(src.read_bytes()[:-20])
    run = subprocess.run([sys.executable, str(REFERENCE), str(bad), str(tmp_path / "x.npy")], capture_output=True, text=True)
    assert run.returncode == 1 and len(run.stderr.strip().splitlines()) == 1 and "truncated" in run.stderr
    assert not (tmp_path / "x.npy").exists()
    copy = tmp_path / "copy.atm"
    copy.write_bytes(src.read_bytes())
    run = subprocess.run([sys.executable, str(REFERENCE), str(copy), str(copy)], capture_output=True, text=True)
    assert run.returncode == 1 and "overwrite the input" in run.stderr
    assert copy.read_bytes() == src.read_bytes()
    named = tmp_path / "image.data"  # written under the name given, no .npy added
    assert subprocess.run([sys.executable, str(REFERENCE), str(src), str(named)]).returncode == 0
    assert_same_image(np.load(named), np.load(out))
    probe = (f"import importlib.util, sys; s = importlib.util.spec_from_file_location('r', {str(REFERENCE)!r}); "
             "m = importlib.util.module_from_spec(s); s.loader.exec_module(m); "
             "print(sorted({'codec', 'format_spec', 'triangle', 'scipy'} & set(sys.modules)))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=tmp_path)
    assert run.stdout.strip() == "[]", run.stdout + run.stderr


# ---------------------------------------------------------------------------
# Conformance files


def test_every_conformance_file_is_tested():
    assert {"lattice_ties", "rings_ties", "walls_ties", "listed_ties", "listed_not_delaunay",
            "holes_float", "bands_gray8", "rgb8_grid", "gray16_scene", "float_elevation"} <= set(CASES)


def assert_built_bands_follow_the_rule(data: bytes) -> int:
    """Every band whose triangles the decoder built obeys §4.2.5 by brute force; returns
    how many such bands there were."""
    _, bands = ref.read(data)
    built = [b for b in bands if not b.listed and b.triangles]
    for band in built:
        segments = [s for line in band.polylines for s in zip(line, line[1:])]
        assert_follows_the_rule(list(zip(band.xs, band.ys)), segments, band.triangles)
    return len(built)


@pytest.mark.parametrize("name", CASES)
def test_conformance_file_decodes_to_its_image(name):
    npy = VECTORS / f"{name}.npy"
    expected = np.load(npy) if npy.exists() else read_image(VECTORS / f"{name}.png")
    data = (VECTORS / f"{name}.atm").read_bytes()
    assert_same_image(ref.decode(data), expected)
    built = assert_built_bands_follow_the_rule(data)
    assert built == 0 if name.startswith(("listed", "line")) else built >= 1


# ---------------------------------------------------------------------------
# The triangulation rule


def lattice(width: int, height: int, spacing: int = 1) -> list[tuple[int, int]]:
    """Points in raster order, every `spacing` pixels, the far sides included."""
    xs = sorted(set(range(0, width, spacing)) | {width - 1})
    ys = sorted(set(range(0, height, spacing)) | {height - 1})
    return [(x, y) for y in ys for x in xs]


def test_cocircular_square_keeps_the_diagonal_away_from_its_first_corner():
    """On a unit lattice every square is a tie: each is split by the diagonal from its
    top-right to its bottom-left corner, the one that avoids its top-left (first in
    raster order) corner; a segment along the other diagonal wins over the rule."""
    w, h = 5, 4
    pts = lattice(w, h)
    at = {p: i for i, p in enumerate(pts)}
    expected = []
    for y in range(h - 1):
        for x in range(w - 1):
            tl, tr, bl, br = at[(x, y)], at[(x + 1, y)], at[(x, y + 1)], at[(x + 1, y + 1)]
            expected += [(tl, tr, bl), (tr, br, bl)]
    tris = ref.delaunay([p[0] for p in pts], [p[1] for p in pts], [])
    assert tris == sorted(expected)
    wall = (at[(1, 1)], at[(2, 2)])
    tris = ref.delaunay([p[0] for p in pts], [p[1] for p in pts], [wall])
    assert (at[(1, 1)], at[(2, 1)], at[(2, 2)]) in tris and (at[(1, 1)], at[(2, 2)], at[(1, 2)]) in tris
    assert len(set(tris) - set(expected)) == 2


@st.composite
def tie_scenes(draw):
    """Points full of exact ties (a lattice, concentric rings of lattice points on one
    circle each, a few random ones), at small and large scales, and segments taken from a triangulation that the
    rule would not choose (random convex flips of it), so they constrain it."""
    w, h = draw(st.integers(3, 30)), draw(st.integers(3, 30))
    pts = {(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)}
    spacing = draw(st.integers(1, 4))
    pts |= {p for p in lattice(w, h, spacing) if draw(st.integers(0, 9)) < 7}
    cx, cy = w // 2, h // 2
    for r2 in draw(st.lists(st.sampled_from([5, 25, 50, 65, 85]), max_size=2)):
        pts |= {(cx + dx, cy + dy) for dx in range(-10, 11) for dy in range(-10, 11)
                if dx * dx + dy * dy == r2 and 0 <= cx + dx < w and 0 <= cy + dy < h}
    for _ in range(draw(st.integers(0, 6))):
        pts.add((draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1))))
    # Scaling keeps every tie; large extents take the predicates past binary64's exact
    # range (products of coordinate differences beyond 2^53), up to the format's 2^20.
    scale = draw(st.sampled_from([1, 1, 3, 4099, 33000]))
    pts = sorted(((x * scale, y * scale) for x, y in pts), key=lambda p: (p[1], p[0]))
    tris = [list(t) for t in ref.delaunay([p[0] for p in pts], [p[1] for p in pts], [])]
    for _ in range(draw(st.integers(0, 30))):
        k = draw(st.integers(0, len(tris) - 1))
        i = draw(st.integers(0, 2))
        a, b, c = tris[k][i], tris[k][(i + 1) % 3], tris[k][(i + 2) % 3]
        other = [m for m, t in enumerate(tris) for j in range(3) if t[j] == b and t[(j + 1) % 3] == a]
        if not other:
            continue
        m = other[0]
        d = next(v for v in tris[m] if v not in (a, b))
        if orient(pts[a], pts[d], pts[c]) > 0 and orient(pts[d], pts[b], pts[c]) > 0:
            tris[k], tris[m] = [a, d, c], [d, b, c]
    edges = sorted({(min(t[j], t[(j + 1) % 3]), max(t[j], t[(j + 1) % 3])) for t in tris for j in range(3)})
    segments = [e for e in edges if draw(st.integers(0, 9)) == 0]
    return pts, segments, draw(st.randoms(use_true_random=False))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tie_scenes())
def test_triangulation_follows_the_rule_in_any_order(scene):
    """The result obeys the rule by brute force, equals the codec's (Triangle plus its
    canonical pass), and is the same for any insertion order, any numbering of the
    vertices and any order or direction of the segments."""
    pts, segments, rnd = scene
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    tris = ref.delaunay(xs, ys, segments)
    assert_follows_the_rule(pts, segments, tris)
    theirs = triangulate(np.array(pts, np.int64), np.array(segments, np.int64).reshape(-1, 2))
    assert canonical(theirs) == tris

    order = list(range(len(pts)))
    rnd.shuffle(order)
    shuffled = [(b, a) if rnd.random() < 0.5 else (a, b) for a, b in segments]
    rnd.shuffle(shuffled)
    assert ref.delaunay(xs, ys, shuffled, order=order) == tris

    renumber = list(range(len(pts)))  # new index of each old vertex
    rnd.shuffle(renumber)
    old = sorted(range(len(pts)), key=lambda i: renumber[i])
    again = ref.delaunay([xs[i] for i in old], [ys[i] for i in old], [(renumber[a], renumber[b]) for a, b in segments])
    assert canonical([[old[i] for i in t] for t in again]) == tris


def test_crossing_walls_and_walls_over_a_vertex_are_corrupt():
    pts = lattice(5, 5, 2)  # (0, 0), (2, 0), (4, 0), (0, 2), ...
    at = {p: i for i, p in enumerate(pts)}
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    with pytest.raises(ref.DecodeError, match="cross"):
        ref.delaunay(xs, ys, [(at[(0, 2)], at[(2, 4)]), (at[(0, 4)], at[(2, 2)])])
    with pytest.raises(ref.DecodeError, match="passes through"):
        ref.delaunay(xs, ys, [(at[(0, 0)], at[(4, 4)])])


def test_hilbert_point_inverts_the_distance_of_the_spec():
    for n in (1, 2, 4, 8, 16, 32):
        seen = set()
        for x in range(n):
            for y in range(n):
                d = ref.hilbert_distance(n, x, y)
                assert ref.hilbert_point(n, d) == (x, y)
                seen.add(d)
        assert seen == set(range(n * n))


# ---------------------------------------------------------------------------
# Random files against codec.decode


@st.composite
def images(draw) -> tuple[np.ndarray, dict]:
    """Small images of every kind the format stores, with steps (walls) and noise."""
    kind = draw(st.sampled_from(["gray8", "gray16", "rgb8", "rgb16", "float", "float_holes", "int_holes", "scene"]))
    h, w = draw(st.integers(1, 28)), draw(st.integers(1, 28))
    seed = draw(st.integers(0, 2**32 - 1))
    if kind == "scene":  # range data: objects with walls, at sizes where walls pay
        h, w = draw(st.integers(40, 56)), draw(st.integers(56, 72))
        return range_scene(w, h, seed=seed, dtype=draw(st.sampled_from([np.uint8, np.uint16]))), {}
    rng = np.random.default_rng(seed)
    surface = rng.normal(size=(h, w)).cumsum(0).cumsum(1)
    surface += np.where(np.arange(w) >= draw(st.integers(0, w)), draw(st.floats(-40, 40)), 0)
    unit = (surface - surface.min()) / max(np.ptp(surface), 1e-9)
    options: dict = {}
    if draw(st.booleans()):
        options["mesher"] = "uniform"
    if h > 4 and draw(st.booleans()):
        options["band_height"] = draw(st.integers(2, h))
    if kind in ("gray8", "int_holes"):
        image = np.round(255 * unit).astype(np.uint8)
    elif kind == "gray16":
        image = np.round(65535 * unit).astype(np.uint16)
    elif kind in ("rgb8", "rgb16"):
        top = 255 if kind == "rgb8" else 65535
        image = np.round(top * np.stack([unit, unit[::-1], unit.T[:h, :w] if h == w else 1 - unit], -1))
        image = image.astype(np.uint8 if kind == "rgb8" else np.uint16)
    else:
        image = (100 * surface).astype(np.float32)
    holes = rng.random((h, w)) < draw(st.sampled_from([0.0, 0.1, 0.4]))
    if kind == "float_holes":
        # NaN, or holes all +inf or all -inf, which NDAT keeps (ATM.md section 4.5)
        image[holes] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    elif kind == "int_holes":
        image[holes] = 0
        options["nodata"] = 0
    return image, options


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images())
def test_random_files_decode_as_the_codec_decodes_them(case):
    image, options = case
    data = codec.encode(image, **options)
    assert_same_image(ref.decode(data), codec.decode(data))
    assert_built_bands_follow_the_rule(data)


def flipped(mesh: Mesh, rnd) -> Mesh:
    """The mesh with some diagonals flipped where the quadrilateral is convex: still a
    tiling, no longer the triangulation of §4.2.5, so the codec lists it."""
    v, t = mesh.vertices, [list(map(int, tri)) for tri in mesh.triangles]
    walls = {frozenset(map(int, p)) for line in mesh.constraints for p in zip(line, line[1:])}
    for _ in range(rnd.randint(1, 12)):
        k, i = rnd.randrange(len(t)), rnd.randrange(3)
        a, b, c = t[k][i], t[k][(i + 1) % 3], t[k][(i + 2) % 3]
        other = [m for m, u in enumerate(t) for j in range(3) if u[j] == b and u[(j + 1) % 3] == a]
        if not other or frozenset((a, b)) in walls:
            continue
        d = next(x for x in t[other[0]] if x not in (a, b))
        if orient(v[a], v[d], v[c]) > 0 and orient(v[d], v[b], v[c]) > 0:
            t[k], t[other[0]] = [a, d, c], [d, b, c]
    return Mesh(v, mesh.values, np.array(t, np.int64), mesh.width, mesh.height, mesh.constraints)


def connectivities(data: bytes) -> set[int]:
    from codec import frames

    return {schema.MeshPayload.parse(frames.decompress(p, 1 << 30, "MESH"), sample_type=0, channels=1).connectivity
            for _, kind, p in chunks(data) if kind == schema.MESH}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**32 - 1), st.integers(2, 40), st.integers(2, 40),
       st.sampled_from([np.uint8, np.uint16]), st.sampled_from([1, 3]), st.integers(0, 150), st.randoms(use_true_random=False))
def test_listed_triangles_decode_as_the_codec_decodes_them(seed, w, h, dtype, channels, extra, rnd):
    mesh = random_mesh(seed, w, h, dtype=dtype, channels=channels, extra=extra)
    other = flipped(mesh, rnd) if len(mesh.triangles) else mesh
    data = container.pack(other)
    if canonical(other.triangles) != canonical(mesh.triangles):
        assert connectivities(data) == {schema.LISTED}
    assert_same_image(ref.decode(data), codec.decode(data))


# ---------------------------------------------------------------------------
# The corpus


# A photo, the range image with the most vertices and walls, and a synthetic range
# scene: the other four corpus images decode equal too, at twice the CI time.
CORPUS_SUBSET = ["camera", "motorcycle_disp", "scene0"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CORPUS_SUBSET)
def test_corpus_decodes_as_the_codec_decodes_it(corpus, name):
    """At the default density (2.8 % of the pixels as vertices: 7,340 on camera)."""
    data = codec.encode(corpus[name])
    assert_same_image(ref.decode(data), codec.decode(data))


# ---------------------------------------------------------------------------
# Malformed input


def test_refuses_version_5_naming_both_versions():
    data = bytearray((VECTORS / "gray8_steps.atm").read_bytes())
    data[8:10] = struct.pack("<H", 5)
    with pytest.raises(ref.UnsupportedError, match=r"version 5.*version 6"):
        ref.decode(bytes(data))


def test_refuses_damaged_files_with_its_own_error():
    good = (VECTORS / "holes_float.atm").read_bytes()
    parts = chunks(good)
    mesh_at = next(i for i, (_, kind, _) in enumerate(parts) if kind == b"MESH")
    offset, _, payload = parts[mesh_at]
    raw = zstandard.ZstdDecompressor().decompress(payload)

    def with_mesh(new_raw: bytes, *, frame: bytes | None = None) -> bytes:
        frame = zstandard.ZstdCompressor().compress(new_raw) if frame is None else frame
        end = offset + 12 + len(payload)
        return good[:offset] + make_chunk(b"MESH", frame) + good[end:]

    cases = {
        "signature": b"\x89PNG\r\n\x1a\n" + good[8:],
        "CRC": good[:-20] + bytes([good[-20] ^ 1]) + good[-19:],
        "truncated": good[: len(good) // 2],
        "no declared size": with_mesh(raw, frame=zstandard.ZstdCompressor(write_content_size=False).compress(raw)),
        "bytes after the last field": with_mesh(raw + b"\0"),
        "connectivity 2": with_mesh(raw[:24] + b"\x02" + raw[25:]),
        "triangle_crc": with_mesh(raw[:26] + bytes([raw[26] ^ 1]) + raw[27:]),
        "unknown critical chunk": good[:offset] + make_chunk(b"ZZZZ", b"") + good[offset:],
        "a chunk between AHDR and QUNT": good[:32] + make_chunk(b"zzzz", b"") + good[32:],
    }
    for what, data in cases.items():
        with pytest.raises(ref.DecodeError):
            ref.decode(data)
        with pytest.raises(codec.ATMError):  # the codec agrees that each is bad
            codec.decode(data)
    # §4: the payload is one frame, so a byte after it is damage, for both decoders
    for frame in (zstandard.ZstdCompressor().compress(raw),
                  zstandard.ZstdCompressor(write_checksum=True).compress(raw)):
        assert_same_image(codec.decode(with_mesh(raw, frame=frame)), ref.decode(good))
        for extra in (b"\0", frame):
            with pytest.raises(ref.DecodeError, match="after the Zstandard frame"):
                ref.decode(with_mesh(raw, frame=frame + extra))
            with pytest.raises(codec.CorruptError, match="after its zstd frame"):
                codec.decode(with_mesh(raw, frame=frame + extra))
    # an unknown ancillary chunk is skipped
    assert_same_image(ref.decode(good[:offset] + make_chunk(b"zzzz", b"?") + good[offset:]), ref.decode(good))


def test_walls_of_a_one_pixel_band_join_neighbouring_vertices():
    """In a band one pixel high there are no triangle edges; constraint 6 on the line:
    a wall segment may not skip a vertex."""
    v, values = np.array([[0, 0], [3, 0], [9, 0]]), np.array([10, 200, 30], np.uint8)
    ok = container.pack(Mesh(v, values, np.zeros((0, 3), np.int64), 10, 1, [np.array([0, 1, 2, 1])]))
    assert_same_image(ref.decode(ok), codec.decode(ok))
    bad = container.pack(Mesh(v, values, np.zeros((0, 3), np.int64), 10, 1, [np.array([0, 2])]))
    with pytest.raises(ref.DecodeError, match="skips a vertex"):
        ref.decode(bad)


def run_lengths(holes: np.ndarray) -> list[int]:
    """§4.6's runs: data first (maybe 0 long), then holes, alternating."""
    flat = holes.ravel()
    edges = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.r_[0, edges, flat.size]
    runs = np.diff(bounds).tolist()
    return ([0] if flat[0] else []) + runs


def test_the_row_two_bands_share_has_one_mask():
    """§4.6: the shared row MUST have the same mask in both bands; a file whose second
    MASK says otherwise is refused by both decoders."""
    from codec import holemask
    from codec.coding import varints

    rng = np.random.default_rng(0)
    image = (rng.normal(size=(12, 10)).cumsum(0).cumsum(1) * 10 + 128).clip(1, 255).astype(np.uint8)
    image[rng.random(image.shape) < 0.2] = 0
    data = codec.encode(image, nodata=0, band_height=6)
    # the second band's mask, a MASK chunk or (§4.11) a HOLE chunk
    offset, kind, payload = [p for p in chunks(data) if p[1] in (b"MASK", b"HOLE")][1]
    fixed = payload if kind == b"HOLE" else zstandard.ZstdDecompressor().decompress(payload)
    y0, rows = struct.unpack_from("<II", fixed)
    holes = image[y0 : y0 + rows] == 0
    assert_same_image(ref.decode(data), codec.decode(data))
    holes[0, np.flatnonzero(~holes[0])[0]] = True  # one more hole on the shared row only
    runs = run_lengths(holes)
    body = bytes(varints(np.array(runs)))
    raw = struct.pack("<IIII", y0, rows, len(runs), len(body)) + body
    for chunk in (make_chunk(b"MASK", zstandard.ZstdCompressor().compress(raw)),
                  make_chunk(b"HOLE", holemask.encode(y0, holes))):
        bad = data[:offset] + chunk + data[offset + 12 + len(payload):]
        with pytest.raises(ref.DecodeError, match="shared by two bands"):
            ref.decode(bad)
        with pytest.raises(codec.CorruptError, match="which two bands share"):
            codec.decode(bad)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(CASES), st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=4))
def test_damaged_mesh_payloads_give_its_own_error_or_an_image(name, edits):
    """Bytes changed inside a decompressed MESH payload, the frame and CRC made anew so
    that the damage reaches the parser: the decoder either refuses with DecodeError or
    returns an image of the header's shape, never another exception."""
    good = (VECTORS / f"{name}.atm").read_bytes()
    parts = chunks(good)
    offset, _, payload = next(p for p in parts if p[1] == b"MESH")
    raw = bytearray(zstandard.ZstdDecompressor().decompress(payload))
    for at, value in edits:
        raw[at % len(raw)] = value
    frame = zstandard.ZstdCompressor().compress(bytes(raw))
    data = good[:offset] + make_chunk(b"MESH", frame) + good[offset + 12 + len(payload):]
    try:
        out = ref.decode(data)
    except ref.DecodeError:
        return
    assert out.shape[:2] == ref.decode(good).shape[:2]


@pytest.mark.parametrize("hole", [np.inf, -np.inf])
def test_infinite_holes_come_back_as_they_were(hole):
    """Float holes that are all +inf (or all -inf) are stored as an infinite NDAT value
    (ATM.md section 4.5) and both decoders give them back."""
    image = np.linspace(0, 100, 30 * 40, dtype=np.float32).reshape(30, 40)
    image[5:9, 5:12] = hole
    data = codec.encode(image, max_error=0.5)
    out = ref.decode(data)
    assert_same_image(out, codec.decode(data))
    assert (out[5:9, 5:12] == hole).all()


def test_both_decoders_apply_the_limits_of_section_8():
    """§8's limits are normative numbers: the decoded image's bytes, and a MESH
    payload longer than its own counts can use, are refused by both decoders."""
    good = (VECTORS / "gray8_steps.atm").read_bytes()
    big = good[:10] + make_chunk(b"AHDR", struct.pack("<IIBB", 16384, 16384, 1, 3)) + good[10 + 22:]
    with pytest.raises(ref.DecodeError, match="2\\^30 bytes"):
        ref.decode(big)
    with pytest.raises(codec.LimitError):
        codec.decode(big)
    offset, _, payload = next(p for p in chunks(good) if p[1] == b"MESH")
    raw = zstandard.ZstdDecompressor().decompress(payload)
    assert raw[-4:] == b"\0\0\0\0"  # an empty triangles section ends the payload
    padded = raw[:-4] + struct.pack("<I", 4000) + bytes(4000)  # 4,000 bytes no count allows
    bad = good[:offset] + make_chunk(b"MESH", zstandard.ZstdCompressor().compress(padded)) + good[offset + 12 + len(payload):]
    with pytest.raises(ref.DecodeError, match="more than its counts can use"):
        ref.decode(bad)
    with pytest.raises(codec.CorruptError, match="its counts can use at most"):
        codec.decode(bad)


def test_the_axis_chunk_gives_the_shape_and_is_checked():
    """§4.9: an `axis` chunk makes a gray image H x W x 1 in both decoders; one with a
    payload, a second one or one after the first band is refused by both."""
    data = (VECTORS / "axis_gray8_holes.atm").read_bytes()
    assert_same_image(ref.decode(data), codec.decode(data))
    assert ref.decode(data).shape == (24, 32, 1)
    axis = make_chunk(b"axis", b"")
    at = data.index(axis)
    without = data[:at] + data[at + len(axis):]
    assert_same_image(ref.decode(without), codec.decode(without))
    assert ref.decode(without).shape == (24, 32)
    end = len(data) - 12  # AEND
    bad = {
        "payload": data[:at] + make_chunk(b"axis", b"\0") + data[at + len(axis):],
        "twice": data[:at] + axis + data[at:],
        "after a band": without[: end - len(axis)] + axis + without[end - len(axis):],
    }
    for what, file in bad.items():
        with pytest.raises(ref.DecodeError, match="axis chunk"):
            ref.decode(file)
        with pytest.raises(codec.CorruptError, match="axis chunk"):
            codec.decode(file)


def test_both_decoders_bound_the_work_by_the_stored_bytes():
    """§8: a frame may declare at most 2^20 + 1024 S bytes, and a connectivity-1 band
    may ask to triangulate at most 2^16 + 64 S vertices (S: the chunk's stored length);
    both decoders refuse more before doing the work."""
    def file(width: int, height: int, mesh: bytes) -> bytes:
        head = make_chunk(b"AHDR", struct.pack("<IIBB", width, height, 0, 1))
        return ref.SIGNATURE + struct.pack("<H", 6) + head + make_chunk(b"MESH", mesh) + make_chunk(b"AEND", b"")

    bomb = file(4096, 4096, zstandard.ZstdCompressor().compress(bytes(3 << 20)))
    with pytest.raises(ref.DecodeError, match="declares"):
        ref.decode(bomb)
    with pytest.raises(codec.LimitError):
        codec.decode(bomb)
    n = 70_000  # > 2^16 + 64 S for this small chunk, within 300 x 300 pixels
    fixed = struct.pack("<IIIIIIBBIH", 0, 300, n, 0, 0, 0, 1, 0, 0, 1)
    raw = fixed + struct.pack("<I", 0) * 3 + struct.pack("<I", 1) + b"\0" + struct.pack("<I", 0) * 3
    cheap = file(300, 300, zstandard.ZstdCompressor().compress(raw))
    with pytest.raises(ref.DecodeError, match="so few stored bytes"):
        ref.decode(cheap)
    with pytest.raises(codec.LimitError, match="rebuild"):
        codec.decode(cheap)
