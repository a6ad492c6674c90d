"""Mesh <-> .atm bytes: signature, version and checksummed chunks (see format_spec/ATM.md)."""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import BinaryIO, Iterator

import numpy as np
import zstandard
from construct import ChecksumError, ConstructError

from format_spec import schema

from . import limits
from .errors import CorruptError, FormatError, LimitError, TruncatedError, UnsupportedError
from .image import DTYPES, SAMPLE_TYPES
from .mesh import Mesh, validate

ZSTD_LEVEL = 12


@dataclass(frozen=True)
class Header:
    """What the AHDR chunk says about the image."""

    width: int
    height: int
    dtype: np.dtype
    channels: int
    version: int = schema.VERSION

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.height, self.width) if self.channels == 1 else (self.height, self.width, self.channels)


def _chunk(ctype: bytes, payload: bytes) -> bytes:
    return schema.Chunk.build(dict(length=len(payload), type=ctype, payload=payload, crc=None))


def pack(mesh: Mesh) -> bytes:
    """Serialise a validated mesh as a complete .atm file."""
    validate(mesh)
    header = dict(
        width=mesh.width,
        height=mesh.height,
        sample_type=SAMPLE_TYPES[mesh.dtype],
        channels=mesh.channels,
    )
    lengths = np.array([len(c) for c in mesh.constraints], dtype=np.uint32)
    indices = (
        np.concatenate(mesh.constraints).astype(np.uint32)
        if mesh.constraints
        else np.zeros(0, np.uint32)
    )
    raw = schema.MeshPayload.build(
        dict(
            vertex_count=len(mesh.vertices),
            triangle_count=len(mesh.triangles),
            polyline_count=len(lengths),
            x=mesh.vertices[:, 0],
            y=mesh.vertices[:, 1],
            samples=mesh.values,
            triangles=mesh.triangles,
            polyline_lengths=lengths,
            polyline_indices=indices,
        ),
        **header,
    )
    compressed = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True).compress(raw)
    return b"".join(
        [
            schema.FileHeader.build(dict(version=schema.VERSION)),
            _chunk(schema.HEADER, schema.Header.build(header)),
            _chunk(schema.MESH, compressed),
            _chunk(schema.END, b""),
        ]
    )


def _read_exact(stream: BinaryIO, n: int, what: str) -> bytes:
    start = stream.tell() if stream.seekable() else None
    data = stream.read(n)
    if len(data) != n:
        where = f" at byte {start}" if start is not None else ""
        raise TruncatedError(f"the file ends inside {what}{where}: needed {n} bytes, got {len(data)}")
    return data


def read_signature(stream: BinaryIO) -> int:
    """Check the signature and return the format version."""
    head = stream.read(schema.FileHeader.sizeof())
    if len(head) < len(schema.SIGNATURE) and schema.SIGNATURE.startswith(head) and head:
        raise TruncatedError("the file ends inside the .atm signature")
    if not head.startswith(schema.SIGNATURE):
        raise FormatError("not an .atm file (the signature does not match)")
    if len(head) < schema.FileHeader.sizeof():
        raise TruncatedError("the file ends inside the version field")
    version = schema.FileHeader.parse(head).version
    if version != schema.VERSION:
        raise UnsupportedError(
            f"this file is .atm version {version}; this codec reads version {schema.VERSION}"
        )
    return version


def iter_chunks(stream: BinaryIO) -> Iterator[tuple[bytes, bytes]]:
    """Yield (type, payload) for each chunk after the file header, checksums verified,
    up to and including the end chunk."""
    while True:
        offset = stream.tell() if stream.seekable() else None
        head = stream.read(schema.ChunkHead.sizeof())
        if not head:
            where = f" (at byte {offset})" if offset is not None else ""
            raise TruncatedError(f"the file ends before its AEND chunk{where}")
        if len(head) < schema.ChunkHead.sizeof():
            raise TruncatedError(f"the file ends inside a chunk header at byte {offset}")
        parsed = schema.ChunkHead.parse(head)
        length, ctype = parsed.length, parsed.type
        name = ctype.decode("latin-1")
        if not all(65 <= c <= 90 or 97 <= c <= 122 for c in ctype):
            raise CorruptError(f"invalid chunk type {ctype!r} at byte {offset}")
        if length > limits.MAX_CHUNK_BYTES:
            raise LimitError(f"chunk {name} declares {length:,} bytes, over the limit")
        body = _read_exact(stream, length + 4, f"chunk {name}")
        try:
            chunk = schema.Chunk.parse(head + body)
        except ChecksumError:
            raise CorruptError(f"chunk {name} fails its CRC check (the file is damaged)") from None
        yield ctype, chunk.payload
        if ctype == schema.END:
            return


def _decompress(payload: bytes, limit: int, name: str) -> bytes:
    try:
        size = zstandard.frame_content_size(payload)
    except zstandard.ZstdError as exc:
        raise CorruptError(f"chunk {name} is not a zstd frame: {exc}") from None
    if size < 0:
        raise CorruptError(f"chunk {name}'s zstd frame does not declare its size")
    if size > min(limit, limits.MAX_PAYLOAD_BYTES):
        raise LimitError(
            f"chunk {name} would decompress to {size:,} bytes, more than its image can need "
            "(a decompression bomb?)"
        )
    try:
        data = zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
    except zstandard.ZstdError as exc:
        raise CorruptError(f"chunk {name} does not decompress: {exc}") from None
    if len(data) != size:
        raise CorruptError(f"chunk {name} decompresses to {len(data)} bytes, not the {size} declared")
    return data


def _payload_limit(header: Header) -> int:
    """The largest MESH payload an image of this size can legitimately need."""
    nv = limits.max_vertices(header.width, header.height)
    nt = limits.max_triangles(header.width, header.height)
    per_vertex = 8 + header.dtype.itemsize * header.channels + 8  # position, values, polylines
    return 12 + nv * per_vertex + nt * 12 + 4096


def _parse_header(payload: bytes) -> Header:
    if len(payload) != schema.Header.sizeof():
        raise CorruptError(f"AHDR chunk has {len(payload)} bytes, not {schema.Header.sizeof()}")
    h = schema.Header.parse(payload)
    if h.sample_type not in DTYPES:
        raise UnsupportedError(f"unknown sample type {h.sample_type} (0 = uint8, 1 = uint16)")
    if h.channels not in (1, 3):
        raise UnsupportedError(f"{h.channels} channels; .atm version 1 has 1 or 3")
    if h.width == 0 or h.height == 0:
        raise CorruptError(f"the header declares an empty {h.width}x{h.height} image")
    limits.check_image_size(h.width, h.height)
    return Header(h.width, h.height, DTYPES[h.sample_type], h.channels)


def read_header(stream: BinaryIO) -> Header:
    """Read the signature and the AHDR chunk, nothing more."""
    read_signature(stream)
    for ctype, payload in iter_chunks(stream):
        if ctype != schema.HEADER:
            raise CorruptError(f"the first chunk is {ctype.decode('latin-1')}, not AHDR")
        return _parse_header(payload)
    raise CorruptError("the file has no AHDR chunk")  # pragma: no cover - iter_chunks raises first


def _parse_mesh(payload: bytes, header: Header) -> Mesh:
    raw = _decompress(payload, _payload_limit(header), "MESH")
    stream = io.BytesIO(raw)
    try:
        m = schema.MeshPayload.parse_stream(
            stream, sample_type=SAMPLE_TYPES[header.dtype], channels=header.channels
        )
    except ConstructError as exc:
        raise CorruptError(f"MESH chunk is malformed: {str(exc).splitlines()[0]}") from None
    if stream.tell() != len(raw):
        raise CorruptError(f"MESH chunk has {len(raw) - stream.tell()} bytes of trailing data")
    vertices = np.stack([m.x, m.y], axis=1).astype(np.int64)
    values = m.samples.astype(header.dtype)
    if header.channels > 1:
        values = values.reshape(-1, header.channels)
    triangles = m.triangles.astype(np.int64).reshape(-1, 3)
    bounds = np.cumsum(m.polyline_lengths.astype(np.int64))[:-1]
    constraints = (
        np.split(m.polyline_indices.astype(np.int64), bounds) if m.polyline_count else []
    )
    mesh = Mesh(vertices, values, triangles, header.width, header.height, constraints)
    validate(mesh)
    return mesh


def unpack(data: bytes | BinaryIO) -> tuple[Header, Mesh]:
    """Parse a complete .atm file into its header and validated mesh."""
    stream = io.BytesIO(data) if isinstance(data, (bytes, bytearray, memoryview)) else data
    read_signature(stream)
    header = None
    mesh = None
    for ctype, payload in iter_chunks(stream):
        name = ctype.decode("latin-1")
        if header is None and ctype != schema.HEADER:
            raise CorruptError(f"the first chunk is {name}, not AHDR")
        if ctype == schema.HEADER:
            if header is not None:
                raise CorruptError("the file has two AHDR chunks")
            header = _parse_header(payload)
        elif ctype == schema.MESH:
            if mesh is not None:
                raise CorruptError("the file has two MESH chunks")
            mesh = _parse_mesh(payload, header)
        elif ctype == schema.END:
            if payload:
                raise CorruptError("the AEND chunk must be empty")
        elif ctype[0] & 0x20 == 0:
            raise UnsupportedError(f"unknown critical chunk {name}; a newer codec wrote this file")
        # ancillary chunks this version does not know are skipped, as PNG does
    if mesh is None:
        raise CorruptError("the file has no MESH chunk")
    return header, mesh
