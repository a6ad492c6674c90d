"""Kernels of MESH field decoding (ATM.md §4.2), sequential loops that numpy can only
express as several passes: LEB128 varints, the sample tree's parents and its running
sums, and the fan areas of the vertex steps. Each releases the GIL and checks every
index it reads; the callers (codec.coding, codec.meshcode) turn status codes into
CorruptError with their own messages."""

from libc.stdint cimport int64_t, uint8_t, uint64_t

import numpy as np

cpdef enum Varints:
    VARINTS_OK = 0
    VARINTS_COUNT = 1   # the bytes do not hold exactly `count` numbers
    VARINTS_LONG = 2    # a number is longer than the longest allowed


def unvarints(const uint8_t[::1] data, int64_t count, int64_t longest):
    """(status, values): exactly `count` unsigned LEB128 numbers filling `data`, none
    longer than `longest` bytes (<= 9, so every value fits an int64). The count is
    checked before anything is allocated: a file cannot make it allocate more than
    its own length (values is None on an error)."""
    cdef int64_t n = data.shape[0], i, k = 0, ends = 0, length = 0
    cdef uint64_t value = 0
    cdef int shift = 0
    if longest > 9 or count < 0:
        raise ValueError("unvarints: at most 9 bytes a number, and a count >= 0")
    with nogil:
        # the count first: the number of last bytes, and a last byte at the end
        for i in range(n):
            ends += data[i] < 0x80
    if ends != count or (n and data[n - 1] >= 0x80):
        return VARINTS_COUNT, None
    out = np.empty(count, dtype=np.int64)
    cdef int64_t[::1] o = out
    with nogil:
        for i in range(n):
            value |= <uint64_t>(data[i] & 0x7F) << shift
            shift += 7
            length += 1
            if data[i] < 0x80:
                o[k] = <int64_t>value
                k += 1
                value = 0
                shift = 0
                length = 0
            elif length >= longest:
                break
    if length:  # stopped inside a number longer than `longest`
        return VARINTS_LONG, None
    return VARINTS_OK, out


def sample_parents(const int64_t[:, ::1] triangles, const int64_t[::1] seq_order):
    """The parent place of each place of the sample sequence (see
    meshcode.sample_parents); None if an index is out of range or seq_order is no
    permutation."""
    cdef int64_t n = seq_order.shape[0], m = triangles.shape[0], j, k, a, b, c, lo, mid, hi
    parent = np.empty(n, dtype=np.int64)
    pos_arr = np.full(n, -1, dtype=np.int64)
    cdef int64_t[::1] p = parent
    cdef int64_t[::1] pos = pos_arr
    cdef bint bad = False
    with nogil:
        for j in range(n):
            k = seq_order[j]
            if k < 0 or k >= n or pos[k] >= 0:
                bad = True
                break
            pos[k] = j
            p[j] = -1
        if not bad:
            for k in range(m):
                a = triangles[k, 0]; b = triangles[k, 1]; c = triangles[k, 2]
                if not (0 <= a < n and 0 <= b < n and 0 <= c < n):
                    bad = True
                    break
                a = pos[a]; b = pos[b]; c = pos[c]
                lo = a if a < b else b
                lo = lo if lo < c else c
                hi = a if a > b else b
                hi = hi if hi > c else c
                mid = a + b + c - lo - hi
                # the last corner's candidate is the middle one, the middle one's the
                # first, strictly earlier (a listed triangle may repeat a corner)
                if mid < hi and mid > p[hi]:
                    p[hi] = mid
                if lo < mid and lo > p[mid]:
                    p[mid] = lo
            for j in range(n):
                if p[j] < 0:
                    p[j] = j - 1
    return None if bad else parent


def tree_sums(const int64_t[:, ::1] increments, const int64_t[::1] parent):
    """Each row as its increment plus its parent's row (parent[j] < j; -1: none), in
    int64 with wrap-around like numpy's; None if a parent is not earlier."""
    cdef int64_t n = increments.shape[0], c = increments.shape[1], j, q, ch
    out = np.empty((n, c), dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    cdef bint bad = parent.shape[0] != n
    with nogil:
        if not bad:
            for j in range(n):
                q = parent[j]
                if q >= j or q < -1:
                    bad = True
                    break
                for ch in range(c):
                    if q < 0:
                        o[j, ch] = increments[j, ch]
                    else:
                        # unsigned: wraps as numpy does, where signed overflow is undefined
                        o[j, ch] = <int64_t>(<uint64_t>increments[j, ch] + <uint64_t>o[q, ch])
    return None if bad else out


def fan_areas(const int64_t[:, ::1] triangles, const int64_t[::1] areas, int64_t n):
    """The summed doubled areas of each vertex's triangles (n vertices); None if a
    corner is out of range."""
    cdef int64_t m = triangles.shape[0], k, i, v
    fan = np.zeros(n, dtype=np.int64)
    cdef int64_t[::1] f = fan
    cdef bint bad = areas.shape[0] != m
    with nogil:
        if not bad:
            for k in range(m):
                for i in range(3):
                    v = triangles[k, i]
                    if v < 0 or v >= n:
                        bad = True
                        break
                    f[v] += areas[k]
                if bad:
                    break
    return None if bad else fan
