"""Meshes <-> .atm bytes: signature, version and checksummed chunks (format_spec/ATM.md).

A file holds one image as a sequence of bands of rows, each band's mesh in its own MESH
chunk; neighbouring bands share their boundary row. `Writer` emits chunks as bands
arrive and never seeks; `Reader` yields bands as their chunks arrive.
"""

from __future__ import annotations

import dataclasses
import io
import struct
import zlib
from dataclasses import dataclass
from typing import BinaryIO, Iterator, NamedTuple

import numpy as np
from construct import ConstructError

from .format_spec import schema

from . import coding, frames, integers, limits, meshcode
from . import holemask
from . import metadata as meta_json
from .errors import CorruptError, FormatError, LimitError, TruncatedError, UnsupportedError
from .image import DTYPES, SAMPLE_TYPES
from .mesh import Mesh, validate
from .quantise import STORAGE, Quantiser
from .triangulate import Delaunay
from .residual import CHUNK as RESIDUAL


@dataclass(frozen=True)
class Header:
    """What the AHDR (and QUNT) chunks say about the image. `dtype` is what decoding
    returns: float32 for quantised float data, whose samples are stored as uint16."""

    width: int
    height: int
    dtype: np.dtype
    channels: int
    version: int = schema.VERSION
    quant: Quantiser | None = None
    #: the value hole pixels decode to; None when the image has no holes
    nodata: float | None = None
    #: JSON key-values (units, georeferencing, ...) from the meta chunk
    metadata: dict | None = None
    #: a gray image decodes as (H, W, 1), not (H, W): the file's `axis` chunk (ATM.md §4.9)
    channel_axis: bool = False
    #: float32 samples stored exactly as binary32 keys by the residual layer
    #: (`sample_type` 6, ATM.md §4.10); the mesh is then a preview through `quant`
    exact: bool = False
    #: with `exact`, the STEP chunk's offset and scale: the layer's samples are 32-bit
    #: whole numbers q of value = offset + scale q (ATM.md §4.10.1), not keys
    steps: Quantiser | None = None

    @property
    def shape(self) -> tuple[int, ...]:
        if self.channels == 1:
            return (self.height, self.width, 1) if self.channel_axis else (self.height, self.width)
        return (self.height, self.width, self.channels)

    @property
    def storage(self) -> np.dtype:
        """The integer type the samples are coded in."""
        return STORAGE if self.quant is not None else np.dtype(self.dtype)

    @property
    def layer_storage(self) -> np.dtype:
        """The integer type a residual layer codes: 32 bits for exact float (binary32
        keys, or whole numbers of the STEP chunk's step)."""
        return np.dtype(np.uint32) if self.exact else self.storage

    def _fields(self) -> dict:
        dtype = np.dtype(self.dtype)
        code = (
            SAMPLE_TYPES[dtype] if self.quant is None
            else integers.SAMPLE_TYPES[dtype] if integers.is_signed(dtype)
            else schema.FLOAT32X if self.exact else schema.FLOAT16Q
        )
        return dict(width=self.width, height=self.height, sample_type=code, channels=self.channels)


def encode_metadata(metadata: dict) -> bytes:
    """The meta chunk's JSON: an object, keys sorted (the same input gives the same bytes)."""
    return meta_json.encode(metadata)


def _stored_bound(size: int) -> int:
    """The most bytes zstd needs to store `size` bytes (its ZSTD_COMPRESSBOUND, rounded
    up): a frame longer than that for the size it may declare is refused unread."""
    return size + (size >> 7) + 1024


#: The MESH payload's fixed fields (schema.MeshPayload up to sample_step), which say
#: how large the rest can be, and the names of all its fields, from the schema.
_MESH_NAMES = [sub.name for sub in schema.MeshPayload.subcons]
_MESH_FIXED = struct.Struct(
    "<" + "".join({1: "B", 2: "H", 4: "I"}[sub.sizeof()] for sub in schema.MeshPayload.subcons[: len(_MESH_NAMES) - len(meshcode.FIELDS)])
)
#: A MESH payload section's length prefix.
_SECTION = struct.Struct("<I")
#: schema.ChunkHead (length, type) as a struct: parsed once per chunk.
_CHUNK_HEAD = struct.Struct("<I4s")
assert _CHUNK_HEAD.size == schema.ChunkHead.sizeof()
#: schema.FileHeader (signature, version) and schema.Header (width, height,
#: sample_type, channels) as structs: construct's parse cost more than a small
#: file's decode
_FILE_HEAD = struct.Struct("<8sH")
assert _FILE_HEAD.size == schema.FileHeader.sizeof()
_HEADER = struct.Struct("<IIBB")
assert _HEADER.size == schema.Header.sizeof()
#: schema.Quantisation (offset, scale) and schema.NoData (value) as structs, likewise
_QUANT = struct.Struct("<dd")
assert _QUANT.size == schema.Quantisation.sizeof()
_NODATA = struct.Struct("<d")
assert _NODATA.size == schema.NoData.sizeof()

#: Frames up to this size are decompressed whole at once (cheaper than reading their
#: fixed fields first); larger ones have their fixed fields checked first.
_WHOLE_FRAME = 1 << 16


class _MeshFields:
    """A parsed MESH payload: the schema's field names as attributes (what
    schema.MeshPayload.parse gives, without construct's per-field cost, which
    dominated decoding files of many small bands)."""

    def __init__(self, raw: bytes, where: str):
        values = list(_MESH_FIXED.unpack_from(raw))
        at, size = _MESH_FIXED.size, len(raw)
        view = memoryview(raw)
        for _ in meshcode.FIELDS:  # seven length-prefixed sections
            start = at + 4
            if start > size:
                raise CorruptError(f"{where} is malformed: it ends inside a section's length")
            (n,) = _SECTION.unpack_from(raw, at)
            at = start + n
            if at > size:
                raise CorruptError(f"{where} is malformed: a section of {n:,} bytes runs past its end")
            values.append(view[start:at])  # a view: no copy
        if at != size:
            raise CorruptError(f"{where} has {size - at} bytes of trailing data")
        self.__dict__.update(zip(_MESH_NAMES, values))


def band_starts(height: int, band_height: int) -> list[int]:
    """First rows of the bands: each band has `band_height` new rows and shares its first
    row with the previous band, so band k covers rows k*band_height .. (k+1)*band_height."""
    if height == 1:
        return [0]
    return list(range(0, height - 1, band_height))


def _build(con, obj: dict, **params) -> bytes:
    """con.build(obj, **params) with no context left in a reference cycle: construct's
    Struct makes its context the root (`_root` pointing to itself) unless the caller's
    context names one, and that cycle kept a band's fields and frame alive until
    Python's cyclic collector ran (a long stream's memory grew with its height). Named
    None (no field of the schema reads it), the contexts that hold the fields are freed
    when the build returns; collecting them after each band instead (gc.collect)
    scanned the whole heap, 18 ms of an RGB photo's 0.7 s encode."""
    return con.build(obj, _root=None, **params)


def _chunk(ctype: bytes, payload: bytes) -> bytes:
    return _build(schema.Chunk, dict(length=len(payload), type=ctype, payload=payload, crc=None))


class Writer:
    """Write an .atm file band by band: header at creation, one MESH chunk per
    `write_band`, AEND at `close`. Bands must come in order and cover the image."""

    def __init__(self, stream: BinaryIO, header: Header):
        limits.check_image_size(header.width, header.height)
        limits.check_image_bytes(header.width, header.height, header.channels, np.dtype(header.dtype).itemsize)
        self._stream = stream
        self.header = header
        self._next_y0 = 0
        self._rows_done = 0
        stream.write(_build(schema.FileHeader, dict(version=schema.VERSION)))
        stream.write(_chunk(schema.HEADER, _build(schema.Header, header._fields())))
        if header.quant is not None:
            q = header.quant
            stream.write(_chunk(schema.QUANT, _build(schema.Quantisation, dict(offset=q.offset, scale=q.scale))))
        if header.steps is not None:
            stream.write(_chunk(schema.STEP, struct.pack("<dd", header.steps.offset, header.steps.scale)))
        if header.nodata is not None:
            stream.write(_chunk(schema.NODATA, _build(schema.NoData, dict(value=header.nodata))))
        if header.channel_axis and header.channels == 1:
            stream.write(_chunk(schema.AXIS, b""))
        if header.metadata is not None:
            stream.write(_chunk(schema.META, frames.compress(encode_metadata(header.metadata))))

    @property
    def done(self) -> bool:
        """Whether the bands written so far reach the image's last row."""
        return self._rows_done == self.header.height

    def write_band(self, y0: int, mesh: Mesh, step: int = 1, delaunay: bool | None = None,
                   layout: meshcode.Layout | None = None, residual: bytes | None = None) -> None:
        """Write the mesh of rows y0 .. y0 + mesh.height - 1, its samples as
        meshcode.quantise(mesh, step, y0 > 0) left them (any samples with step 1);
        delaunay and layout as for meshcode.encode_band; residual: the band's RESD
        payload (codec.residual), if the image has a residual layer."""
        h = self.header
        if y0 != self._next_y0:
            raise ValueError(f"band starts at row {y0}, expected {self._next_y0}")
        if mesh.width != h.width or y0 + mesh.height > h.height:
            raise ValueError("band does not fit the image")
        # a mesh the encoder triangulated as a decoder will (delaunay) tiles the image and
        # has its walls as edges by construction: the cheap checks stay, the edge sort goes
        validate(mesh, walls_are_edges=bool(delaunay), tiles=bool(delaunay))
        if h.nodata is not None:
            holes = mesh.holes if mesh.holes is not None else np.zeros((mesh.height, mesh.width), bool)
            runs = coding.runs(holes)
            mask = _build(
                schema.MaskPayload,
                dict(y0=y0, rows=mesh.height, run_count=len(runs), runs=coding.varints(runs))
            )
            mask = _chunk(schema.MASK, frames.compress(mask))
            # ragged holes (sensor depth) cost less context-coded, DEM voids as runs
            coded = _chunk(holemask.CHUNK, holemask.encode(y0, holes)) if holes.any() else mask
            self._stream.write(coded if len(coded) < len(mask) else mask)
        elif mesh.holes is not None and mesh.holes.any():
            raise ValueError("a band with holes needs a header with a nodata value")
        if residual is not None:
            self._stream.write(_chunk(RESIDUAL, residual))
        fields = meshcode.encode_band(y0, mesh, step, delaunay, layout)
        raw = _build(schema.MeshPayload, fields, **h._fields())
        frame = frames.compress_parts(meshcode.payload_parts(raw, fields), meshcode.own_parameters_pay(fields))
        if fields["connectivity"] == schema.DELAUNAY and len(mesh.vertices) > limits.max_rebuilt_vertices(len(frame)):
            # too cheap to store for a decoder to rebuild: list the triangles
            fields = meshcode.encode_band(y0, mesh, step, rebuild=False)
            raw = _build(schema.MeshPayload, fields, **h._fields())
            frame = frames.compress_parts(meshcode.payload_parts(raw, fields), meshcode.own_parameters_pay(fields))
        if len(raw) > limits.max_payload(len(frame)):
            raise LimitError(
                f"the band from row {y0} compresses {len(raw):,} bytes into {len(frame):,}, more "
                "than decoders accept (raise codec.limits.MAX_PAYLOAD_EXPANSION when encoding and "
                "decoding such files)"
            )
        self._stream.write(_chunk(schema.MESH, frame))
        self._next_y0 = y0 + mesh.height - 1
        self._rows_done = y0 + mesh.height

    def close(self) -> None:
        if not self.done:
            raise ValueError(f"the bands end before row {self.header.height - 1}")
        self._stream.write(_chunk(schema.END, b""))


def pack(mesh: Mesh) -> bytes:
    """Serialise one mesh of a whole image as a complete .atm file (a single band)."""
    out = io.BytesIO()
    writer = Writer(out, Header(mesh.width, mesh.height, mesh.dtype, mesh.channels))
    writer.write_band(0, mesh)
    writer.close()
    return out.getvalue()


class _Counted:
    """A read-only stream that knows how many bytes have been read, for error messages
    on pipes that cannot tell()."""

    def __init__(self, stream: BinaryIO):
        self._stream = stream
        self.offset = 0

    def read(self, n: int) -> bytes:
        data = self._stream.read(n)
        if data is None:  # non-blocking stream with nothing yet: treat as the end
            data = b""
        self.offset += len(data)
        return data

    def read_exact(self, n: int, what: str) -> bytes:
        start = self.offset
        parts, left = [], n
        while left:
            # read in pieces so a lying length cannot make us allocate it up front
            part = self.read(min(left, 1 << 20))
            if not part:
                raise TruncatedError(
                    f"the file ends inside {what} at byte {self.offset} "
                    f"(needed {n} bytes from byte {start}, got {n - left})"
                )
            parts.append(part)
            left -= len(part)
        return b"".join(parts)


class _RawFields(NamedTuple):
    """schema.Header's fields, as its parse names them."""

    width: int
    height: int
    sample_type: int
    channels: int


@dataclass(frozen=True)
class _RawHeader:
    sample_type: int
    header: Header


class Reader:
    """Read an .atm file from a stream: the header at creation, then bands on iteration.

    Iterating yields (y0, Mesh) for each band, validated, as soon as its chunk has been
    read; a damaged or truncated file raises an ATMError after the intact bands.
    """

    def __init__(self, stream: BinaryIO, metadata: bool = True, *,
                 dctx: "frames.zstandard.ZstdDecompressor | None" = None, triangulator: Delaunay | None = None):
        """metadata=False skips the meta chunks before the first band unparsed (what
        Pillow's Image.open wants: the size, and nothing that costs). dctx and
        triangulator: a decompressor and a triangulation's buffers to use instead of
        new ones (a codec.Decoder's, which outlive the reader: one thread at a time)."""
        self._stream = _Counted(stream)
        #: metadata bytes (decompressed) still allowed in this file
        self._meta_budget = limits.MAX_METADATA_BYTES
        self._dctx = frames.decompressor() if dctx is None else dctx  # this reader's own, or its owner's
        #: the triangulation's buffers, this reader's own (or its owner's): reused band after band
        self._triangulator = Delaunay() if triangulator is None else triangulator
        self.version = self._read_signature()
        ctype, payload, offset = self._next_chunk()
        if ctype != schema.HEADER:
            raise CorruptError(f"the first chunk is {ctype.decode('latin-1')}, not AHDR")
        self.header = self._parse_header(payload)
        if self.header.sample_type in schema.QUANTISED:
            ctype, payload, offset = self._next_chunk()
            if ctype != schema.QUANT:
                kind = "float" if self.header.sample_type in (schema.FLOAT16Q, schema.FLOAT32X) else "signed integer"
                raise CorruptError(f"{kind} data needs a QUNT chunk after AHDR; found {ctype.decode('latin-1')}")
            self.header = self._parse_quant(self.header, payload)
        self.header = self.header.header
        self._pending_head = None
        self._pending_error = None
        self._largest_payload: int | None = None  # _check_frame's bound, once known
        after_quant = self.header.quant is not None  # where a STEP chunk may come (ATM.md §4.10.1)
        # the chunks before the first band (NDAT, meta, ancillary ones); the first band's
        # chunk is left unread, so that opening a file reads its header and no more
        while True:
            try:
                head = self._next_head()
            except TruncatedError as exc:
                # the header is intact: report the truncation when the bands are read
                self._pending_error = exc
                break
            ctype = head[0]
            if ctype == schema.STEP and after_quant and self.header.exact:
                self._pending_head = head
                self.header = self._parse_steps(self.header, self._next_chunk())
                after_quant = False
                continue
            after_quant = False
            if (ctype[0] & 0x20 == 0 and ctype != schema.NODATA) or (
                ctype == schema.NODATA and self.header.nodata is not None
            ):
                self._pending_head = head  # __iter__ reads it
                break
            self._pending_head = head
            try:
                ctype, payload, offset = self._next_chunk()
            except TruncatedError as exc:
                self._pending_error = exc
                break
            if ctype == schema.NODATA:
                self.header = self._parse_nodata(self.header, payload)
            elif ctype == schema.AXIS:
                if payload or self.header.channel_axis or self.header.channels != 1:
                    raise CorruptError(
                        f"axis chunk at byte {offset}: it is empty, comes once and only in a gray image (ATM.md §4.9)"
                    )
                self.header = dataclasses.replace(self.header, channel_axis=True)
            elif ctype == schema.META and metadata:
                self._read_metadata(payload, offset)
        self._iterated = False

    def _read_signature(self) -> int:
        head = self._stream.read(_FILE_HEAD.size)
        if len(head) < len(schema.SIGNATURE) and head and schema.SIGNATURE.startswith(head):
            raise TruncatedError("the file ends inside the .atm signature")
        if not head.startswith(schema.SIGNATURE):
            raise FormatError("not an .atm file (the signature does not match)")
        if len(head) < _FILE_HEAD.size:
            raise TruncatedError("the file ends inside the version field")
        version = _FILE_HEAD.unpack(head)[1]
        if version != schema.VERSION:
            # version 5 has version 6's bytes, but its implicit triangles were one
            # library's tie-breaking (ATM.md section 7)
            why = " (version 5 left ties to one library: re-encode the source image)" if version == 5 else ""
            raise UnsupportedError(
                f"this file is .atm version {version}; this codec reads version {schema.VERSION}{why}"
            )
        return version

    def _next_head(self) -> tuple[bytes, bytes, int, int]:
        """(type, raw head, length, offset) of the next chunk; its body is not read."""
        if getattr(self, "_pending_head", None) is not None:
            head, self._pending_head = self._pending_head, None
            return head
        if getattr(self, "_pending_error", None) is not None:
            raise self._pending_error
        s = self._stream
        offset = s.offset
        raw = s.read(_CHUNK_HEAD.size)
        if not raw:
            raise TruncatedError(f"the file ends at byte {offset}, before its AEND chunk")
        if len(raw) < _CHUNK_HEAD.size:
            raise TruncatedError(f"the file ends inside a chunk header at byte {s.offset}")
        length, ctype = _CHUNK_HEAD.unpack(raw)
        if not ctype.isalpha():  # bytes: ASCII letters only
            raise CorruptError(f"invalid chunk type {ctype!r} at byte {offset}")
        if length > limits.MAX_CHUNK_BYTES:
            raise LimitError(
                f"chunk {ctype.decode('latin-1')} at byte {offset} declares {length:,} bytes, over the limit"
            )
        if ctype == schema.META and length > _stored_bound(limits.MAX_METADATA_BYTES):
            raise LimitError(
                f"meta chunk at byte {offset} declares {length:,} bytes; metadata is at most "
                f"{limits.MAX_METADATA_BYTES:,} bytes (codec.limits.MAX_METADATA_BYTES)"
            )
        return ctype, raw, length, offset

    def _next_chunk(self) -> tuple[bytes, bytes, int]:
        """(type, payload, offset) of the next chunk, its CRC verified."""
        ctype, raw, length, offset = self._next_head()
        name = ctype.decode("latin-1")
        body = self._stream.read_exact(length + 4, f"chunk {name}")
        payload = body[:length]
        # the CRC as schema.Chunk defines it (type and payload), without construct's cost
        if zlib.crc32(payload, zlib.crc32(ctype)) != int.from_bytes(body[length:], "little"):
            raise CorruptError(f"chunk {name} at byte {offset} fails its CRC check (the file is damaged)")
        return ctype, payload, offset

    @staticmethod
    def _parse_header(payload: bytes) -> "_RawHeader":
        if len(payload) != _HEADER.size:
            raise CorruptError(f"AHDR chunk has {len(payload)} bytes, not {_HEADER.size}")
        h = _RawFields(*_HEADER.unpack(payload))
        if h.sample_type not in schema.SAMPLE_DTYPES:
            raise UnsupportedError(
                f"unknown sample type {h.sample_type} (0 = uint8, 1 = uint16, 2 = quantised float, "
                "3 = int8, 4 = int16, 5 = int32, 6 = exact float)"
            )
        if h.channels not in (1, 3):
            raise UnsupportedError(f"{h.channels} channels; .atm has 1 or 3")
        if h.width == 0 or h.height == 0:
            raise CorruptError(f"the header declares an empty {h.width}x{h.height} image")
        if h.sample_type in schema.QUANTISED and h.channels != 1:
            raise UnsupportedError("quantised float and signed integer data have one channel")
        limits.check_image_size(h.width, h.height)
        exact = h.sample_type == schema.FLOAT32X
        dtype = (np.dtype(np.float32) if h.sample_type == schema.FLOAT16Q or exact
                 else {**DTYPES, **integers.DTYPES}[h.sample_type])
        limits.check_image_bytes(h.width, h.height, h.channels, dtype.itemsize)
        return _RawHeader(h.sample_type, Header(h.width, h.height, dtype, h.channels, exact=exact))

    @staticmethod
    def _parse_quant(raw: "_RawHeader", payload: bytes) -> "_RawHeader":
        if len(payload) != _QUANT.size:
            raise CorruptError(f"QUNT chunk has {len(payload)} bytes, not {_QUANT.size}")
        q = Quantiser(*_QUANT.unpack(payload))
        top = abs(q.offset) + q.scale * 65535 if np.isfinite(q.offset) and np.isfinite(q.scale) else np.inf
        if not (q.scale > 0 and top <= float(np.finfo(np.float32).max)):
            raise CorruptError(
                f"QUNT chunk has scale {q.scale!r} and offset {q.offset!r}: values must be finite "
                "and within float32's range"
            )
        h = raw.header
        if integers.is_signed(h.dtype) and not integers.check_quant(q.offset, q.scale):
            raise CorruptError(
                f"QUNT chunk of {h.dtype} data has scale {q.scale!r} and offset {q.offset!r}: "
                "integer data needs scale 1 and a whole-number offset within int32's range"
            )
        return _RawHeader(raw.sample_type, dataclasses.replace(h, quant=Quantiser(q.offset, q.scale)))

    @staticmethod
    def _parse_steps(h: Header, chunk: tuple[bytes, bytes, int]) -> Header:
        _, payload, offset = chunk
        if len(payload) != 16:
            raise CorruptError(f"STEP chunk at byte {offset} has {len(payload)} bytes, not 16")
        start, scale = struct.unpack("<dd", payload)
        top = abs(start) + scale * 0xFFFFFFFF if np.isfinite(start) and np.isfinite(scale) else np.inf
        if not (scale > 0 and top <= float(np.finfo(np.float32).max)):
            raise CorruptError(
                f"STEP chunk at byte {offset} has scale {scale!r} and offset {start!r}: values must be finite "
                "and within float32's range (ATM.md §4.10.1)"
            )
        return dataclasses.replace(h, steps=Quantiser(start, scale))

    def _read_metadata(self, payload: bytes, offset: int) -> None:
        where = f"meta chunk at byte {offset}"
        size = frames.declared_size(payload, where)
        if size > self._meta_budget:
            raise LimitError(
                f"{where} holds {size:,} bytes of metadata, which brings the file's over "
                f"{limits.MAX_METADATA_BYTES:,} (codec.limits.MAX_METADATA_BYTES)"
            )
        self._meta_budget -= size
        meta = meta_json.parse(frames.decompress(payload, size, where, self._dctx), where)
        h = self.header
        merged = dict(h.metadata or {}, **meta)
        self.header = dataclasses.replace(h, metadata=merged)

    @staticmethod
    def _parse_nodata(h: Header, payload: bytes) -> Header:
        if len(payload) != _NODATA.size:
            raise CorruptError(f"NDAT chunk has {len(payload)} bytes, not {_NODATA.size}")
        (value,) = _NODATA.unpack(payload)
        if np.dtype(h.dtype).kind in "ui":
            info = np.iinfo(h.dtype)
            if not (np.isfinite(value) and value == int(value) and info.min <= value <= info.max):
                raise CorruptError(f"NDAT value {value!r} is not a {h.dtype} sample")
        elif np.isfinite(value) and abs(value) > float(np.finfo(np.float32).max):
            raise CorruptError(f"NDAT value {value!r} is beyond float32's range")
        elif h.exact and np.isnan(value) and not struct.unpack("<Q", payload)[0] & (0x7FFFFF << 29):
            raise CorruptError("NDAT is a NaN whose binary32 form would be infinite (ATM.md §4.10)")
        return dataclasses.replace(h, nodata=float(value))

    def _parse_mask(self, payload: bytes, offset: int, y0: int) -> np.ndarray:
        h = self.header
        where = f"MASK chunk at byte {offset}"
        if frames.declared_size(payload, where) > limits.max_payload(len(payload)):
            raise LimitError(f"{where} would decompress to more than {limits.MAX_PAYLOAD_EXPANSION} times its size")
        raw = frames.decompress(payload, 12 + 4 + coding.MAX_VARINT_BYTES * (h.width * h.height + 1), where, self._dctx)
        stream = io.BytesIO(raw)
        try:
            m = schema.MaskPayload.parse_stream(stream)
        except ConstructError as exc:
            raise CorruptError(f"{where} is malformed: {str(exc).splitlines()[0]}") from None
        if stream.tell() != len(raw):
            raise CorruptError(f"{where} has trailing data")
        if m.y0 != y0 or m.rows < min(2, h.height) or m.y0 + m.rows > h.height:
            raise CorruptError(f"{where} covers rows {m.y0}..{m.y0 + m.rows - 1}, not a band from row {y0}")
        if m.run_count > h.width * m.rows + 1:
            raise CorruptError(f"{where} has more runs than pixels")
        runs = coding.unvarints(m.runs, m.run_count, where)
        return coding.unruns(runs, m.rows, h.width, where)

    def _payload_limit(self) -> int:
        """The largest MESH payload the image can legitimately need: every count at its
        limit and every varint at its longest."""
        h = self.header
        nv = limits.max_vertices(h.width, h.height)
        nt = limits.max_triangles(h.width, h.height)
        v = coding.MAX_VARINT_BYTES
        # a position and samples per vertex; up to two polyline points per vertex, each
        # a step of two numbers, and a length and a start per polyline of two or more
        per_vertex = v + h.storage.itemsize * h.channels + 2 * (2 * v) + 2 * v
        return 65 + nv * per_vertex + nt * 3 * v

    def _check_frame(self, payload: bytes, where: str, y0_expected: int, whole: bool = True) -> tuple[bytes, bytes]:
        """(fixed fields, whole payload or b"" unless `whole`) of a MESH frame, once its
        declared size is known to fit what the image, the chunk's stored bytes and the
        band's own counts allow (all checked before decompressing more than the fixed
        fields of a large frame)."""
        h = self.header
        size = frames.declared_size(payload, where)
        if size > limits.max_payload(len(payload)):
            raise LimitError(
                f"{where} would decompress {len(payload):,} bytes to {size:,}, more than "
                f"{limits.MAX_PAYLOAD_EXPANSION} times (a decompression bomb?; raise "
                "codec.limits.MAX_PAYLOAD_EXPANSION to accept it)"
            )
        if self._largest_payload is None:  # the header's, worked out once
            self._largest_payload = min(self._payload_limit(), limits.MAX_PAYLOAD_BYTES)
        if size > self._largest_payload:
            raise LimitError(f"{where} would decompress to {size:,} bytes, more than its image can need")
        if frames.frame_length(payload, where) != len(payload):  # codec.info decompresses no more
            raise CorruptError(f"{where} has bytes after its zstd frame (ATM.md §4: one frame)")
        # (the frame's length checked just above: decompress need not walk its blocks again)
        raw = frames.decompress(payload, size, where, self._dctx, one_frame=True, size=size) if size <= _WHOLE_FRAME else b""
        fixed = raw[: _MESH_FIXED.size] if size <= _WHOLE_FRAME else frames.head(payload, _MESH_FIXED.size, where)
        if len(fixed) < _MESH_FIXED.size:
            raise CorruptError(f"{where} is malformed: it ends inside its fixed fields")
        y0, rows, n, nt, lines, points, connectivity, _, _, _ = _MESH_FIXED.unpack(fixed)
        if y0 != y0_expected or rows < min(2, h.height) or y0 + rows > h.height:
            raise CorruptError(f"{where} has {rows} rows from row {y0}, expected a band from row {y0_expected}")
        most = limits.max_vertices(h.width, rows)
        if n > most:
            raise LimitError(f"{where}: {n:,} vertices is too many for {h.width}x{rows} pixels")
        if nt > limits.max_triangles(h.width, rows):
            raise LimitError(f"{where}: {nt:,} triangles is too many for {h.width}x{rows} pixels")
        if points > 2 * most or lines > points:
            raise CorruptError(f"{where}: {lines:,} polylines of {points:,} points in all")
        if connectivity == schema.DELAUNAY and n > limits.max_rebuilt_vertices(len(payload)):
            raise LimitError(
                f"{where} asks to rebuild the triangles of {n:,} vertices from {len(payload):,} "
                "bytes (raise codec.limits.MAX_REBUILT_VERTICES_PER_BYTE to accept it)"
            )
        v = coding.MAX_VARINT_BYTES
        # every section at its longest for these counts, with its length prefix
        need = (_MESH_FIXED.size + 7 * 4 + v * (2 * lines + 2 * points + n + 1)
                + (24 * n + 7) // 8 + v * n * h.channels + 3 * v * nt)
        if size > need:
            raise CorruptError(f"{where} declares {size:,} bytes; its counts can use at most {need:,}")
        if whole and not raw:
            raw = frames.decompress(payload, size, where, self._dctx, one_frame=True, size=size)
        return fixed, raw

    def _parse_band(self, payload: bytes, offset: int, y0_expected: int) -> tuple[int, Mesh]:
        h = self.header
        where = f"MESH chunk at byte {offset}"
        # (_check_frame refused a band not from y0_expected or not within the image)
        _, raw = self._check_frame(payload, where, y0_expected)
        m = _MeshFields(raw, where)
        mesh, checked = meshcode.decode_band(m, h.width, h.storage, h.channels, where, self._triangulator)
        # a rebuilt triangulation tiles the band and has the walls as edges (decode_band
        # checked them), whose polylines decode_band made and checked
        rebuilt = m.connectivity == schema.DELAUNAY
        validate(mesh, walls_are_edges=rebuilt, tiles=rebuilt, checked=checked, lines_checked=True)
        return int(m.y0), mesh

    def __iter__(self) -> Iterator[tuple[int, Mesh]]:
        if self._iterated:
            raise RuntimeError("an .atm Reader can be iterated once")
        self._iterated = True
        h = self.header
        next_y0, finished, holes = 0, False, None
        shared = None  # the holes of the last band's last row, which the next band repeats
        #: the (payload, offset) of the band just yielded's RESD chunk, None without one
        self.band_residual, residual, layered = None, None, None
        while True:
            ctype, payload, offset = self._next_chunk()
            name = ctype.decode("latin-1")
            if ctype == RESIDUAL:
                if residual is not None:
                    raise CorruptError(f"two RESD chunks before a MESH at byte {offset}")
                if h.nodata is not None and holes is None:
                    raise CorruptError(f"RESD chunk at byte {offset} comes before its band's MASK chunk")
                residual = (payload, offset)
            elif ctype in (schema.MASK, holemask.CHUNK):
                if h.nodata is None:
                    raise CorruptError(f"{name} chunk at byte {offset} in a file without NDAT")
                if holes is not None:
                    raise CorruptError(f"two MASK or HOLE chunks before a MESH at byte {offset}")
                if ctype == schema.MASK:
                    holes = self._parse_mask(payload, offset, next_y0)
                else:
                    holes = holemask.decode(payload, f"HOLE chunk at byte {offset}", next_y0, h.width, h.height)
            elif ctype == schema.MESH:
                if finished:
                    raise CorruptError(f"MESH chunk at byte {offset} lies beyond the image's last row")
                if h.nodata is not None and holes is None:
                    raise CorruptError(f"MESH chunk at byte {offset} has no MASK chunk before it")
                if layered is not None and layered != (residual is not None):
                    raise CorruptError(f"MESH chunk at byte {offset}: a residual layer covers every band or none")
                if h.exact and residual is None:
                    raise CorruptError(f"MESH chunk at byte {offset} has no RESD chunk: exact float data "
                                       "(sample_type 6) is stored in its residual layer (ATM.md §4.10)")
                layered, self.band_residual, residual = residual is not None, residual, None
                y0, mesh = self._parse_band(payload, offset, next_y0)
                if holes is not None:
                    if holes.shape != (mesh.height, mesh.width):
                        raise CorruptError(f"MASK and MESH chunks before byte {offset} cover different rows")
                    if shared is not None and not np.array_equal(holes[0], shared):
                        raise CorruptError(
                            f"MASK chunk before byte {offset}: row {y0}, which two bands share, "
                            "has different holes in each (ATM.md §4.6)"
                        )
                    mesh.holes, holes, shared = holes, None, holes[-1]
                next_y0 = y0 + mesh.height - 1
                finished = y0 + mesh.height == h.height
                yield y0, mesh
            elif ctype == schema.END:
                if payload:
                    raise CorruptError("the AEND chunk must be empty")
                if residual is not None:
                    raise CorruptError("the file ends with a RESD chunk that no MESH chunk follows")
                if not finished:
                    raise CorruptError(f"the file ends at row {next_y0}, before the image's last row")
                return
            elif ctype == schema.META:
                self._read_metadata(payload, offset)
            elif ctype in (schema.HEADER, schema.QUANT, schema.NODATA, schema.AXIS, schema.STEP):
                raise CorruptError(f"misplaced {name} chunk at byte {offset}")
            elif ctype[0] & 0x20 == 0:
                raise UnsupportedError(f"unknown critical chunk {name}; a newer codec wrote this file")
            # ancillary chunks this version does not know are skipped, as PNG does


@dataclass(frozen=True)
class Summary:
    """What codec.info reports of a file's bands, from their chunks' count fields."""

    bands: int
    vertices: int
    triangles: int
    polylines: int
    #: the residual layer's bound E in stored sample units (ATM.md §4.8), None without one
    residual: int | None = None


def summarise(reader: Reader) -> Summary:
    """Count a file's bands, vertices, triangles and polylines from each MESH chunk's
    fixed fields, checking its CRC and frame limits but decoding no mesh (the cost is
    the file's bytes, not its meshes')."""
    h = reader.header
    bands = vertices = triangles = polylines = 0
    next_y0, finished, bound = 0, False, None
    while True:
        ctype, payload, offset = reader._next_chunk()
        if ctype == RESIDUAL:
            if len(payload) < 12:
                raise CorruptError(f"RESD chunk at byte {offset} has {len(payload)} bytes, fewer than its 12 fixed ones")
            bound = int.from_bytes(payload[10:12], "little")
        elif ctype == schema.MESH:
            if finished:
                raise CorruptError(f"MESH chunk at byte {offset} lies beyond the image's last row")
            fixed, _ = reader._check_frame(payload, f"MESH chunk at byte {offset}", next_y0, whole=False)
            y0, rows, n, nt, lines, *_ = _MESH_FIXED.unpack(fixed)
            bands, vertices, triangles, polylines = bands + 1, vertices + n, triangles + nt, polylines + lines
            next_y0, finished = y0 + rows - 1, y0 + rows == h.height
        elif ctype == schema.END:
            if not finished:
                raise CorruptError(f"the file ends at row {next_y0}, before the image's last row")
            return Summary(bands, vertices, triangles, polylines, bound)
        elif ctype == schema.META:
            reader._read_metadata(payload, offset)
        elif ctype in (schema.HEADER, schema.QUANT, schema.NODATA, schema.AXIS, schema.STEP):
            raise CorruptError(f"misplaced {ctype.decode('latin-1')} chunk at byte {offset}")
        elif ctype[0] & 0x20 == 0 and ctype not in (schema.MASK, RESIDUAL, holemask.CHUNK):
            raise UnsupportedError(f"unknown critical chunk {ctype.decode('latin-1')}; a newer codec wrote this file")


def read_header(stream: BinaryIO, metadata: bool = True) -> Header:
    """Read the signature and the chunks before the first band (metadata=False: the
    meta chunks unparsed, the header's metadata None)."""
    return Reader(stream, metadata).header


def unpack(data: bytes | BinaryIO) -> tuple[Header, list[tuple[int, Mesh]]]:
    """Parse a complete .atm file into its header and validated bands (y0, Mesh)."""
    stream = io.BytesIO(data) if isinstance(data, (bytes, bytearray, memoryview)) else data
    reader = Reader(stream)
    return reader.header, list(reader)
