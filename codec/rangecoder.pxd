# The byte output of LZMA's binary range encoder (ATM.md §4.8.2), as inline functions
# the kernels cimport (codec._residual's layer and codec._mask's HOLE chunk).

from libc.stdint cimport uint8_t, uint32_t, uint64_t
from libc.stdlib cimport free, malloc, realloc


cdef struct RangeEncoder:
    uint64_t low
    uint32_t rng
    uint8_t cache
    uint64_t pending
    uint8_t* buf
    size_t size
    size_t cap
    int failed


cdef inline int rc_begin(RangeEncoder* e) noexcept nogil:
    # 0 on success, -1 if the first buffer cannot be had
    e.low = 0
    e.rng = 0xFFFFFFFF
    e.cache = 0
    e.pending = 0
    e.size = 0
    e.cap = 4096
    e.failed = 0
    e.buf = <uint8_t*>malloc(e.cap)
    return 0 if e.buf != NULL else -1


cdef inline void rc_put(RangeEncoder* e, uint8_t b) noexcept nogil:
    cdef uint8_t* grown
    if e.size == e.cap:
        grown = <uint8_t*>realloc(e.buf, e.cap * 2 + 64)
        if grown == NULL:
            e.failed = 1
            return
        e.buf = grown
        e.cap = e.cap * 2 + 64
    e.buf[e.size] = b
    e.size += 1


cdef inline void rc_shift_low(RangeEncoder* e) noexcept nogil:
    # a byte is held back while a carry may still reach it
    cdef uint8_t carry
    if e.low < <uint64_t>0xFF000000 or e.low >= (<uint64_t>1 << 32):
        carry = <uint8_t>(e.low >> 32)
        rc_put(e, <uint8_t>(e.cache + carry))
        while e.pending:
            rc_put(e, <uint8_t>(0xFF + carry))
            e.pending -= 1
        e.cache = <uint8_t>((e.low >> 24) & 0xFF)
    else:
        e.pending += 1
    e.low = (e.low & 0x00FFFFFF) << 8


cdef inline void rc_flush(RangeEncoder* e) noexcept nogil:
    # the last bytes: five shifts of low (the first byte out, always 0, is not stored)
    cdef int i
    for i in range(5):
        rc_shift_low(e)
