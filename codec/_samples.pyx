"""Encoder kernel: a band's samples quantised closed-loop along the sample tree
(codec.meshcode.quantise): each sample is rounded to a multiple of its step away from
its parent's sample as the decoder rebuilds it, so rounding errors do not add up. The
decoder's side is a sum along the tree (codec._fields.tree_sums). Sequential by
nature, so a compiled loop (a Python loop over the vertices took 1-1.5 ms of a 50 ms
encode of a 512² image). The GIL is released while it works."""

from libc.stdint cimport int64_t, uint8_t, uint64_t

import numpy as np


cdef inline int64_t _floordiv(int64_t a, int64_t b) noexcept nogil:
    """Python's a // b for b > 0 (rounds toward minus infinity)."""
    cdef int64_t q = a // b
    if a % b != 0 and a < 0:
        q -= 1
    return q


def quantised(const int64_t[:, ::1] values, const int64_t[::1] steps, const int64_t[::1] parents, int64_t top):
    """N x C int64: values (N x C, in sample order) as rebuilt from residuals coded
    against their parents' rebuilt samples (parents[i] < i; -1: predicted from 0) with
    steps[i] > 0: prev + round-half-up((v - prev) / s) * s, then moved by whole steps
    into 0 .. top, exactly as meshcode.quantise's Python loop did. ValueError on a step
    below 1, a parent that is not an earlier sample, or sizes that do not match."""
    cdef int64_t n = values.shape[0], ch = values.shape[1], i, c, p, s, prev
    if steps.shape[0] != n or parents.shape[0] != n:
        raise ValueError("quantised: a step and a parent per sample")
    for i in range(n):
        if steps[i] < 1:
            raise ValueError("quantised: a step below 1")
        if not -1 <= parents[i] < i:
            raise ValueError("quantised: a parent that is not an earlier sample")
    out = np.empty((n, ch), dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    with nogil:
        for c in range(ch):
            for i in range(n):
                p = parents[i]
                prev = 0 if p < 0 else o[p, c]
                s = steps[i]
                prev += _floordiv(2 * (values[i, c] - prev) + s, 2 * s) * s
                if prev > top:
                    prev -= (prev - top + s - 1) // s * s
                elif prev < 0:
                    prev -= _floordiv(prev, s) * s
                o[i, c] = prev
    return out


def varint_histograms(const int64_t[::1] values, int64_t first, int64_t last):
    """For each shift k = first .. last, the histogram (256 counts) of the bytes of the
    varints (coding.varints: 7 bits a byte, low first, the top bit set on all but the
    last) of values >> k, and the number of those bytes: what
    meshcode._varint_entropy counts for one k, for all of them in one pass each.
    ValueError on a negative value or shift."""
    cdef Py_ssize_t n = values.shape[0], i
    cdef int64_t k, v
    if first < 0 or last < first or last > 62:
        raise ValueError("varint_histograms: shifts 0 <= first <= last <= 62")
    for i in range(n):
        if values[i] < 0:
            raise ValueError("varint_histograms: a negative value")
    counts_a = np.zeros((last - first + 1, 256), dtype=np.int64)
    cdef int64_t[:, ::1] counts = counts_a
    with nogil:
        for k in range(first, last + 1):
            for i in range(n):
                v = values[i] >> k
                while v >= 128:
                    counts[k - first, (v & 127) | 128] += 1
                    v >>= 7
                counts[k - first, v] += 1
    return counts_a


def varints(const uint64_t[::1] values):
    """Unsigned LEB128 of `values` (codec.coding.varints: 7 bits a byte, low group
    first, the high bit set on every byte but a number's last) as bytes, in two passes
    (the sizes, then the bytes) instead of numpy's repeat/shift/mask temporaries."""
    cdef Py_ssize_t n = values.shape[0], i, total = 0, j = 0
    cdef uint64_t v
    with nogil:
        for i in range(n):
            v = values[i] >> 7
            total += 1
            while v:
                total += 1
                v >>= 7
    out_a = np.empty(total, dtype=np.uint8)
    if total == 0:
        return b""
    cdef uint8_t[::1] out = out_a
    with nogil:
        for i in range(n):
            v = values[i]
            while v >= 0x80:
                out[j] = <uint8_t>(v & 0x7F) | 0x80
                j += 1
                v >>= 7
            out[j] = <uint8_t>v
            j += 1
    return out_a.tobytes()
