# cython: boundscheck=False, wraparound=False, cdivision=True
"""Kernel of the context-coded hole mask (ATM.md §4.11, the HOLE chunk): each pixel's
bit (1: a hole) is coded in raster order by a binary range coder (LZMA's, as the
residual layer's, §4.8.2) with an adaptive model chosen by twelve neighbouring bits
already coded, as JBIG's templates do. Encoder and decoder share the model. The loops
release the GIL; the decoder never reads past the chunk and reports a chunk it cannot
decode (status codes; codec.holes turns them into CorruptError)."""

from libc.stdint cimport int64_t, uint8_t, uint16_t, uint32_t, uint64_t
from libc.stdlib cimport free, malloc

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


cdef struct Model:
    # a context's two estimates of the probability of a 0 and its count (§4.8.2)
    uint16_t fast
    uint16_t steady
    uint8_t count


cdef struct Models:
    Model m[CONTEXTS]


#: The count's adaptation shifts (§4.8.2): the steady one, floor(log2(n + 2)) at most
#: MAX_SHIFT, and the fast one, at most FAST_SHIFT.
cdef uint8_t STEADY[256]
cdef uint8_t FAST[256]
cdef int _i
for _i in range(256):
    STEADY[_i] = min((_i + 2).bit_length() - 1, MAX_SHIFT)
    FAST[_i] = min(STEADY[_i], FAST_SHIFT)


cdef inline void _fresh(Models* m) noexcept nogil:
    cdef int i
    for i in range(CONTEXTS):
        m.m[i].fast = 32768
        m.m[i].steady = 32768
        m.m[i].count = 0


cdef inline uint32_t _p(Model* m) noexcept nogil:
    return (<uint32_t>m.fast + m.steady) >> 1


cdef inline void _zero(Model* m) noexcept nogil:
    # a 0 was coded: both estimates move towards it
    m.fast += (65536 - m.fast) >> FAST[m.count]
    m.steady += (65536 - m.steady) >> STEADY[m.count]
    m.count += m.count < 255


cdef inline void _one(Model* m) noexcept nogil:
    m.fast -= m.fast >> FAST[m.count]
    m.steady -= m.steady >> STEADY[m.count]
    m.count += m.count < 255


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
    # the template of ATM.md §4.11 moved one pixel right: the left bits take `bit` (the
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
    cdef Model* model
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
                    model = &m.m[c]
                    bound = (e.rng >> 16) * _p(model)
                    if bit:
                        e.low += bound
                        e.rng -= bound
                        _one(model)
                    else:
                        e.rng = bound
                        _zero(model)
                    while e.rng < TOP:
                        e.rng <<= 8
                        rc_shift_low(&e)
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
    cdef Model* model
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
                    model = &m.m[c]
                    bound = (rng >> 16) * _p(model)
                    if code < bound:
                        rng = bound
                        bit = 0
                        _zero(model)
                    else:
                        code -= bound
                        rng -= bound
                        bit = 1
                        _one(model)
                    while rng < TOP:
                        rng <<= 8
                        code = (code << 8) | (buf[at] if at < size else 0)
                        at += 1
                    row[x] = bit
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
