"""Encoder kernel: a triangulation renumbered and put in canonical order (ATM.md
§4.2.3) in one linear pass, for refinement, whose incremental triangulation numbers
vertices in insertion order while the mesh keeps them in stored order. The GIL is
released while it works."""

from libc.stdint cimport int64_t, uint64_t

import numpy as np


def canonical_renumbered(const int64_t[:, ::1] triangles, const int64_t[::1] number, bint rows=False):
    """The rows of number[triangles] (M x 3 int64, `number` a permutation of 0..N-1)
    each rotated to start at its smallest corner (orientation kept), the rows sorted:
    coding.canonical_triangles of it, by a counting sort on the first corner and an
    insertion sort within each fan (a vertex starts a few triangles) instead of a
    comparison sort of all rows. rows: also return, for each output row, the input row
    it came from (refinement keeps its triangles' statistics by the kernel's slots).
    ValueError if a corner or a number is out of range."""
    cdef int64_t m = triangles.shape[0], n = number.shape[0], t, i, j, a, b, c, r
    cdef bint bad = False
    if triangles.shape[1] != 3:
        raise ValueError("canonical_renumbered: an M x 3 array")
    # zeros: a slot not yet filled never reads as part of a later vertex's fan
    out = np.zeros((m, 3), dtype=np.int64)
    start_array = np.zeros(n + 1, dtype=np.int64)
    source_array = np.empty(m if rows else 0, dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    cdef int64_t[::1] start = start_array, source = source_array
    with nogil:
        for t in range(m):
            for i in range(3):
                j = triangles[t, i]
                if j < 0 or j >= n or number[j] < 0 or number[j] >= n:
                    bad = True
            if bad:
                break
            a = number[triangles[t, 0]]; b = number[triangles[t, 1]]; c = number[triangles[t, 2]]
            start[min(a, min(b, c)) + 1] += 1
        if not bad:
            for i in range(n):
                start[i + 1] += start[i]
            for t in range(m):
                a = number[triangles[t, 0]]; b = number[triangles[t, 1]]; c = number[triangles[t, 2]]
                if b < a and b < c:
                    r = a; a = b; b = c; c = r
                elif c < a and c < b:
                    r = c; c = b; b = a; a = r
                j = start[a]
                start[a] += 1
                # the fan of a fills its slots left to right: keep (b, c) increasing
                while j > 0 and o[j - 1, 0] == a and (o[j - 1, 1] > b or (o[j - 1, 1] == b and o[j - 1, 2] > c)):
                    o[j, 0] = o[j - 1, 0]; o[j, 1] = o[j - 1, 1]; o[j, 2] = o[j - 1, 2]
                    if rows:
                        source[j] = source[j - 1]
                    j -= 1
                o[j, 0] = a; o[j, 1] = b; o[j, 2] = c
                if rows:
                    source[j] = t
    if bad:
        raise ValueError("canonical_renumbered: a corner or a number out of range")
    return (out, source_array) if rows else out


cdef inline int64_t _slot(uint64_t key, int bits) noexcept nogil:
    # Fibonacci hashing: the high bits of the key times 2^64 / golden ratio
    return <int64_t>((key * <uint64_t>0x9E3779B97F4A7C15) >> (64 - bits))


cdef inline int64_t _gcd(int64_t a, int64_t b) noexcept nogil:
    # of |a| and |b|
    cdef int64_t r
    a = a if a >= 0 else -a
    b = b if b >= 0 else -b
    while b:
        r = a % b
        a = b
        b = r
    return a


def split_in_raster_order(const int64_t[:, ::1] vertices, const int64_t[:, ::1] segments, int64_t width):
    """triangulate.split_at_vertices(vertices, segments, width) for vertices in raster
    order (pixel numbers y width + x increasing), as refinement stores a band's: every
    segment cut at the vertices on its pixel centres, pieces in segment order and from
    each segment's first vertex on, zero-length segments dropped; the vertices found by
    a hash table of their pixel numbers. ValueError on a segment naming no vertex or
    vertices out of raster order."""
    cdef int64_t n = vertices.shape[0], s = segments.shape[0], i, j, a, b, dx, dy, g, t, x, y, key, hit, prev
    cdef int64_t pieces = 0, size, slot
    cdef int bits = 4
    if vertices.shape[1] != 2 or segments.shape[1] != 2:
        raise ValueError("split_in_raster_order: vertices N x 2, segments S x 2")
    if not 0 < width < 2**31:
        raise ValueError("split_in_raster_order: width out of range")
    for i in range(n):
        if not (0 <= vertices[i, 0] < width and 0 <= vertices[i, 1] < 2**31):
            raise ValueError("split_in_raster_order: a vertex out of range")
        if i and vertices[i, 1] * width + vertices[i, 0] <= vertices[i - 1, 1] * width + vertices[i - 1, 0]:
            raise ValueError("split_in_raster_order: vertices not in raster order")
    for j in range(s):
        if not (0 <= segments[j, 0] < n and 0 <= segments[j, 1] < n):
            raise ValueError("split_in_raster_order: a segment names no vertex")
    while (<int64_t>1 << bits) < 2 * n:
        bits += 1
    size = <int64_t>1 << bits
    table_a = np.full(size, -1, dtype=np.int64)
    cdef int64_t[::1] table = table_a
    # a piece per lattice point on a segment past its first, at most
    cdef int64_t most = 0
    for j in range(s):
        most += _gcd(vertices[segments[j, 1], 0] - vertices[segments[j, 0], 0],
                     vertices[segments[j, 1], 1] - vertices[segments[j, 0], 1])
    out = np.empty((most, 2), dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    with nogil:
        for i in range(n):
            key = vertices[i, 1] * width + vertices[i, 0]
            slot = _slot(<uint64_t>key, bits)
            while table[slot] >= 0:
                slot = (slot + 1) & (size - 1)
            table[slot] = i
        for j in range(s):
            a = segments[j, 0]
            b = segments[j, 1]
            if a == b:
                continue
            dx = vertices[b, 0] - vertices[a, 0]
            dy = vertices[b, 1] - vertices[a, 1]
            g = _gcd(dx, dy)
            dx //= g
            dy //= g
            prev = a
            for t in range(1, g + 1):
                x = vertices[a, 0] + t * dx
                y = vertices[a, 1] + t * dy
                key = y * width + x
                slot = _slot(<uint64_t>key, bits)
                hit = -1
                while table[slot] >= 0:
                    i = table[slot]
                    if vertices[i, 1] * width + vertices[i, 0] == key:
                        hit = i
                        break
                    slot = (slot + 1) & (size - 1)
                if hit >= 0:
                    o[pieces, 0] = prev
                    o[pieces, 1] = hit
                    pieces += 1
                    prev = hit
    return out[:pieces]
