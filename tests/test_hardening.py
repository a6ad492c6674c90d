"""Hostile files for the decoder side (issue #17): each is built here for the current
format version and must be refused with an ATMError quickly, from every entry point."""

from __future__ import annotations

import io
import json
import subprocess
import sys
import time

import numpy as np
import pytest
from PIL import Image

import codec
import codec.pil  # noqa: F401  (registers the plugin)
from codec import container, frames, limits
from codec.mesh import Mesh
from codec.triangulate import triangulate
from codec.format_spec import schema


def _chunk(ctype: bytes, payload: bytes) -> bytes:
    return container._chunk(ctype, payload)


def _file(width: int, height: int, *middle: bytes, sample_type: int = 0, channels: int = 1, bands: bytes | None = None) -> bytes:
    """Signature, AHDR, the given chunks, then a valid mesh of the image and AEND."""
    head = schema.FileHeader.build(dict(version=schema.VERSION)) + _chunk(
        schema.HEADER, schema.Header.build(dict(width=width, height=height, sample_type=sample_type, channels=channels))
    )
    if bands is None:
        v = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.int64)
        mesh = Mesh(v, np.zeros(4, np.uint8), triangulate(v), width, height, [])
        body = container.pack(mesh)
        bands = body[len(head):]  # its chunks after AHDR
    return head + b"".join(middle) + bands


def _meta(text: bytes) -> bytes:
    return _chunk(schema.META, frames.compress(text))


def _every_entry_point(data: bytes, tmp_path, error=codec.ATMError) -> None:
    """Decode, info, read, StreamDecoder and Pillow all refuse the file with `error`
    (Pillow's as an OSError too)."""
    path = tmp_path / "bad.atm"
    path.write_bytes(data)
    with pytest.raises(error):
        codec.decode(data)
    with pytest.raises(error):
        codec.info(data)
    with pytest.raises(error):
        codec.read(path)
    with pytest.raises(error):
        list(codec.StreamDecoder(io.BytesIO(data)))
    with pytest.raises(error) as caught:
        with Image.open(path) as im:
            im.load()
    assert isinstance(caught.value, OSError)


@pytest.fixture
def quick():
    """Asserts the block took under `seconds` (generous: a loaded 2-core machine)."""
    start = time.perf_counter()

    def check(seconds: float = 2.0) -> None:
        assert time.perf_counter() - start < seconds

    return check


# ---------------------------------------------------------------- metadata

@pytest.mark.parametrize("text", [
    b'{"a": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",          # RecursionError before
    b'{"a": ' + b'{"b": ' * 5_000 + b"1" + b"}" * 5_000 + b"}",
])
def test_deep_metadata_is_refused_everywhere(text, tmp_path, quick):
    _every_entry_point(_file(8, 8, _meta(text)), tmp_path, codec.LimitError)
    quick(5.0)


@pytest.mark.parametrize("text", [
    b'{"a": "\\ud800"}',          # a lone surrogate: atm info crashed printing it
    b'{"a": NaN}', b'{"a": -Infinity}', b'{"a": 1e999}',   # not JSON; printed as such
    b'{"a": 1, "a": 2}',
    b'{"a": 1} x', b"[1]",
])
def test_metadata_must_be_strict_json(text, tmp_path):
    _every_entry_point(_file(8, 8, _meta(text)), tmp_path, codec.CorruptError)


def test_metadata_within_limits_still_reads(tmp_path):
    meta = {"units": "m", "nested": [[[{"k": "\u00e9\U0001f600"}]]], "x": 1.5e300}
    data = _file(8, 8, _meta(json.dumps(meta).encode()))
    assert codec.info(data)["metadata"] == meta
    path = tmp_path / "ok.atm"
    path.write_bytes(data)
    with Image.open(path) as im:
        assert "metadata" not in im.info  # not parsed by Image.open
        im.load()
        assert im.info["metadata"] == meta


def test_encoder_refuses_what_the_decoder_would():
    deep: list = []
    for _ in range(2_000):
        deep = [deep]
    image = np.zeros((4, 4), np.uint8)
    for bad in ({"a": deep}, {"a": "\ud800"}, {"a": float("nan")}):
        with pytest.raises(codec.OptionError):
            codec.encode(image, metadata=bad)


def test_atm_info_json_is_valid_and_errors_are_one_line(tmp_path):
    good = tmp_path / "good.atm"
    good.write_bytes(_file(8, 8, _meta(b'{"a": "\\u00e9"}')))
    out = subprocess.run([sys.executable, "-m", "codec", "info", "--json", str(good)], capture_output=True)
    assert out.returncode == 0 and json.loads(out.stdout)["metadata"] == {"a": "\u00e9"}
    for text in (b'{"a": "\\ud800"}', b'{"a": NaN}'):
        bad = tmp_path / "bad.atm"
        bad.write_bytes(_file(8, 8, _meta(text)))
        out = subprocess.run([sys.executable, "-m", "codec", "info", "--json", str(bad)], capture_output=True)
        assert out.returncode != 0 and out.stdout == b""
        assert len(out.stderr.decode().strip().splitlines()) == 1


def test_many_meta_chunks_have_one_budget(tmp_path, quick):
    """3,000 chunks of 1 MB of JSON each: 2.6 GB, then MemoryError, before."""
    one = frames.compress(b'{"k": "' + b"a" * (limits.MAX_METADATA_BYTES - 9) + b'"}')
    data = _file(8, 8, *[_chunk(schema.META, one)] * 3_000)
    assert len(data) < 1_000_000
    _every_entry_point(data, tmp_path, codec.LimitError)
    path = tmp_path / "bad.atm"
    with Image.open(path) as im:  # opening reads the header only
        assert im.size == (8, 8)
    quick(10.0)


def test_a_meta_chunk_cannot_declare_more_than_metadata_may_hold(tmp_path, quick):
    head = schema.ChunkHead.build(dict(length=1 << 30, type=schema.META))
    _every_entry_point(_file(8, 8, head + bytes(1000)), tmp_path, codec.LimitError)
    quick()


# ---------------------------------------------------------------- memory and time bombs

def _frame_declaring(data: bytes, size: int) -> bytes:
    """A zstd frame of `data` whose header declares `size` bytes instead (a lie)."""
    frame = bytearray(zstandard_frame(data))
    fhd = frame[4]
    assert fhd >> 6 == 2 and not fhd & 3  # a 4-byte size field, no dictionary
    at = 5 if fhd & 0x20 else 6  # after the window byte, which single-segment frames lack
    frame[at : at + 4] = size.to_bytes(4, "little")
    return bytes(frame)


def zstandard_frame(data: bytes) -> bytes:
    import zstandard

    return zstandard.ZstdCompressor(level=3, write_content_size=True).compress(data)


def test_a_mesh_frame_declaring_gigabytes_is_refused_before_decompressing(tmp_path, quick):
    """A 65 KB file whose MESH frame declares ~2 GB: 21 s and 2.1 GB before."""
    rng = np.random.default_rng(0)
    frame = _frame_declaring(rng.integers(0, 256, 66_000).astype(np.uint8).tobytes(), (1 << 31) - 1000)
    data = _file(16384, 8192, bands=_chunk(schema.MESH, frame) + _chunk(schema.END, b""))
    assert 65_000 < len(data) < 70_000
    _every_entry_point(data, tmp_path, codec.LimitError)
    quick()


def test_a_mesh_frame_declaring_more_than_its_counts_use_is_refused(tmp_path, quick):
    fixed = container._MESH_FIXED.pack(0, 512, 4, 2, 0, 0, 1, 0, 0, 1)
    frame = _frame_declaring(fixed + bytes(100_000), 900_000)
    data = _file(512, 512, bands=_chunk(schema.MESH, frame) + _chunk(schema.END, b""))
    _every_entry_point(data, tmp_path, codec.CorruptError)
    quick()


def _all_pixel_band(width: int, height: int) -> bytes:
    """One Delaunay band with every pixel a vertex: all position gaps and samples 0."""
    n = width * height
    fields = dict(
        y0=0, rows=height, vertex_count=n, triangle_count=2 * (width - 1) * (height - 1),
        polyline_count=0, polyline_index_count=0, connectivity=schema.DELAUNAY,
        position_order=schema.POSITIONS_RASTER, triangle_crc=12345, sample_step=1,
        polyline_lengths=b"", polyline_starts=b"", polyline_steps=b"",
        positions=bytes(n + 1), position_bits=b"", samples=bytes(n), triangles=b"",
    )
    raw = schema.MeshPayload.build(fields, sample_type=0, channels=1)
    return _chunk(schema.MESH, frames.compress(raw)) + _chunk(schema.END, b"")


@pytest.mark.parametrize("width, height", [(2048, 2048), (600, 500)])
def test_every_pixel_a_vertex_is_refused_before_triangulating(width, height, tmp_path, quick):
    """A few hundred bytes declaring millions of vertices to rebuild: 1.1-1.7 GB and
    20 s of triangulation before. 2048^2 exceeds the payload expansion limit, 600x500
    (within it) the rebuilt-vertices one."""
    data = _file(width, height, bands=_all_pixel_band(width, height))
    assert len(data) < 2_000
    _every_entry_point(data, tmp_path, codec.LimitError)
    quick(5.0)


def test_the_encoder_lists_triangles_a_decoder_would_not_rebuild(monkeypatch):
    image = (np.indices((64, 64)).sum(0) % 2 * 255).astype(np.uint8)
    monkeypatch.setattr(limits, "MIN_REBUILT_VERTICES", 16)
    data = codec.encode(image, quality=100)
    assert np.array_equal(codec.decode(data), image)


def test_an_output_over_the_byte_limit_is_a_limit_error(tmp_path, quick):
    """A tiny RGB16 16384^2 file: MemoryError allocating the output before."""
    data = _file(16384, 16384, sample_type=1, channels=3, bands=_chunk(schema.END, b""))
    with pytest.raises(codec.LimitError, match="MAX_IMAGE_BYTES"):
        codec.decode(data)
    with pytest.raises(codec.LimitError):
        codec.info(data)
    path = tmp_path / "big.atm"
    path.write_bytes(data)
    with pytest.raises(OSError):
        Image.open(path)
    quick()


def test_info_reads_counts_without_decoding_meshes(monkeypatch):
    image = np.random.default_rng(3).integers(0, 256, (60, 50)).astype(np.uint8)
    data = codec.encode(image, points=300, band_height=16)
    bands = container.unpack(data)[1]
    from codec import meshcode

    monkeypatch.setattr(meshcode, "decode_band", lambda *a, **k: pytest.fail("decoded a mesh"))
    i = codec.info(data)
    assert i["bands"] == len(bands) == 4
    assert i["vertices"] == sum(len(m.vertices) for _, m in bands)
    assert i["triangles"] == sum(len(m.triangles) for _, m in bands)
    assert i["constraints"] == sum(len(m.constraints) for _, m in bands)


def test_pillow_errors_are_os_errors_and_codec_errors(tmp_path):
    path = tmp_path / "trunc.atm"
    path.write_bytes(codec.encode(np.zeros((8, 8), np.uint8))[:-20])
    with Image.open(path) as im:
        with pytest.raises(OSError) as caught:
            im.load()
    assert isinstance(caught.value, codec.FormatError)
    path.write_bytes(_file(8, 8)[:12])
    with pytest.raises(OSError):
        Image.open(path)


def test_many_small_bands_are_parsed_without_construct(monkeypatch):
    """20,000 one-row bands took 81 s (4 ms a band); construct's per-field parsing of
    each chunk and payload was a third of the container's share. The chunk heads, CRCs
    and MESH payloads are now parsed with struct: refuse construct's parsers and a
    file of many bands still decodes."""
    width, height = 9, 60
    out = io.BytesIO()
    writer = container.Writer(out, container.Header(width, height, np.dtype(np.uint8), 1))
    v = np.array([[0, 0], [width - 1, 0], [0, 1], [width - 1, 1]], np.int64)
    for y0 in range(height - 1):
        values = np.array([y0, y0 + 1, y0 + 2, y0 + 3], np.uint8)
        writer.write_band(y0, Mesh(v, values, triangulate(v), width, 2, []))
    writer.close()
    expected = codec.decode(out.getvalue())
    for construct in (schema.MeshPayload, schema.Chunk, schema.ChunkHead):
        monkeypatch.setattr(construct, "parse", lambda *a, **k: pytest.fail("parsed with construct"))
        monkeypatch.setattr(construct, "parse_stream", lambda *a, **k: pytest.fail("parsed with construct"))
    assert np.array_equal(codec.decode(out.getvalue()), expected)
    assert codec.info(out.getvalue())["bands"] == height - 1
