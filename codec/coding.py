"""Integer coding primitives for MESH payloads (format_spec/ATM.md §4.2), vectorised:
LEB128 varints, zigzag, the Hilbert order of vertices, canonical triangle lists."""

from __future__ import annotations

import zlib

import numpy as np

from .errors import CorruptError

#: Longest varint accepted: 5 bytes hold every value below 2**35.
MAX_VARINT_BYTES = 5


def varints(values: np.ndarray) -> bytes:
    """Unsigned LEB128: 7 bits per byte, low group first, high bit set on all bytes
    but the last of each number."""
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


def unvarints(data: bytes, count: int, what: str) -> np.ndarray:
    """Decode exactly `count` varints that fill `data`; CorruptError otherwise."""
    b = np.frombuffer(data, dtype=np.uint8)
    last = b < 0x80
    if int(last.sum()) != count or (count and not last[-1]) or (count == 0 and b.size):
        raise CorruptError(f"{what}: {b.size} bytes do not hold {count} numbers")
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    ends = np.flatnonzero(last) + 1
    starts = np.r_[0, ends[:-1]]
    lengths = ends - starts
    if lengths.max() > MAX_VARINT_BYTES:
        raise CorruptError(f"{what}: a number is longer than {MAX_VARINT_BYTES} bytes")
    k = np.arange(b.size) - np.repeat(starts, lengths)
    parts = (b & 0x7F).astype(np.int64) << (7 * k)
    return np.add.reduceat(parts, starts)


def zigzag(v: np.ndarray) -> np.ndarray:
    """Signed -> unsigned: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ..."""
    v = np.asarray(v, dtype=np.int64)
    return np.where(v < 0, -2 * v - 1, 2 * v).astype(np.uint64)


def unzigzag(u: np.ndarray) -> np.ndarray:
    u = np.asarray(u, dtype=np.int64)
    return np.where(u & 1, -(u >> 1) - 1, u >> 1)


def hilbert_keys(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Position of each (x, y) along the Hilbert curve over the smallest 2^k square
    that holds them all (the classic xy -> d mapping, ATM.md §4.2.2)."""
    x = np.asarray(x, dtype=np.int64).copy()
    y = np.asarray(y, dtype=np.int64).copy()
    top = int(max(x.max(initial=0), y.max(initial=0)))
    n = 1
    while n <= top:
        n *= 2
    d = np.zeros(x.shape, dtype=np.int64)
    s = n // 2
    while s > 0:
        rx = (x & s) > 0
        ry = (y & s) > 0
        d += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        flip = ~ry & rx
        x = np.where(flip, n - 1 - x, x)
        y = np.where(flip, n - 1 - y, y)
        swap = ~ry
        x, y = np.where(swap, y, x), np.where(swap, x, y)
        s //= 2
    return d


def canonical_triangles(triangles: np.ndarray) -> np.ndarray:
    """Each triangle rotated (orientation kept) to start at its smallest index, the rows
    sorted: one list for a triangulation, whatever order it was made in."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return t
    shift = np.argmin(t, axis=1)
    idx = (shift[:, None] + np.arange(3)[None, :]) % 3
    t = np.take_along_axis(t, idx, axis=1)
    n = int(t.max()) + 1
    if n < 1 << 21:  # the three indices fit one int64 sort key
        return t[np.argsort((t[:, 0] * n + t[:, 1]) * n + t[:, 2], kind="stable")]
    return t[np.lexsort((t[:, 2], t[:, 1], t[:, 0]))]


def triangle_crc(canonical: np.ndarray) -> int:
    """CRC-32 of a canonical triangle list as little-endian u32 triples."""
    return zlib.crc32(np.ascontiguousarray(canonical, dtype="<u4").tobytes()) & 0xFFFFFFFF


def runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of the alternating runs of False and True in `mask` (raster order),
    starting with a False run (empty if the first pixel is True)."""
    flat = np.asarray(mask, bool).ravel()
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    lengths = np.diff(bounds)
    return np.concatenate([[0], lengths]) if flat.size and flat[0] else lengths


def unruns(lengths: np.ndarray, rows: int, width: int, what: str) -> np.ndarray:
    """The rows x width mask of run `lengths` (False first); CorruptError unless they
    add up to the pixel count and only the first run is empty."""
    lengths = np.asarray(lengths, dtype=np.int64)
    if lengths.sum() != rows * width or (len(lengths) > 1 and lengths[1:].min() == 0):
        raise CorruptError(f"{what}: the runs do not describe {rows} x {width} pixels")
    values = (np.arange(len(lengths)) % 2).astype(bool)
    return np.repeat(values, lengths).reshape(rows, width)
