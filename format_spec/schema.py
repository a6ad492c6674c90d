"""Byte layout of .atm version 6 as `construct` declarations.

Every multi-byte integer is little-endian. ATM.md (beside this file) is the normative
description; the names here match its field names.
"""

from __future__ import annotations

import zlib

import numpy as np
from construct import (
    Bytes,
    Checksum,
    Const,
    Construct,
    Float64l,
    GreedyBytes,
    Int8ul,
    Int16ul,
    Int32ul,
    Prefixed,
    SizeofError,
    Struct,
    evaluate,
    stream_read,
    stream_write,
    this,
)

SIGNATURE = b"\x89ATM\r\n\x1a\n"
VERSION = 6

#: Chunk types. An upper-case first letter marks a critical chunk.
HEADER = b"AHDR"
MESH = b"MESH"
END = b"AEND"
QUANT = b"QUNT"
#: binary32 samples stored as 32-bit whole numbers of a step (sample_type 6, §4.10.1):
#: offset and scale, binary64, not compressed; directly after QUNT
STEP = b"STEP"
NODATA = b"NDAT"
MASK = b"MASK"
META = b"meta"
#: ancillary, empty: the decoded gray image keeps a channel axis of 1, (H, W, 1) (§4.9)
AXIS = b"axis"

#: sample_type codes -> how samples are stored. Code 2 is float data stored as 16-bit
#: integers with the QUNT chunk's scale and offset.
SAMPLE_DTYPES = {0: np.dtype("<u1"), 1: np.dtype("<u2"), 2: np.dtype("<u2"), 3: np.dtype("<u2"), 4: np.dtype("<u2"), 5: np.dtype("<u2"),
                 6: np.dtype("<u2")}
FLOAT16Q = 2
#: Code 6: binary32 samples stored exactly by the residual layer (§4.10); the mesh is a
#: preview quantised as for code 2.
FLOAT32X = 6
#: Codes 3, 4, 5: int8, int16, int32 samples stored as 16-bit integers plus the QUNT
#: chunk's whole-number offset (scale 1). Every code in QUANTISED has a QUNT chunk.
QUANTISED = (2, 3, 4, 5, 6)


class NDArray(Construct):
    """`count` little-endian numbers of `dtype`, parsed into and built from numpy arrays.

    Both arguments may be context lambdas. Parsing never allocates more than the bytes
    actually present in the stream.
    """

    def __init__(self, dtype, count):
        super().__init__()
        self.dtype = dtype
        self.count = count

    def _dtype(self, context) -> np.dtype:
        return np.dtype(evaluate(self.dtype, context)).newbyteorder("<")

    def _parse(self, stream, context, path):
        dtype = self._dtype(context)
        count = int(evaluate(self.count, context))
        data = stream_read(stream, count * dtype.itemsize, path)
        return np.frombuffer(data, dtype=dtype)

    def _build(self, obj, stream, context, path):
        dtype = self._dtype(context)
        count = int(evaluate(self.count, context))
        arr = np.ascontiguousarray(obj, dtype=dtype).reshape(-1)
        if arr.size != count:
            raise ValueError(f"{path}: expected {count} numbers, got {arr.size}")
        data = arr.tobytes()
        stream_write(stream, data, len(data), path)
        return obj

    def _sizeof(self, context, path):
        raise SizeofError("NDArray has a data-dependent size", path=path)


#: The first 10 bytes of every .atm file.
FileHeader = Struct(
    "signature" / Const(SIGNATURE),
    "version" / Int16ul,
)

#: The first 8 bytes of every chunk; read first so that `length` can be checked
#: against limits before the payload is read.
ChunkHead = Struct(
    "length" / Int32ul,
    "type" / Bytes(4),
)

#: A whole chunk. The CRC-32 (ISO-HDLC, as zlib.crc32) covers type and payload.
Chunk = Struct(
    "length" / Int32ul,
    "type" / Bytes(4),
    "payload" / Bytes(this.length),
    "crc"
    / Checksum(
        Int32ul,
        lambda data: zlib.crc32(data) & 0xFFFFFFFF,
        lambda ctx: ctx.type + ctx.payload,
    ),
)

#: AHDR payload (stored, not compressed): 10 bytes.
Header = Struct(
    "width" / Int32ul,
    "height" / Int32ul,
    "sample_type" / Int8ul,
    "channels" / Int8ul,
)

#: connectivity codes
LISTED = 0
DELAUNAY = 1

#: position_order codes: the free vertices' positions as gaps in raster order or along
#: the band's Hilbert curve
POSITIONS_RASTER = 0
POSITIONS_HILBERT = 1

#: Byte sections whose length comes first (varint streams, decoded by the codec).
Section = Prefixed(Int32ul, GreedyBytes)

#: QUNT payload (stored, not compressed): 16 bytes; required when sample_type is 2.
Quantisation = Struct(
    "offset" / Float64l,
    "scale" / Float64l,
)

#: NDAT payload (stored, not compressed): 8 bytes; the value hole pixels decode to.
NoData = Struct(
    "value" / Float64l,
)

#: MASK payload, after zstd decompression: the hole pixels of one band, as the lengths
#: of alternating runs (valid first) in raster order.
MaskPayload = Struct(
    "y0" / Int32ul,
    "rows" / Int32ul,
    "run_count" / Int32ul,
    "runs" / Section,
)

#: MESH payload, after zstd decompression: the mesh of one band of rows. Build and
#: parse it with the header's `sample_type` and `channels` as keyword arguments.
MeshPayload = Struct(
    "y0" / Int32ul,
    "rows" / Int32ul,
    "vertex_count" / Int32ul,
    "triangle_count" / Int32ul,
    "polyline_count" / Int32ul,
    "polyline_index_count" / Int32ul,
    "connectivity" / Int8ul,
    "position_order" / Int8ul,
    "triangle_crc" / Int32ul,
    "sample_step" / Int16ul,
    "polyline_lengths" / Section,
    "polyline_starts" / Section,
    "polyline_steps" / Section,
    "positions" / Section,
    "position_bits" / Section,
    "samples" / Section,
    "triangles" / Section,
)
