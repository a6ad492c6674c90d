# cython: boundscheck=False, wraparound=False, cdivision=True
"""Kernel of the context-coded hole mask (ATM.md §4.10, the HOLE chunk): each pixel's
bit (1: a hole) is coded in raster order by a binary range coder (LZMA's, as the
residual layer's, §4.8.2) with an adaptive model chosen by twelve neighbouring bits
already coded, as JBIG's templates do. Encoder and decoder share the model. The loops
release the GIL; the decoder never reads past the chunk and reports a chunk it cannot
decode (status codes; codec.holes turns them into CorruptError)."""

from libc.stdint cimport int64_t, uint8_t, uint16_t, uint32_t, uint64_t
from libc.stdlib cimport free, malloc
from libc.string cimport memset

import numpy as np

from codec.rangecoder cimport RangeEncoder, rc_begin, rc_flush, rc_shift_low

#: Context bits: four to the left, five in the row above, three two rows up.
DEF BITS = 12
DEF CONTEXTS = 1 << BITS
#: Adaptation (as §4.8.2): the steady estimate moves by at most 1/2^MAX_SHIFT of the
#: way to the coded bit, the fast one by at least 1/2^FAST_SHIFT.
DEF MAX_SHIFT = 8
DEF FAST_SHIFT = 4
DEF TOP = 1 << 24

cpdef enum Status:
    MASK_OK = 0
    MASK_OVERRUN = 1   # the coder read past the end of the chunk
    MASK_TRAILING = 2  # the coder left bytes of the chunk unread
    MASK_MEMORY = 3

CONTEXT_BITS = BITS


cdef struct Models:
    uint16_t fast[CONTEXTS]
    uint16_t steady[CONTEXTS]
    uint8_t count[CONTEXTS]


cdef uint8_t SHIFTS[256]
cdef int _i
for _i in range(256):
    # floor(log2(n + 2)), at most MAX_SHIFT
    SHIFTS[_i] = min((_i + 2).bit_length() - 1, MAX_SHIFT)


cdef inline void _fresh(Models* m) noexcept nogil:
    cdef int i
    for i in range(CONTEXTS):
        m.fast[i] = 32768
        m.steady[i] = 32768
    memset(m.count, 0, CONTEXTS)


cdef inline uint32_t _p(Models* m, int c) noexcept nogil:
    return (<uint32_t>m.fast[c] + m.steady[c]) >> 1


cdef inline void _update(Models* m, int c, int bit) noexcept nogil:
    cdef int s = SHIFTS[m.count[c]]
    cdef int f = s if s < FAST_SHIFT else FAST_SHIFT
    if bit:
        m.fast[c] -= m.fast[c] >> f
        m.steady[c] -= m.steady[c] >> s
    else:
        m.fast[c] += (65536 - m.fast[c]) >> f
        m.steady[c] += (65536 - m.steady[c]) >> s
    if m.count[c] < 255:
        m.count[c] += 1


#: Padding of the rows a coder keeps: PAD zero pixels left of column 0 (the template
#: reaches 4 left), 3 right of the last (2, and 1 read after a row's last pixel), and
#: two zero rows above the band.
DEF PAD = 4


cdef inline int _start(const uint8_t* up, const uint8_t* up2) noexcept nogil:
    # the context of column 0 but for its left part: rows above at x - 2 .. x + 2 and
    # x - 1 .. x + 1 (padded rows: columns -4..-1 are 0)
    cdef const uint8_t* a = up - 2
    cdef const uint8_t* b = up2 - 1
    return a[0] << 4 | a[1] << 5 | a[2] << 6 | a[3] << 7 | a[4] << 8 | b[0] << 9 | b[1] << 10 | b[2] << 11


cdef inline int _next_context(int c, int bit, const uint8_t* up, const uint8_t* up2, int64_t x) noexcept nogil:
    # the template of ATM.md §4.10 moved one pixel right: the left bits take `bit` (the
    # pixel just coded), the windows above drop their leftmost pixel and take x + 3 / x + 2
    return ((c << 1 | bit) & 0xF) | (((c >> 1) & 0xF0) | up[x + 3] << 8) & 0x1F0 \
        | (((c >> 1) & 0x600) | up2[x + 2] << 11) & 0xE00


def encode(const uint8_t[:, ::1] holes):
    """The coded bytes of a band's mask (rows x W, 0 or 1; 1: a hole)."""
    cdef int64_t rows = holes.shape[0], w = holes.shape[1], x, y
    cdef RangeEncoder e
    cdef Models* m = <Models*>malloc(sizeof(Models))
    cdef const uint8_t* row
    cdef const uint8_t* up
    cdef const uint8_t* up2
    cdef int c, bit
    cdef uint32_t bound
    if m == NULL:
        raise MemoryError()
    padded = np.zeros((rows + 2, w + PAD + 3), np.uint8)
    padded[2:, PAD : PAD + w] = np.asarray(holes) != 0
    cdef const uint8_t[:, ::1] pv = padded
    if rc_begin(&e) != 0:
        free(m)
        raise MemoryError()
    try:
        with nogil:
            _fresh(m)
            for y in range(rows):
                row, up, up2 = &pv[y + 2, PAD], &pv[y + 1, PAD], &pv[y, PAD]
                c = _start(up, up2)
                for x in range(w):
                    bit = row[x]
                    bound = (e.rng >> 16) * _p(m, c)
                    if bit:
                        e.low += bound
                        e.rng -= bound
                    else:
                        e.rng = bound
                    while e.rng < TOP:
                        e.rng <<= 8
                        rc_shift_low(&e)
                    _update(m, c, bit)
                    c = _next_context(c, bit, up, up2, x)
            rc_flush(&e)
        if e.failed:
            raise MemoryError()
        # LZMA's coder always starts with a zero byte: it is not stored
        return bytes(e.buf[1 : e.size])
    finally:
        free(e.buf)
        free(m)


def decode(const uint8_t[::1] data, int64_t rows, int64_t w):
    """(status, rows x W bool mask) of a chunk's coded bytes; the mask is None unless
    the status is MASK_OK. The caller checked rows and w against the image."""
    cdef int64_t x, y, at = 0, size = data.shape[0]
    cdef uint32_t code = 0, rng = 0xFFFFFFFF, bound
    cdef int c, bit, i
    cdef Models* m = <Models*>malloc(sizeof(Models))
    cdef uint8_t* row
    cdef const uint8_t* up
    cdef const uint8_t* up2
    cdef const uint8_t* buf = &data[0] if size else NULL
    if m == NULL:
        raise MemoryError()
    padded = np.zeros((rows + 2, w + PAD + 3), np.uint8)
    cdef uint8_t[:, ::1] pv = padded
    try:
        with nogil:
            _fresh(m)
            for i in range(4):
                code = (code << 8) | (buf[at] if at < size else 0)
                at += 1
            for y in range(rows):
                row, up, up2 = &pv[y + 2, PAD], &pv[y + 1, PAD], &pv[y, PAD]
                c = _start(up, up2)
                for x in range(w):
                    bound = (rng >> 16) * _p(m, c)
                    if code < bound:
                        rng = bound
                        bit = 0
                    else:
                        code -= bound
                        rng -= bound
                        bit = 1
                    while rng < TOP:
                        rng <<= 8
                        code = (code << 8) | (buf[at] if at < size else 0)
                        at += 1
                    row[x] = bit
                    _update(m, c, bit)
                    c = _next_context(c, bit, up, up2, x)
                if at > size:
                    break  # past the chunk's end: corrupt, whatever follows
    finally:
        free(m)
    if at > size:
        return MASK_OVERRUN, None
    if at < size:
        return MASK_TRAILING, None
    return MASK_OK, padded[2:, PAD : PAD + w].astype(bool)
