"""Integer coding primitives for MESH payloads (format_spec/ATM.md §4.2), vectorised:
LEB128 varints, zigzag, the Hilbert order of vertices, canonical triangle lists."""

from __future__ import annotations

import functools
import zlib

import numpy as np

from .errors import CorruptError
from .native import _fields, _samples

#: Longest varint accepted: 5 bytes hold every value below 2**35.
MAX_VARINT_BYTES = 5


def varints(values: np.ndarray) -> bytes:
    """Unsigned LEB128: 7 bits per byte, low group first, high bit set on all bytes
    but the last of each number."""
    # one compiled pass (the encoder writes seven such fields a band)
    return _samples.varints(np.ascontiguousarray(np.asarray(values, dtype=np.uint64).ravel()))


def unvarints(data: bytes, count: int, what: str) -> np.ndarray:
    """Decode exactly `count` varints that fill `data` (int64); CorruptError otherwise."""
    b = np.frombuffer(data, dtype=np.uint8)
    status, out = _fields.unvarints(b, count, MAX_VARINT_BYTES)
    if status == _fields.Varints.VARINTS_COUNT:
        raise CorruptError(f"{what}: {b.size} bytes do not hold {count} numbers")
    if status == _fields.Varints.VARINTS_LONG:
        raise CorruptError(f"{what}: a number is longer than {MAX_VARINT_BYTES} bytes")
    return out


def zigzag(v: np.ndarray) -> np.ndarray:
    """Signed -> unsigned: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ..."""
    v = np.asarray(v, dtype=np.int64)
    return np.where(v < 0, -2 * v - 1, 2 * v).astype(np.uint64)


def unzigzag(u: np.ndarray) -> np.ndarray:
    """Unsigned -> signed, the inverse of zigzag (int64)."""
    u = np.asarray(u, dtype=np.int64)
    # -(u & 1) is all ones for odd u, and x ^ -1 = -x - 1
    return (u >> 1) ^ -(u & 1)


def _frozen(table: np.ndarray) -> np.ndarray:
    """`table` made read-only: the cached tables are handed to every caller, so one
    caller's write would change every later encode and decode."""
    table.setflags(write=False)
    return table


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


_HILBERT_DIGIT, _HILBERT_NEXT = (_frozen(t) for t in _hilbert_tables())

#: Bits of x and of y that one lookup of hilbert_keys consumes.
_HILBERT_GROUP = 5


@functools.cache
def _hilbert_group_tables() -> tuple[np.ndarray, np.ndarray]:
    """The one-bit tables composed over _HILBERT_GROUP levels: index state * 4**g + x
    bits * 2**g + y bits (high level first) -> (2g-bit digit, next state). Built on
    first use, by running the one-bit machine on every index at once."""
    g = _HILBERT_GROUP
    i = np.arange(4 << (2 * g))
    state = (i >> (2 * g)).astype(np.uint8)
    gx, gy = (i >> g) & ((1 << g) - 1), i & ((1 << g) - 1)
    digit = np.zeros(len(i), dtype=np.int64)
    for k in range(g - 1, -1, -1):
        j = state * np.uint8(4) + (((gx >> k) & 1) * 2 + ((gy >> k) & 1)).astype(np.uint8)
        digit = (digit << 2) | _HILBERT_DIGIT[j]
        state = _HILBERT_NEXT[j]
    return _frozen(digit), _frozen(state.astype(np.int64) << (2 * g))


@functools.cache
def _hilbert_inverse_tables() -> tuple[np.ndarray, np.ndarray]:
    """The group tables read backwards: index state * 4**g + 2g-bit digit -> (x bits *
    2**g + y bits, next state), so that a key is turned back into its pixel g levels
    per lookup."""
    g = _HILBERT_GROUP
    digit, nxt = _hilbert_group_tables()
    i = np.arange(len(digit))
    state = i >> (2 * g)
    xy = np.empty(len(digit), dtype=np.int64)
    back = np.empty(len(digit), dtype=np.int64)
    # within one state, the 4**g bit pairs map one to one onto the 4**g digits
    at = (state << (2 * g)) | digit
    xy[at] = i & ((1 << (2 * g)) - 1)
    back[at] = nxt
    return _frozen(xy), _frozen(back)


def _hilbert_start(levels: int) -> tuple[int, int]:
    """(number of g-level groups, starting state) for a 2**levels square. The levels
    are taken g at a time, from a multiple of g. A level whose bits are both 0 adds a
    0 digit and toggles the swap (state 0 <-> 2, the only states reached from 0 that
    way), so padding levels above the top leave d alone and the state at the top level
    2 if their number is odd."""
    g = _HILBERT_GROUP
    groups = -(-levels // g)
    return groups, ((groups * g - levels) & 1) << (2 * g + 1)


def hilbert_levels(width: int, height: int) -> int:
    """The number of levels of the Hilbert curve over a width x height band: the
    smallest square of side 2**levels that holds its pixels (ATM.md §4.2.2)."""
    return (max(width, height) - 1).bit_length()


def hilbert_keys(x: np.ndarray, y: np.ndarray, levels: int) -> np.ndarray:
    """Position of each (x, y) along the Hilbert curve over the 2**levels square (the
    classic xy -> d mapping, ATM.md §4.2.2); x and y must be below 2**levels."""
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    digit, nxt = _hilbert_group_tables()
    groups, start = _hilbert_start(levels)
    # a compiled loop over the points: numpy passes per group cost more on small bands
    d = _fields.hilbert_keys(np.ascontiguousarray(x).ravel(), np.ascontiguousarray(y).ravel(), digit, nxt,
                             _HILBERT_GROUP, groups, start)
    return d.reshape(x.shape)


def hilbert_tables(levels: int) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """(digit table, next-state table, bits a lookup, groups, starting state): what
    _fields' Hilbert kernels take for keys over the 2**levels square."""
    digit, nxt = _hilbert_group_tables()
    return (digit, nxt, _HILBERT_GROUP) + _hilbert_start(levels)


def hilbert_inverse_tables() -> tuple[np.ndarray, np.ndarray]:
    """(pixel table, next-state table): what _fields' kernels take to turn keys back
    into pixels (hilbert_points'), with hilbert_tables' bits, groups and state."""
    return _hilbert_inverse_tables()


def hilbert_points(d: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of each key d < 4**levels along the Hilbert curve over the 2**levels
    square: the inverse of hilbert_keys."""
    d = np.asarray(d, dtype=np.int64)
    xy, back = _hilbert_inverse_tables()
    groups, start = _hilbert_start(levels)
    # a compiled loop over the keys, as hilbert_keys
    x, y = _fields.hilbert_points(np.ascontiguousarray(d).ravel(), xy, back, _HILBERT_GROUP, groups, start)
    return x.reshape(d.shape), y.reshape(d.shape)


def canonical_triangles(triangles: np.ndarray) -> np.ndarray:
    """Each triangle rotated (orientation kept) to start at its smallest index, the rows
    sorted: one list for a triangulation, whatever order it was made in."""
    # a compiled pass: numpy's passes cost more than the work on a small band
    return _fields.canonical_triangles(np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3))


def triangle_crc(canonical: np.ndarray) -> int:
    """CRC-32 of a canonical triangle list as little-endian u32 triples."""
    # the array's own buffer: no copy to bytes first
    return zlib.crc32(np.ascontiguousarray(canonical, dtype="<u4").reshape(-1).view(np.uint8)) & 0xFFFFFFFF


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
