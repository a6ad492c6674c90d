"""The .atm container: exact round trips, chunk rules, and errors on damaged bytes."""

from __future__ import annotations

import dataclasses
import io
import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import container
from codec.decoding import render
from codec.coding import canonical_triangles
from codec.errors import ATMError, CorruptError, FormatError, TruncatedError, UnsupportedError
from codec.triangulate import triangulate
from codec.format_spec import schema
from tests.conftest import chunks, random_mesh

mesh_args = st.tuples(
    st.integers(0, 2**32 - 1),
    st.integers(1, 60),
    st.integers(1, 60),
    st.sampled_from([np.uint8, np.uint16]),
    st.sampled_from([1, 3]),
    st.integers(0, 200),
)


def canonical(m):
    """The mesh with vertices in raster order and triangles in canonical order: the
    form the container stores, whatever order the mesh was made in."""
    order = np.argsort(m.vertices[:, 1] * m.width + m.vertices[:, 0])
    inverse = np.empty(len(order), np.int64)
    inverse[order] = np.arange(len(order))
    tris = canonical_triangles(inverse[m.triangles])
    return m.vertices[order], m.values[order], tris, [inverse[c] for c in m.constraints]


def assert_same_mesh(a, b) -> None:
    assert (a.width, a.height, a.dtype, a.channels) == (b.width, b.height, b.dtype, b.channels)
    for p, q in zip(canonical(a)[:3], canonical(b)[:3]):
        np.testing.assert_array_equal(p, q)
    ca, cb = canonical(a)[3], canonical(b)[3]
    assert len(ca) == len(cb)
    for p, q in zip(ca, cb):
        np.testing.assert_array_equal(p, q)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mesh_args)
def test_pack_unpack_is_exact_for_arbitrary_meshes(args):
    seed, w, h, dtype, channels, extra = args
    mesh = random_mesh(seed, w, h, dtype=dtype, channels=channels, extra=extra)
    data = container.pack(mesh)
    header, bands = container.unpack(data)
    [(y0, back)] = bands
    assert y0 == 0
    assert (header.width, header.height, header.dtype, header.channels) == (w, h, np.dtype(dtype), channels)
    assert_same_mesh(mesh, back)
    assert container.pack(back) == data


def make_chunk(ctype: bytes, payload: bytes) -> bytes:
    return struct.pack("<I4s", len(payload), ctype) + payload + struct.pack("<I", zlib.crc32(ctype + payload))


@pytest.fixture(scope="module")
def sample_file() -> bytes:
    return container.pack(random_mesh(7, 20, 12, extra=30))


def test_layout_matches_spec(sample_file):
    assert sample_file[:8] == b"\x89ATM\r\n\x1a\n"
    assert struct.unpack_from("<H", sample_file, 8) == (schema.VERSION,)
    types = [c[1] for c in chunks(sample_file)]
    assert types == [b"AHDR", b"MESH", b"AEND"]
    ahdr = chunks(sample_file)[0][2]
    assert struct.unpack("<IIBB", ahdr) == (20, 12, 0, 1)
    import zstandard

    mesh = zstandard.ZstdDecompressor().decompress(chunks(sample_file)[1][2])
    assert struct.unpack_from("<II", mesh) == (0, 12)  # y0, rows


def test_unknown_ancillary_chunk_is_skipped(sample_file):
    pos = chunks(sample_file)[1][0]
    data = sample_file[:pos] + make_chunk(b"tEXt", b"hello") + sample_file[pos:]
    np.testing.assert_array_equal(codec.decode(data), codec.decode(sample_file))


def test_unknown_critical_chunk_is_an_error(sample_file):
    pos = chunks(sample_file)[1][0]
    data = sample_file[:pos] + make_chunk(b"QQQQ", b"") + sample_file[pos:]
    with pytest.raises(UnsupportedError, match="critical chunk QQQQ"):
        codec.decode(data)


def test_bad_crc_names_the_chunk(sample_file):
    pos, _, payload = chunks(sample_file)[1]
    data = bytearray(sample_file)
    data[pos + 8 + len(payload) // 2] ^= 0x40
    with pytest.raises(CorruptError, match="MESH.*CRC"):
        codec.decode(bytes(data))


def test_every_truncation_is_a_clear_error(sample_file):
    for n in range(len(sample_file)):
        with pytest.raises(FormatError):
            codec.decode(sample_file[:n])


def test_truncation_inside_a_chunk_is_truncated_error(sample_file):
    with pytest.raises(TruncatedError, match="ends inside chunk MESH"):
        codec.decode(sample_file[:-20])


def test_bytes_after_aend_are_ignored(sample_file):
    np.testing.assert_array_equal(codec.decode(sample_file + b"junk"), codec.decode(sample_file))


@pytest.mark.parametrize("version", [1, 2, 3, 4, 5, 7])
def test_other_versions_are_unsupported(sample_file, version):
    data = sample_file[:8] + struct.pack("<H", version) + sample_file[10:]
    with pytest.raises(UnsupportedError, match=f"version {version}; this codec reads version {schema.VERSION}"):
        codec.decode(data)


def test_not_an_atm_file():
    with pytest.raises(FormatError, match="not an .atm file"):
        codec.decode(b"\x89PNG\r\n\x1a\n" + bytes(40))


def test_mesh_invariants_are_checked(sample_file):
    import zstandard

    from codec import meshcode
    from codec.coding import canonical_triangles, hilbert_keys, triangle_crc, varints, zigzag
    from codec.mesh import doubled_areas

    header, [(_, mesh)] = container.unpack(sample_file)
    good = meshcode.encode_band(0, mesh)  # mesh came from a file: raster order, canonical

    def listed(triangles) -> dict:
        t = np.asarray(triangles)
        a = t[:, 0]
        fields = np.stack([np.diff(a, prepend=0), t[:, 1] - a - 1, t[:, 2] - a - 1], 1).ravel()
        return dict(connectivity=1 - 1, triangle_count=len(t), triangles=varints(fields),
                    triangle_crc=triangle_crc(t))

    def repack(**changes) -> bytes:
        fields = dict(good, **changes)
        raw = schema.MeshPayload.build(fields, sample_type=0, channels=1)
        payload = zstandard.ZstdCompressor().compress(raw)
        parts = chunks(sample_file)
        return sample_file[: parts[1][0]] + make_chunk(b"MESH", payload) + make_chunk(b"AEND", b"")

    flipped = mesh.triangles.copy()
    flipped[0] = flipped[0, [0, 2, 1]]
    beyond = mesh.triangles.copy()
    beyond[-1, 2] = len(mesh.vertices)
    keys = mesh.vertices[:, 1] * 20 + mesh.vertices[:, 0]
    on_lines = np.unique(np.concatenate(mesh.constraints)) if mesh.constraints else []
    free = np.delete(keys, on_lines)
    gaps = np.diff(free, prepend=-1) - 1
    gaps[-1] += 20 * 12
    # one wall from vertex 0 to vertex 1, both of which the positions also list
    one_wall = dict(polyline_count=1, polyline_index_count=2, polyline_lengths=varints([2]),
                    polyline_starts=varints(zigzag([keys[0]])),
                    polyline_steps=varints(zigzag(mesh.vertices[1] - mesh.vertices[0])))
    raster = dict(position_order=schema.POSITIONS_RASTER)
    twice = dict(one_wall, **raster, **meshcode.position_fields(np.diff(keys[:-2], prepend=-1) - 1))
    # along the Hilbert curve of the 20 x 12 band's 32 x 32 square: a free vertex moved
    # to (25, 3), in the square but not in the band, and a key beyond the square
    hx, hy = free % 20, free // 20
    hx[-1], hy[-1] = 25, 3
    moved = np.sort(hilbert_keys(hx, hy, 5))
    beyond_square = np.diff(np.sort(hilbert_keys(free % 20, free // 20, 5)), prepend=-1) - 1
    beyond_square[-1] += 32 * 32
    curve = dict(position_order=schema.POSITIONS_HILBERT)
    empty_step = dict(one_wall, polyline_steps=varints(zigzag([0, 0])))
    leaving = dict(one_wall, polyline_starts=varints(zigzag([0])), polyline_steps=varints(zigzag([-1, 0])))
    cases = {
        "wrongly oriented": listed(flipped),
        "beyond": listed(beyond),
        "outside": dict(raster, **meshcode.position_fields(gaps)),
        "lies outside the 20x12 band": dict(curve, **meshcode.position_fields(np.diff(moved, prepend=-1) - 1)),
        "lies outside": dict(curve, **meshcode.position_fields(beyond_square)),
        "unknown position order": dict(position_order=2),
        "cover": listed(mesh.triangles[:-1]),
        "leaves the": leaving,
        "step is empty": empty_step,
        "stored both on a polyline and by position": twice,
        "CRC mismatch": dict(triangle_crc=good["triangle_crc"] ^ 1),
        "hold": dict(positions=good["positions"] + b"\x01"),
        "more than 24": dict(positions=varints([25]) + good["positions"][1:]),
        "bytes of position bits": dict(position_bits=good["position_bits"] + b"\x00"),
    }
    # listed triangles whose areas still add up: one triangle twice in place of another
    # of the same area (a hole where that one was)
    areas = doubled_areas(mesh.vertices, mesh.triangles)
    first, second = next((i, j) for i in range(len(areas)) for j in range(i + 1, len(areas))
                         if areas[i] == areas[j])
    twice_one = canonical_triangles(np.delete(np.vstack([mesh.triangles, mesh.triangles[first]]), second, axis=0))
    cases["overlap: they lie on the same side of a shared edge"] = listed(twice_one)
    np.testing.assert_array_equal(codec.decode(repack()), codec.decode(sample_file))
    np.testing.assert_array_equal(codec.decode(repack(**listed(mesh.triangles))), codec.decode(sample_file))
    for message, change in cases.items():
        with pytest.raises(CorruptError, match=message):
            codec.decode(repack(**change))
    # refused before any decoder runs, so the GL backend gives the same error
    with pytest.raises(CorruptError, match="overlap"):
        codec.decode(repack(**listed(twice_one)), backend="gl")


def test_both_position_orders_give_the_same_mesh():
    """A band whose free vertices are stored in raster order and the same band stored
    along the Hilbert curve decode to the same vertices, triangles and samples."""
    import zstandard

    from codec import meshcode
    from codec.coding import hilbert_keys, hilbert_levels

    mesh = random_mesh(11, 37, 23, extra=60)
    data = container.pack(mesh)
    mesh_at = chunks(data)[1][0]
    fields = meshcode.encode_band(0, mesh)
    on_lines = np.unique(np.concatenate(mesh.constraints)) if mesh.constraints else []
    free = np.delete(mesh.vertices, on_lines, axis=0)
    keys = {
        schema.POSITIONS_RASTER: np.sort(free[:, 1] * 37 + free[:, 0]),
        schema.POSITIONS_HILBERT: np.sort(hilbert_keys(free[:, 0], free[:, 1], hilbert_levels(37, 23))),
    }
    decoded = []
    for order, k in keys.items():
        changed = dict(fields, position_order=order, **meshcode.position_fields(np.diff(k, prepend=-1) - 1))
        raw = schema.MeshPayload.build(changed, sample_type=0, channels=1)
        one = data[:mesh_at] + make_chunk(b"MESH", zstandard.ZstdCompressor().compress(raw)) + make_chunk(b"AEND", b"")
        decoded.append(codec.decode_mesh(one))
    for got in decoded:
        np.testing.assert_array_equal(got.vertices, decoded[0].vertices)
        np.testing.assert_array_equal(got.triangles, decoded[0].triangles)
        np.testing.assert_array_equal(got.values, decoded[0].values)
    np.testing.assert_array_equal(codec.decode(data), render(decoded[0]))


@pytest.mark.parametrize("bits", [0, 1, 3, 8])
def test_position_bits_round_trip_and_padding_is_checked(bits):
    """Any split of the position gaps decodes to the same vertices; the packed low
    bits must fill their bytes exactly, padded with zeros."""
    import zstandard

    from codec import meshcode

    grid = np.stack(np.meshgrid(np.arange(0, 15, 5), np.arange(0, 9, 4)), -1).reshape(-1, 2)
    mesh = codec.Mesh(grid, np.arange(9, dtype=np.uint8) * 20, triangulate(grid), 11, 9)
    data = container.pack(mesh)
    mesh_at = chunks(data)[1][0]

    def with_fields(**changes) -> bytes:
        fields = dict(meshcode.encode_band(0, mesh), **changes)
        raw = schema.MeshPayload.build(fields, sample_type=0, channels=1)
        return data[:mesh_at] + make_chunk(b"MESH", zstandard.ZstdCompressor().compress(raw)) + make_chunk(b"AEND", b"")

    keys = np.sort(grid[:, 1] * 11 + grid[:, 0])
    split = dict(meshcode.position_fields(np.diff(keys, prepend=-1) - 1, bits=bits), position_order=schema.POSITIONS_RASTER)
    np.testing.assert_array_equal(codec.decode(with_fields(**split)), codec.decode(data))
    if 9 * bits % 8:
        padded = dict(split, position_bits=split["position_bits"][:-1] + bytes([split["position_bits"][-1] | 1]))
        with pytest.raises(CorruptError, match="padded with ones"):
            codec.decode(with_fields(**padded))


def test_a_wall_over_a_vertex_is_corrupt():
    """A rebuilt triangulation splits such a wall at the vertex, so its step would be
    no triangle edge; the decoder must refuse the file, not draw a different mesh."""
    import zstandard

    from codec import meshcode
    from codec.coding import varints, zigzag

    grid = np.stack(np.meshgrid(np.arange(3), np.arange(3)), -1).reshape(-1, 2)
    mesh = codec.Mesh(grid, np.arange(9, dtype=np.uint8), triangulate(grid), 3, 3)
    fields = meshcode.encode_band(0, mesh)
    free = np.setdiff1d(np.arange(9), [0, 2])  # keys of the pixels off the wall
    fields.update(polyline_count=1, polyline_index_count=2, polyline_lengths=varints([2]),
                  polyline_starts=varints(zigzag([0])), polyline_steps=varints(zigzag([2, 0])),
                  position_order=schema.POSITIONS_RASTER,
                  **meshcode.position_fields(np.diff(free, prepend=-1) - 1))
    raw = schema.MeshPayload.build(fields, sample_type=0, channels=1)
    data = container.pack(mesh)
    mesh_at = chunks(data)[1][0]
    bad = data[:mesh_at] + make_chunk(b"MESH", zstandard.ZstdCompressor().compress(raw)) + make_chunk(b"AEND", b"")
    with pytest.raises(CorruptError, match="passes over a vertex"):
        codec.decode(bad)


def test_delaunay_connectivity_is_not_stored(sample_file):
    import zstandard

    raw = zstandard.ZstdDecompressor().decompress(chunks(sample_file)[1][2])
    parsed = schema.MeshPayload.parse(raw, sample_type=0, channels=1)
    assert parsed.connectivity == schema.DELAUNAY and parsed.triangles == b""


def test_decompression_bomb_is_refused_before_allocation():
    import zstandard

    header = schema.Header.build(dict(width=100, height=100, sample_type=0, channels=1))
    bomb = zstandard.ZstdCompressor().compress(bytes(50_000_000))
    data = (
        schema.FileHeader.build(dict(version=schema.VERSION))
        + make_chunk(b"AHDR", header)
        + make_chunk(b"MESH", bomb)
        + make_chunk(b"AEND", b"")
    )
    with pytest.raises(codec.LimitError, match="decompression bomb"):
        codec.decode(data)


def test_huge_declared_image_is_refused_quickly():
    header = schema.Header.build(dict(width=100_000, height=100_000, sample_type=0, channels=1))
    data = schema.FileHeader.build(dict(version=schema.VERSION)) + make_chunk(b"AHDR", header) + make_chunk(b"AEND", b"")
    with pytest.raises(codec.LimitError, match="pixels"):
        codec.decode(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_raise_only_atm_error(data):
    with pytest.raises(ATMError):
        codec.decode(data)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_files_decode_or_raise_atm_error(sample_file, data):
    buf = bytearray(sample_file)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(buf) - 1))
        buf[i] = data.draw(st.integers(0, 255))
    try:
        image = codec.decode(bytes(buf))
    except ATMError:
        return
    assert image.shape == (12, 20)


def test_tall_sliver_fans_are_refused_before_rendering(monkeypatch):
    """A mesh of tall slivers has legal areas but would cost time out of proportion to
    its size; the limit on the triangles' total row extent refuses it."""
    from codec import limits
    from codec.mesh import Mesh, validate
    from codec.triangulate import triangulate

    h = 200
    # a fan from the top-left corner to every pixel of the right column
    vertices = np.array([[0, 0], [0, h - 1]] + [[3, y] for y in range(h)])
    mesh = Mesh(vertices, np.zeros(len(vertices), np.uint8), triangulate(vertices), 4, h)
    data = container.pack(mesh)  # within the default limits
    monkeypatch.setattr(limits, "MIN_TRIANGLE_ROWS", 0)
    with pytest.raises(codec.LimitError, match="rows in all"):
        validate(mesh)
    with pytest.raises(codec.LimitError, match="rows in all"):
        codec.decode(data)


def test_reading_the_header_reads_no_band(sample_file):
    """Opening a file (e.g. Pillow's _open) reads the header chunks and stops at the
    first band's chunk head, so a huge band costs nothing until it is decoded."""
    import io

    mesh_at = chunks(sample_file)[1][0]
    stream = io.BytesIO(sample_file[: mesh_at + 8])  # the MESH chunk's head only
    header = container.read_header(stream)
    assert (header.width, header.height) == (20, 12)
    assert stream.tell() == mesh_at + 8


@pytest.mark.parametrize("step", [1, 3, 12, 200])
def test_quantised_samples_round_trip_within_their_steps(step):
    """meshcode.quantise leaves every sample within its vertex's step of the target
    (half a step unless the sample range was in the way), a file stores those samples
    exactly, and the steps shrink as fans grow."""
    from codec import meshcode
    from codec.mesh import doubled_areas

    mesh = random_mesh(3, 40, 30, extra=80)
    target = mesh.values.astype(np.int64)
    quantised = meshcode.quantise(dataclasses.replace(mesh), step, top_pinned=False)
    steps = meshcode.vertex_steps(mesh.vertices, mesh.triangles, step, False)
    err = np.abs(quantised.values.astype(np.int64) - target)
    inner = (target >= steps) & (target <= 255 - steps)  # rounding needs no range fix
    assert (err <= steps).all() and (err[inner] <= steps[inner] / 2).all()
    out = io.BytesIO()
    writer = container.Writer(out, container.Header(40, 30, np.dtype(np.uint8), 1))
    writer.write_band(0, quantised, step)
    writer.close()
    _, [(_, back)] = container.unpack(out.getvalue())
    assert_same_mesh(quantised, back)
    fan = np.bincount(mesh.triangles.ravel(), np.repeat(doubled_areas(mesh.vertices, mesh.triangles), 3))
    by_fan = steps[np.argsort(fan, kind="stable")]
    assert (np.diff(by_fan) <= 0).all()
    if step > 1 and not np.array_equal(mesh.values, quantised.values):
        with pytest.raises(ValueError, match="quantise"):
            meshcode.encode_band(0, mesh, step)


def test_value_step_option():
    """A larger base step gives a smaller file; step 1 keeps the fitted samples."""
    image = (np.add.outer(np.arange(40), np.arange(50)) * 2 + np.random.default_rng(0).integers(0, 9, (40, 50))).astype(np.uint8)
    sizes = [len(codec.encode(image, value_step=step, points=200)) for step in (1, 5, 16)]
    assert sizes[0] > sizes[1] > sizes[2]
    with pytest.raises(codec.OptionError, match="value_step"):
        codec.encode(image, value_step=0)


def test_a_mesh_given_without_its_triangulation_vouched_for_is_still_checked_for_tiling() -> None:
    """write_band skips the edge sort only for a mesh the encoder triangulated as a
    decoder will (delaunay=True); any other mesh is checked whole: here two triangles
    of the right total area that overlap and leave a gap."""
    from codec.mesh import Mesh

    v = np.array([[0, 0], [4, 0], [0, 4], [4, 4], [2, 2]], np.int64)
    good = np.array([[0, 1, 4], [1, 3, 4], [3, 2, 4], [2, 0, 4]], np.int64)
    # the same area: the top triangle twice, the bottom one missing
    bad = np.array([[0, 1, 4], [0, 1, 4], [1, 3, 4], [2, 0, 4]], np.int64)
    values = np.full(5, 7, np.uint8)
    for triangles, delaunay in ((good, None), (good, True)):
        writer = container.Writer(io.BytesIO(), container.Header(5, 5, np.dtype(np.uint8), 1))
        writer.write_band(0, Mesh(v, values, triangles, 5, 5, []), 1, delaunay)
    for delaunay in (None, False):
        writer = container.Writer(io.BytesIO(), container.Header(5, 5, np.dtype(np.uint8), 1))
        with pytest.raises(CorruptError, match="same side|tile"):
            writer.write_band(0, Mesh(v, values, bad, 5, 5, []), 1, delaunay)


def test_a_reader_decompresses_every_frame_with_its_own_decompressor(monkeypatch) -> None:
    """One zstd decompressor a decode, made by the reader and used for all its frames
    (meta, MASK and each band's MESH), not one per frame."""
    import zstandard

    rng = np.random.default_rng(3)
    image = rng.integers(0, 200, (40, 30)).astype(np.uint16)
    image[5:15, 4:12] = 65535  # a compact void: its band's mask as runs (MASK)
    data = codec.encode(image, points=120, band_height=8, nodata=65535, metadata={"units": "m"})
    kinds = [kind for _, kind, _ in chunks(data)]
    assert kinds.count(schema.MESH) > 1 and schema.MASK in kinds and schema.META in kinds
    made = []
    real = zstandard.ZstdDecompressor

    def counted(*args, **kwargs):
        made.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(zstandard, "ZstdDecompressor", counted)
    decoded = codec.decode(data)
    assert (decoded[image == 65535] == 65535).all() and decoded.shape == image.shape
    assert len(made) == 1


def test_a_reader_triangulates_its_bands_in_its_own_buffers(monkeypatch):
    """Each Reader owns the triangulation's buffers and reuses them band after band (no
    buffers shared between readers, so threads decoding files never meet); the meshes
    are those of a fresh triangulation, and a refused band leaves the buffers sound."""
    from codec import triangulate as triangulate_module

    rng = np.random.default_rng(5)
    image = (np.add.outer(np.arange(96), np.arange(80)) + rng.integers(0, 40, (96, 80))).astype(np.uint8)
    data = codec.encode(image, points=300, band_height=24)
    calls = []
    real = triangulate_module.Delaunay.triangles_and_crc

    def counted(self, *args, **kwargs):
        calls.append(id(self))
        return real(self, *args, **kwargs)

    with monkeypatch.context() as patch:
        patch.setattr(triangulate_module.Delaunay, "triangles_and_crc", counted)
        first, second = container.Reader(io.BytesIO(data)), container.Reader(io.BytesIO(data))
        owned = list(first)
    assert len(owned) == 4 and calls == [id(first._triangulator)] * 4
    assert first._triangulator is not second._triangulator
    # a refused triangulation (two walls crossing) leaves the buffers sound for the next
    with pytest.raises(ATMError):
        second._triangulator.triangles_and_crc(
            np.array([[0, 0], [4, 4], [0, 4], [4, 0]]), np.array([[0, 1], [2, 3]]), strict=True)
    reused = list(second)
    # the meshes of a fresh kernel call per band
    with monkeypatch.context() as patch:
        patch.setattr(triangulate_module.Delaunay, "triangles_and_crc",
                      lambda self, v, w=None, strict=False: triangulate_module.delaunay_and_crc(v, w, strict=strict))
        fresh = list(container.Reader(io.BytesIO(data)))
    for (y0, a), (y1, b), (y2, c) in zip(owned, reused, fresh):
        assert y0 == y1 == y2
        assert np.array_equal(a.triangles, c.triangles) and np.array_equal(b.triangles, c.triangles)
        assert np.array_equal(a.vertices, c.vertices)
