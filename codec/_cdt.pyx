# distutils: language = c++
"""The constrained Delaunay triangulation of ATM.md §4.2.5, compiled (codec/cdt.hpp):
the canonical triangles straight from integer vertices and segments, with the GIL
released while they are built. codec.triangulate turns the status codes into ATMError."""

from libc.stdint cimport int64_t, uint8_t, uint32_t
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
        CDT_OVER
        CDT_OUTSIDE
    cdef struct Pt:
        int x, y
    cdef cppclass Slots[X]:
        size_t size() const
        X& operator[](size_t)
        X* data()
    cdef cppclass CDT:
        vector[Pt] pt
        Slots[int] V
        vector[int] vinc
        bint narrow, track, broken
        int64_t flip_limit
        vector[int] dirty, old
        vector[unsigned char] dirty_mark
        Status build() except + nogil
        Status insert(const int64_t* xy, int64_t k, int64_t* done, const int64_t* near,
                      unsigned char* taken) except + nogil
        Status constrain(int a, int b) except + nogil
        bint legalise() nogil
    uint32_t cdt_canonical "atmcdt::canonical" (CDT& cdt, const int64_t* order,
                                               int64_t* out) nogil
    int64_t MAX_EXTENT
    void cdt_recycle "atmcdt::recycle" (CDT* cdt) nogil
    Status cdt_triangulate "atmcdt::triangulate" (
        int64_t n, const int64_t* xy, int64_t s, const int64_t* seg, bint strict,
        CDT* cdt, vector[int64_t]* order, int64_t* flips) nogil

OK = CDT_OK
CROSSING = CDT_CROSSING
DUPLICATE = CDT_DUPLICATE
EXTENT = CDT_EXTENT
INDEX = CDT_INDEX
MEMORY = CDT_MEMORY
INTERNAL = CDT_INTERNAL
OVER = CDT_OVER
OUTSIDE = CDT_OUTSIDE


def triangulate(const int64_t[:, ::1] vertices, const int64_t[:, ::1] segments, bint strict=False):
    """(status, triangles, flips, crc): the triangles (M x 3 int64, canonical order of
    ATM.md §4.2.3, positively oriented) of the N x 2 integer vertices with every segment
    (S x 2 vertex indices, checked here) an edge, cut at the vertices on it (strict:
    refused, status OVER), and the CRC-32 of their list as u32 little-endian values
    (ATM.md's triangle_crc); triangles is None and crc 0 unless status is OK."""
    cdef CDT cdt
    cdef vector[int64_t] order
    return _triangulate(&cdt, &order, vertices, segments, strict)


cdef object _triangulate(CDT* cdt, vector[int64_t]* order, const int64_t[:, ::1] vertices,
                         const int64_t[:, ::1] segments, bint strict):
    """triangulate() in *cdt (empty), its vertex order in *order."""
    if vertices.shape[1] != 2 or segments.shape[1] != 2:
        raise ValueError("vertices and segments are N x 2")
    cdef int64_t n = vertices.shape[0], s = segments.shape[0], flips = 0
    cdef const int64_t* xy = &vertices[0, 0] if n else NULL
    cdef const int64_t* seg = &segments[0, 0] if s else NULL
    cdef Status status
    cdef uint32_t crc = 0
    with nogil:
        status = cdt_triangulate(n, xy, s, seg, strict, cdt, order, &flips)
    if status != CDT_OK:
        return int(status), None, int(flips), 0
    triangles = triangle_array(cdt[0], order.data() if order.size() else NULL, &crc)
    return 0, triangles, int(flips), int(crc)


cdef class Delaunay:
    """triangulate() again and again in buffers it owns: each call after the first
    reuses the memory of the arrays that grow with the vertices (a decoder's band after
    band, file after file), where a fresh call faults in and zeroes new pages for them.
    One thread at a time (another's call meanwhile raises RuntimeError)."""

    cdef CDT cdt
    cdef vector[int64_t] order
    cdef bint busy

    def triangulate(self, const int64_t[:, ::1] vertices, const int64_t[:, ::1] segments, bint strict=False):
        """As the module's triangulate(): (status, triangles, flips, crc)."""
        if self.busy:
            raise RuntimeError("Delaunay.triangulate: the object is in use by another thread")
        self.busy = True
        try:
            cdt_recycle(&self.cdt)
            self.order.clear()
            return _triangulate(&self.cdt, &self.order, vertices, segments, strict)
        finally:
            self.busy = False


cdef object triangle_array(CDT& cdt, const int64_t* order, uint32_t* crc):
    """The canonical triangles of cdt, written straight into a new M x 3 array; *crc
    their list's CRC-32 (0 for none, as zlib's of no bytes)."""
    result = np.empty((cdt.V.size() // 3, 3), dtype=np.int64)
    cdef int64_t[:, ::1] view = result
    crc[0] = 0
    if cdt.V.size():
        with nogil:
            crc[0] = cdt_canonical(cdt, order, &view[0, 0])
    return result


cdef class Triangulation:
    """The triangulation of ATM.md §4.2.5 kept up to date as points are inserted and
    segments constrained (the encoder's refinement loop): it owns its buffers; every
    call that builds releases the GIL. Methods return a status (OK or one of the
    module's codes; codec.triangulate.Triangulation raises instead)."""

    cdef CDT cdt
    cdef bint busy

    # One thread at a time: the kernel's buffers (canonical()'s counts among them) are
    # the object's own, used with the GIL released; a second thread's call meanwhile
    # raises instead of sharing them.
    def _one_thread(self, str name, method, *args):
        if self.busy:
            raise RuntimeError(f"Triangulation.{name}: the object is in use by another thread")
        self.busy = True
        try:
            return method(*args)
        finally:
            self.busy = False

    def start(self, vertices, bint track=False):
        """Triangulate vertices (N x 2) afresh; track=True records changes() after it."""
        return self._one_thread("start", self._start, vertices, track)

    def insert(self, points, near=None, taken=None):
        """As _insert (below), one thread at a time."""
        return self._one_thread("insert", self._insert, points, near, taken)

    def constrain(self, segments):
        """As _constrain (below), one thread at a time."""
        return self._one_thread("constrain", self._constrain, segments)

    def triangles(self):
        """All triangles, M x 3, canonical order (ATM.md §4.2.3)."""
        return self._one_thread("triangles", self._triangles)

    def changes(self):
        """As _changes (below), one thread at a time."""
        return self._one_thread("changes", self._changes)

    def _start(self, const int64_t[:, ::1] vertices, bint track=False):
        """Triangulate the first N x 2 vertices (pixel coordinates 0 .. MAX_EXTENT,
        distinct, not all on one line); their indices are their rows. track: keep
        what changes() reports (each changed triangle slot's old corners)."""
        cdef int64_t n = vertices.shape[0], i
        cdef int64_t xmin = MAX_EXTENT, xmax = 0, ymin = MAX_EXTENT, ymax = 0
        cdef Pt p
        cdef Status status
        if self.cdt.pt.size():
            raise ValueError("Triangulation.start: already started")
        if vertices.shape[1] != 2:
            raise ValueError("vertices are N x 2")
        self.cdt.pt.reserve(n)
        for i in range(n):
            if not (0 <= vertices[i, 0] <= MAX_EXTENT and 0 <= vertices[i, 1] <= MAX_EXTENT):
                return CDT_EXTENT
            p.x = <int>vertices[i, 0]
            p.y = <int>vertices[i, 1]
            xmin = min(xmin, p.x); xmax = max(xmax, p.x)
            ymin = min(ymin, p.y); ymax = max(ymax, p.y)
            self.cdt.pt.push_back(p)
        # later points lie inside the hull, so this extent holds for good
        self.cdt.narrow = n > 0 and xmax - xmin < (1 << 14) and ymax - ymin < (1 << 14)
        with nogil:  # build() refuses two vertices at one position (CDT_DUPLICATE)
            status = self.cdt.build()
        if status == CDT_OK and self.cdt.V.size() == 0:
            return CDT_OUTSIDE  # all on one line: nothing to insert into
        self.cdt.track = track
        self.cdt.dirty.clear()
        self.cdt.old.clear()
        self.cdt.dirty_mark.assign(self.cdt.V.size() // 3, 0)
        return status

    def _insert(self, const int64_t[:, ::1] points, const int64_t[::1] near=None, uint8_t[::1] taken=None):
        """(status, indices): insert each point (K x 2) inside the hull; the new vertex
        indices continue the vertices' numbering in the points' order. All are checked
        first: if one is refused, only those before it go in (status: its refusal).
        near (K vertex indices, -1 for none): where each point's location walk starts,
        a hint that changes no triangle (one naming no vertex in place is ignored).
        taken (K bytes): a point at a position taken (by a vertex, or a point before
        it) is left out, not refused, and marked 1 there (the others 0)."""
        cdef int64_t k = points.shape[0], done = 0, first = self.cdt.pt.size()
        cdef const int64_t* xy = &points[0, 0] if k else NULL
        cdef const int64_t* hint = NULL
        cdef unsigned char* left_out = NULL
        cdef Status status
        if points.shape[1] != 2:
            raise ValueError("points are K x 2")
        if near is not None:
            if near.shape[0] != k:
                raise ValueError("near has one vertex index per point")
            hint = &near[0] if k else NULL
        if taken is not None:
            if taken.shape[0] != k:
                raise ValueError("taken has one entry per point")
            left_out = &taken[0] if k else NULL
        with nogil:  # every point checked in the kernel, then inserted in a spatial order
            status = self.cdt.insert(xy, k, &done, hint, left_out)
        if status == CDT_INTERNAL:  # a bug: those that went in are no prefix
            went_in = [j for j in range(first, self.cdt.pt.size()) if self.cdt.vinc[j] >= 0]
            return int(status), np.array(went_in, dtype=np.int64)
        return int(status), np.arange(first, first + done, dtype=np.int64)

    def _constrain(self, const int64_t[:, ::1] segments):
        """Make every segment (S x 2 vertex indices) an edge, cut at vertices on it."""
        cdef int64_t s = segments.shape[0], j, n = self.cdt.pt.size()
        cdef Status status = CDT_OK
        if self.cdt.broken:
            return CDT_INTERNAL
        for j in range(s):
            if not (0 <= segments[j, 0] < n and 0 <= segments[j, 1] < n):
                return CDT_INDEX
        if self.cdt.V.size() == 0:
            return CDT_OK
        with nogil:
            for j in range(s):
                if segments[j, 0] != segments[j, 1]:
                    status = self.cdt.constrain(<int>segments[j, 0], <int>segments[j, 1])
                    if status != CDT_OK:
                        break
            if not self.cdt.legalise():
                status = CDT_INTERNAL
            if status == CDT_INTERNAL:
                self.cdt.broken = True
        return int(status)

    def _limit_flips(self, int64_t limit):
        """For tests: the most flips one Lawson pass may make before it reports an
        internal error (the guard a broken predicate would meet; -1: n (n - 1) / 2)."""
        self.cdt.flip_limit = limit

    def _triangles(self):
        cdef uint32_t crc
        return triangle_array(self.cdt, NULL, &crc)

    def _changes(self):
        """(removed, added): the triangles (K x 3 each, corners in their stored
        rotation) that left and that joined the triangulation since start or the last
        call; a triangle may be in both if it was undone and made again. Only for a
        triangulation started with track=True."""
        cdef size_t j, k = self.cdt.dirty.size()
        if not self.cdt.track:
            raise ValueError("Triangulation.changes: started without track=True")
        removed, added = [], []
        for j in range(k):
            t = self.cdt.dirty[j]
            if self.cdt.old[3 * j] >= 0:
                removed.append((self.cdt.old[3 * j], self.cdt.old[3 * j + 1], self.cdt.old[3 * j + 2]))
            added.append((self.cdt.V[3 * t], self.cdt.V[3 * t + 1], self.cdt.V[3 * t + 2]))
            self.cdt.dirty_mark[t] = 0
        self.cdt.dirty.clear()
        self.cdt.old.clear()
        return (np.array(removed, dtype=np.int64).reshape(-1, 3),
                np.array(added, dtype=np.int64).reshape(-1, 3))

    def slots(self):
        """As _slots (below), one thread at a time."""
        return self._one_thread("slots", self._slots)

    def dirty(self, into=None):
        """As _dirty (below), one thread at a time."""
        return self._one_thread("dirty", self._dirty, into)

    def size(self):
        """The number of triangle slots (of triangles)."""
        return self.cdt.V.size() // 3

    def _slots(self):
        """Every triangle slot's triangle (M x 3, row t the triangle in slot t), each
        rotated to start at its smallest corner, orientation kept: the rotation the
        canonical order lists it in (ATM.md §4.2.3), but in slot order. A slot keeps its
        number until a change rewrites it (changes(), dirty()); new ones come last."""
        cdef int64_t m = self.cdt.V.size() // 3, t
        out = np.empty((m, 3), dtype=np.int64)
        cdef int64_t[:, ::1] o = out
        cdef int* v = self.cdt.V.data()
        with nogil:
            for t in range(m):
                _rotated(v + 3 * t, &o[t, 0])
        return out

    def _dirty(self, int64_t[:, ::1] into=None):
        """(slots, triangles): the triangle slots written since start or the last call
        of this or changes() (one record, which both empty), in the order they were
        first written, and the triangle each holds now (K x 3, rotated as _slots
        rotates them); a slot may hold the triangle it held before. into (a row per
        slot, size() at least): each slot's triangle goes to its row there instead, and
        only the slots are returned. Only for a triangulation started with track=True."""
        cdef int64_t k = self.cdt.dirty.size(), j, t, m = self.cdt.V.size() // 3
        if not self.cdt.track:
            raise ValueError("Triangulation.dirty: started without track=True")
        if into is not None and (into.shape[0] < m or into.shape[1] != 3):
            raise ValueError("Triangulation.dirty: into needs 3 columns and a row per slot")
        slots = np.empty(k, dtype=np.int64)
        out = np.empty((k if into is None else 0, 3), dtype=np.int64)
        cdef int64_t[::1] s = slots
        cdef int64_t[:, ::1] o = out if into is None else into
        cdef int* v = self.cdt.V.data()
        cdef bint bad = False, by_slot = into is not None
        with nogil:
            for j in range(k):
                t = self.cdt.dirty[j]
                if not 0 <= t < m:
                    bad = True  # a slot written but never made: a bug, not an input
                    break
                s[j] = t
                _rotated(v + 3 * t, &o[t if by_slot else j, 0])
                self.cdt.dirty_mark[t] = 0
            if not bad:
                self.cdt.dirty.clear()
                self.cdt.old.clear()
        if bad:
            raise RuntimeError("Triangulation.dirty: a changed slot beyond the triangles")
        return slots if by_slot else (slots, out)


cdef inline void _rotated(const int* v, int64_t* out) noexcept nogil:
    """Triangle v (3 corners) rotated to start at its smallest corner (orientation kept)."""
    cdef int64_t a = v[0], b = v[1], c = v[2], r
    if b < a and b < c:
        r = a; a = b; b = c; c = r
    elif c < a and c < b:
        r = c; c = b; b = a; a = r
    out[0] = a
    out[1] = b
    out[2] = c
