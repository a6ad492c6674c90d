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


# The Hilbert mapping of ATM.md §4.2.2 as a state machine: the reflections and swaps
# the reference loop applies to the lower bits form the group {identity, swap,
# complement, both}, so one small table per level replaces its per-level np.where's.
# Index: state * 4 + 2 * bit_x + bit_y -> (digit, next state); state = 2*swap + complement.
def _hilbert_tables() -> tuple[np.ndarray, np.ndarray]:
    digit = np.zeros(16, dtype=np.int64)
    nxt = np.zeros(16, dtype=np.uint8)
    for swap in (0, 1):
        for comp in (0, 1):
            for bx in (0, 1):
                for by in (0, 1):
                    rx, ry = bx ^ comp, by ^ comp
                    if swap:
                        rx, ry = ry, rx
                    s2, c2 = swap, comp
                    if ry == 0:
                        s2 ^= 1
                        c2 ^= rx
                    i = (2 * swap + comp) * 4 + 2 * bx + by
                    digit[i] = (3 * rx) ^ ry
                    nxt[i] = 2 * s2 + c2
    return digit, nxt


_HILBERT_DIGIT, _HILBERT_NEXT = _hilbert_tables()


def hilbert_keys(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Position of each (x, y) along the Hilbert curve over the smallest 2^k square
    that holds them all (the classic xy -> d mapping, ATM.md §4.2.2)."""
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    top = int(max(x.max(initial=0), y.max(initial=0)))
    d = np.zeros(x.shape, dtype=np.int64)
    state = np.zeros(x.shape, dtype=np.uint8)
    for k in range(top.bit_length() - 1, -1, -1):
        i = state * np.uint8(4) + (((x >> k) & 1) * 2 + ((y >> k) & 1)).astype(np.uint8)
        d = (d << 2) | _HILBERT_DIGIT[i]
        state = _HILBERT_NEXT[i]
    return d


def canonical_triangles(triangles: np.ndarray) -> np.ndarray:
    """Each triangle rotated (orientation kept) to start at its smallest index, the rows
    sorted: one list for a triangulation, whatever order it was made in."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return t
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    first_b = (b < a) & (b < c)
    first_c = (c < a) & (c < b)
    r0 = np.where(first_b, b, np.where(first_c, c, a))
    r1 = np.where(first_b, c, np.where(first_c, a, b))
    r2 = np.where(first_b, a, np.where(first_c, b, c))
    n = int(t.max()) + 1
    if n < 1 << 21:  # the three indices fit one int64 sort key, distinct per triangle
        keys = np.sort((r0 * n + r1) * n + r2)
        if len(keys) < 2 or (keys[1:] != keys[:-1]).all():
            r01, r2 = np.divmod(keys, n)
            r0, r1 = np.divmod(r01, n)
            return np.stack([r0, r1, r2], 1)
    t = np.stack([r0, r1, r2], 1)
    return t[np.lexsort((r2, r1, r0))]


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
