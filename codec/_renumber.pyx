"""Encoder kernel: a triangulation renumbered and put in canonical order (ATM.md
§4.2.3) in one linear pass, for refinement, whose incremental triangulation numbers
vertices in insertion order while the mesh keeps them in stored order. The GIL is
released while it works."""

from libc.stdint cimport int64_t

import numpy as np


def canonical_renumbered(const int64_t[:, ::1] triangles, const int64_t[::1] number):
    """The rows of number[triangles] (M x 3 int64, `number` a permutation of 0..N-1)
    each rotated to start at its smallest corner (orientation kept), the rows sorted:
    coding.canonical_triangles of it, by a counting sort on the first corner and an
    insertion sort within each fan (a vertex starts a few triangles) instead of a
    comparison sort of all rows. ValueError if a corner or a number is out of range."""
    cdef int64_t m = triangles.shape[0], n = number.shape[0], t, i, j, a, b, c, r
    cdef bint bad = False
    if triangles.shape[1] != 3:
        raise ValueError("canonical_renumbered: an M x 3 array")
    # zeros: a slot not yet filled never reads as part of a later vertex's fan
    out = np.zeros((m, 3), dtype=np.int64)
    start_array = np.zeros(n + 1, dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    cdef int64_t[::1] start = start_array
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
                    j -= 1
                o[j, 0] = a; o[j, 1] = b; o[j, 2] = c
    if bad:
        raise ValueError("canonical_renumbered: a corner or a number out of range")
    return out
