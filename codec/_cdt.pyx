# distutils: language = c++
"""The constrained Delaunay triangulation of ATM.md §4.2.5, compiled (codec/cdt.hpp):
the canonical triangles straight from integer vertices and segments, with the GIL
released while they are built. codec.triangulate turns the status codes into ATMError."""

from libc.stdint cimport int64_t
from libcpp.vector cimport vector

import numpy as np

cdef extern from "cdt.hpp" namespace "atmcdt":
    ctypedef enum Status:
        CDT_OK
        CDT_CROSSING
        CDT_DUPLICATE
        CDT_EXTENT
        CDT_INDEX
        CDT_MEMORY
        CDT_INTERNAL
    Status cdt_triangulate "atmcdt::triangulate" (
        int64_t n, const int64_t* xy, int64_t s, const int64_t* seg,
        vector[int64_t]* out, int64_t* flips) nogil

OK = CDT_OK
CROSSING = CDT_CROSSING
DUPLICATE = CDT_DUPLICATE
EXTENT = CDT_EXTENT
INDEX = CDT_INDEX
MEMORY = CDT_MEMORY
INTERNAL = CDT_INTERNAL


def triangulate(const int64_t[:, ::1] vertices, const int64_t[:, ::1] segments):
    """(status, triangles, flips): the triangles (M x 3 int64, canonical order of ATM.md
    §4.2.3, positively oriented) of the N x 2 integer vertices with every segment (S x 2
    vertex indices, checked here) an edge; triangles is None unless status is OK."""
    if vertices.shape[1] != 2 or segments.shape[1] != 2:
        raise ValueError("vertices and segments are N x 2")
    cdef int64_t n = vertices.shape[0], s = segments.shape[0], flips = 0
    cdef vector[int64_t] out
    cdef const int64_t* xy = &vertices[0, 0] if n else NULL
    cdef const int64_t* seg = &segments[0, 0] if s else NULL
    cdef Status status
    with nogil:
        status = cdt_triangulate(n, xy, s, seg, &out, &flips)
    if status != CDT_OK:
        return int(status), None, int(flips)
    result = np.empty((out.size() // 3, 3), dtype=np.int64)
    cdef int64_t[:, ::1] r = result
    cdef size_t i
    for i in range(out.size()):
        r[i // 3, i % 3] = out[i]
    return 0, result, int(flips)
