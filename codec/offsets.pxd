# The check of an offsets array (run k is starts[k] .. starts[k + 1] - 1 of `total`
# items), as an inline function the kernels that take one cimport (codec._elements'
# span statistics and totals, codec._polylines' wall segments); each raises its own
# message from the code it returns.

from libc.stdint cimport int64_t

#: offsets_fault's codes: the runs fit, the ends are not 0 and total, a run ends before it starts
cdef enum:
    OFFSETS_OK = 0
    OFFSETS_ENDS = 1
    OFFSETS_DECREASE = 2


cdef inline int offsets_fault(const int64_t[::1] starts, Py_ssize_t runs, int64_t total) noexcept nogil:
    # starts holds runs + 1 values (the caller has checked runs >= 0 and the length)
    cdef Py_ssize_t k
    if starts[0] != 0 or starts[runs] != total:
        return OFFSETS_ENDS
    for k in range(runs):
        if starts[k + 1] < starts[k]:
            return OFFSETS_DECREASE
    return OFFSETS_OK
