"""Kernels of MESH field decoding (ATM.md §4.2), sequential loops that numpy can only
express as several passes: LEB128 varints, the sample tree's parents and its running
sums, and the fan areas of the vertex steps. Each releases the GIL and checks every
index it reads; the callers (codec.coding, codec.meshcode) turn status codes into
CorruptError with their own messages. band_values does a band's whole sample stage in
one call, so that a file of many tiny bands pays no per-array numpy overhead there."""

from libc.math cimport rint, sqrt
from libc.stdlib cimport free, malloc
from libc.string cimport memcpy, memset
from libc.stdint cimport int64_t, uint8_t, uint16_t, uint32_t, uint64_t

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
    cdef int64_t n = data.shape[0], ends
    cdef bint long_ = False
    if longest > 9 or count < 0:
        raise ValueError("unvarints: at most 9 bytes a number, and a count >= 0")
    with nogil:
        ends = _varint_scan(&data[0] if n else NULL, n, longest, &long_)
    # the count first: a file cannot make it allocate more than its own length
    if ends != count:
        return VARINTS_COUNT, None
    if long_:
        return VARINTS_LONG, None
    out = np.empty(count, dtype=np.int64)
    cdef int64_t[::1] o = out
    if count:
        with nogil:
            _leb128_into(&data[0], n, &o[0])
    return VARINTS_OK, out


def sample_parents(const int64_t[:, ::1] triangles, const int64_t[::1] seq_order):
    """The parent place of each place of the sample sequence (see
    meshcode.sample_parents); None if an index is out of range or seq_order is no
    permutation."""
    cdef int64_t n = seq_order.shape[0], m = triangles.shape[0], j, k
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
                for j in range(3):
                    if not 0 <= triangles[k, j] < n:
                        bad = True
        if not bad:
            _parents(triangles, pos, p)
    return None if bad else parent


cdef bint _corners_beyond(const int64_t* corners, int64_t count, int64_t n) noexcept nogil:
    """Whether any of `count` vertex indices lies outside 0..n-1 (one unsigned
    comparison each, without a branch: a loop the compiler vectorises)."""
    cdef uint64_t bad = 0
    cdef int64_t i
    for i in range(count):
        bad |= <uint64_t>corners[i] >= <uint64_t>n
    return bad != 0


cdef inline void _parent_of(int64_t a, int64_t b, int64_t c, int64_t* p) noexcept nogil:
    """One triangle's part of sample_parents, its corners' sequence places a, b, c: the
    last corner's candidate is the middle one, the middle one's the first, strictly
    earlier (a listed triangle may repeat a corner); conditional moves, as the
    comparisons go either way from triangle to triangle."""
    cdef int64_t lo, mid, hi, t, old
    lo = a if a < b else b
    lo = lo if lo < c else c
    hi = a if a > b else b
    hi = hi if hi > c else c
    mid = a + b + c - lo - hi
    t = mid if mid < hi else -1
    old = p[hi]
    p[hi] = t if t > old else old
    t = lo if lo < mid else -1
    old = p[mid]
    p[mid] = t if t > old else old


cdef void _parents(const int64_t[:, ::1] triangles, const int64_t[::1] pos, int64_t[::1] p) noexcept nogil:
    """sample_parents' pass: pos is each vertex's place in the sequence, p (all -1 on
    entry) gets each place's parent place; the corners already checked."""
    cdef int64_t n = p.shape[0], j, k
    for k in range(triangles.shape[0]):
        _parent_of(pos[triangles[k, 0]], pos[triangles[k, 1]], pos[triangles[k, 2]], &p[0])
    for j in range(n):
        if p[j] < 0:
            p[j] = j - 1


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


cdef void _doubled_areas(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles,
                         int64_t[::1] areas) noexcept nogil:
    """(x1-x0)(y2-y0) - (x2-x0)(y1-y0) of each triangle; its corners already checked."""
    cdef int64_t k, a, b, c, xa, ya
    for k in range(triangles.shape[0]):
        a = triangles[k, 0]; b = triangles[k, 1]; c = triangles[k, 2]
        xa = vertices[a, 0]; ya = vertices[a, 1]
        areas[k] = (vertices[b, 0] - xa) * (vertices[c, 1] - ya) - (vertices[c, 0] - xa) * (vertices[b, 1] - ya)


cdef void _vertex_steps(const int64_t[:, ::1] triangles, const int64_t[::1] areas, int64_t step,
                        double bound, int64_t[::1] fan, int64_t[::1] steps) noexcept nogil:
    """meshcode.vertex_steps without the pinned top row: `step` times the square root
    of the mean fan area over each vertex's own, the factor within 1/bound..bound
    (meshcode.STEP_RANGE), rounded half
    to even and kept within 1..65535; `step` where a vertex has no fan. The arithmetic
    is numpy's (binary64, one rounding each), so encoder and decoder agree exactly.
    Corners already checked; fan is zeroed scratch of n entries."""
    cdef int64_t k, i
    if step > 1:
        for k in range(triangles.shape[0]):
            for i in range(3):
                fan[triangles[k, i]] += areas[k]
    _steps_of_fans(fan, step, bound, triangles.shape[0], steps)


cdef extern from *:
    """
    /* _steps_of_fans' vertices two at a time in SSE2 (every x86-64 has it): the
       division and the square root are correctly rounded in either form, so the same
       doubles; only their throughput doubles (a decode's 7,000 vertices spent
       ~20 us in the scalar pair). The clamps as selects, in the scalar order; the
       rounding is cvtpd2dq's (MXCSR's mode, nearest even, as rint's) after the clamp
       to 1 .. 65535, not before: both bounds are whole, so
       clamp(rint(x)) = rint(clamp(x)). A vertex without a positive fan takes `step`.
       Returns how many vertices it did (the rest are the caller's). */
    #if defined(__SSE2__) && (defined(__x86_64__) || defined(_M_X64))
    #include <emmintrin.h>
    static int64_t atm_steps_of_fans2(const int64_t* fan, int64_t n, int64_t step, double mean,
                                      double least, double bound, int64_t* steps) {
        const __m128d vm = _mm_set1_pd(mean), lo = _mm_set1_pd(least), hi = _mm_set1_pd(bound);
        const __m128d st = _mm_set1_pd((double)step), one = _mm_set1_pd(1.0), top = _mm_set1_pd(65535.0);
        int64_t i;
        for (i = 0; i + 2 <= n; i += 2) {
            int64_t f0 = fan[i], f1 = fan[i + 1];
            __m128d f = _mm_set_pd((double)f1, (double)f0), x, below, above;
            __m128i r;
            x = _mm_sqrt_pd(_mm_div_pd(vm, f));
            below = _mm_cmplt_pd(x, lo);
            above = _mm_cmpgt_pd(x, hi);
            x = _mm_or_pd(_mm_and_pd(above, hi), _mm_andnot_pd(above, x));
            x = _mm_or_pd(_mm_and_pd(below, lo), _mm_andnot_pd(below, x));
            x = _mm_mul_pd(st, x);
            x = _mm_min_pd(_mm_max_pd(x, one), top);
            r = _mm_cvtpd_epi32(x);
            steps[i] = f0 > 0 ? (int64_t)_mm_cvtsi128_si32(r) : step;
            steps[i + 1] = f1 > 0 ? (int64_t)_mm_cvtsi128_si32(_mm_shuffle_epi32(r, 1)) : step;
        }
        return i;
    }
    #else
    static int64_t atm_steps_of_fans2(const int64_t* fan, int64_t n, int64_t step, double mean,
                                      double least, double bound, int64_t* steps) { return 0; }
    #endif
    """
    int64_t atm_steps_of_fans2(const int64_t* fan, int64_t n, int64_t step, double mean, double least,
                               double bound, int64_t* steps) noexcept nogil


cdef void _steps_of_fans(const int64_t[::1] fan, int64_t step, double bound, int64_t m,
                         int64_t[::1] steps) noexcept nogil:
    """_vertex_steps from the vertices' fan areas (sums of their triangles' doubled
    areas; m triangles): two at a time where there is SSE2 (atm_steps_of_fans2), the
    rest here."""
    cdef int64_t n = steps.shape[0], i, total = 0, some = 0
    cdef double mean, factor, s, least = 1.0 / bound  # once: the compiler keeps a division in the loop
    if step > 1 and m:
        for i in range(n):
            if fan[i] > 0:
                total += fan[i]
                some += 1
    if some == 0:
        for i in range(n):
            steps[i] = step
        return
    mean = <double>total / <double>some
    for i in range(atm_steps_of_fans2(&fan[0], n, step, mean, least, bound, &steps[0]) if n else 0, n):
        if fan[i] > 0:
            factor = sqrt(mean / <double>fan[i])
            factor = least if factor < least else (bound if factor > bound else factor)
            s = rint(<double>step * factor)
            s = 1.0 if s < 1.0 else (65535.0 if s > 65535.0 else s)
            steps[i] = <int64_t>s
        else:
            steps[i] = step


def vertex_steps(const int64_t[:, ::1] triangles, const int64_t[::1] areas, int64_t n, int64_t step,
                 double bound):
    """Every vertex's quantisation step before the pinned top row (_vertex_steps); None
    if a corner is out of range or the areas do not match the triangles."""
    cdef int64_t m = triangles.shape[0], k, i
    cdef bint bad = areas.shape[0] != m
    steps = np.empty(n, dtype=np.int64)
    fan = np.zeros(n, dtype=np.int64)
    cdef int64_t[::1] s = steps
    cdef int64_t[::1] f = fan
    with nogil:
        for k in range(m):
            for i in range(3):
                if not 0 <= triangles[k, i] < n:
                    bad = True
        if not bad:
            _vertex_steps(triangles, areas, step, bound, f, s)
    return None if bad else steps


cpdef enum MeshCheck:
    MESH_OK = 0
    MESH_OUTSIDE = 1      # a vertex lies outside the image
    MESH_INDEX = 2        # a triangle refers to a vertex beyond those stored
    MESH_DEGENERATE = 3   # a triangle's doubled area is not positive


cpdef enum Values:
    VALUES_OK = 0
    VALUES_CORNER = 1     # a triangle refers to a vertex beyond those stored
    VALUES_RESIDUAL = 2   # a stored residual exceeds the sample type's range
    VALUES_ORDER = 3      # the sample order is no permutation of the vertices
    VALUES_SAMPLE = 4     # a decoded sample leaves the sample type's range
    VALUES_COUNT = 5      # the samples field does not hold one varint per vertex and channel
    VALUES_LONG = 6       # a sample's varint is longer than the longest allowed


cdef int _vertices_inside(const int64_t[:, ::1] vertices, int64_t w, int64_t h, bint* increasing) noexcept nogil:
    """mesh_checks' vertex pass: MESH_OUTSIDE at the first vertex outside w x h, and
    whether the keys y * w + x increase up to there."""
    cdef int64_t j, key, last = -1
    increasing[0] = True
    for j in range(vertices.shape[0]):
        if not (0 <= vertices[j, 0] < w and 0 <= vertices[j, 1] < h):
            return MESH_OUTSIDE
        key = vertices[j, 1] * w + vertices[j, 0]
        if key <= last:
            increasing[0] = False
        last = key
    return MESH_OK


cdef int _varint_count(const uint8_t[::1] data, int64_t count, int64_t longest) noexcept nogil:
    """unvarints' refusals of `data` without decoding it: VALUES_COUNT unless it holds
    exactly `count` numbers (checked first, as unvarints does), VALUES_LONG if a number
    has more than `longest` bytes (a run of `longest` continuation bytes)."""
    cdef bint long_ = False
    if _varint_scan(&data[0] if data.shape[0] else NULL, data.shape[0], longest, &long_) != count:
        return VALUES_COUNT
    return VALUES_LONG if long_ else VALUES_OK


cdef int _triangle_pass(const int64_t* V, int64_t n, const int64_t* T, int64_t m, const int64_t* pos,
                        int64_t* ar, int64_t* fan, int64_t* p, int* checks, int64_t* total,
                        int64_t* crossed) noexcept nogil:
    """band_values' one pass over the triangles: their corners checked (VALUES_CORNER
    at the first beyond the n vertices), doubled areas (ar, unless NULL), the vertices' fan areas
    (fan, zeroed), the samples' parents (_parent_of: p, all -1, from pos) and
    mesh_checks' sums (checks: MESH_DEGENERATE at a triangle of area <= 0; total
    area; rows crossed plus the count). _doubled_areas, _vertex_steps' sums and
    _parents would each read the corners again; a function of its own, so that the
    compiler keeps its pointers and sums in registers."""
    cdef int64_t k, a, b, c, xa, ya, xb, yb, xc, yc, area, lo, hi, area_sum = 0, rows = 0
    cdef bint flat = False
    for k in range(m):
        a = T[3 * k]; b = T[3 * k + 1]; c = T[3 * k + 2]
        if <uint64_t>a >= <uint64_t>n or <uint64_t>b >= <uint64_t>n or <uint64_t>c >= <uint64_t>n:
            return VALUES_CORNER
        xa = V[2 * a]; ya = V[2 * a + 1]
        xb = V[2 * b]; yb = V[2 * b + 1]
        xc = V[2 * c]; yc = V[2 * c + 1]
        area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
        if ar != NULL:
            ar[k] = area
        fan[a] += area
        fan[b] += area
        fan[c] += area
        _parent_of(pos[a], pos[b], pos[c], p)
        flat |= area <= 0
        area_sum += area
        lo = ya if ya < yb else yb
        lo = lo if lo < yc else yc
        hi = ya if ya > yb else yb
        hi = hi if hi > yc else yc
        rows += hi - lo + 1
    if flat and checks[0] == MESH_OK:
        checks[0] = MESH_DEGENERATE
    total[0] = area_sum
    crossed[0] = rows
    return VALUES_OK


def band_values(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles,
                const uint8_t[::1] samples, int64_t channels, const int64_t[::1] seq_order, int64_t step,
                double bound, bint top_pinned, int64_t top, int64_t longest, int64_t width, int64_t rows,
                bint want_areas=True):
    """(status, values, areas, checks): a band's samples from its samples field (ATM.md
    §4.2.4), in one call: the field's n * channels LEB128 varints (refused as
    coding.unvarints refuses them, none longer than `longest` <= 9 bytes; nothing is
    allocated for them before their count is known to match), each zigzag residual in
    sequence order checked against 2 * top, unzigzagged, times its vertex's step
    (vertex_steps, the rows at y = 0 step 1 when top_pinned), added to its parent's
    sample (sample_parents) and checked within 0..top. values: n (one channel) or n x
    channels samples in vertex order, uint8 for top < 2**8, uint16 for top < 2**16,
    else int64; areas the triangles' doubled areas; checks what mesh_checks(vertices,
    triangles, areas, width, rows) returns, from the same pass over the triangles (so
    that mesh.validate need not read them again). Every index is checked before it is
    used; values, areas and checks are None on an error. want_areas=False: areas is None
    (a decoder's mesh.validate takes the checks, not the areas; an M-long array fewer to
    fault in). The varints are read into the array that then holds the samples, and the
    fan areas become the steps in place (each sample's parent comes before it in the
    sequence, so the running sums read only finished entries): two n-long arrays fewer."""
    cdef int64_t n = vertices.shape[0], m = triangles.shape[0], j, k, i, ch, q
    cdef int64_t total = 0, crossed = 0
    cdef bint residual_bad = False, order_bad = False
    cdef uint64_t u
    cdef int64_t r
    cdef bint increasing = True
    cdef int checks = MESH_OK
    if seq_order.shape[0] != n or channels < 1 or longest > 9 or n * channels < 0:
        raise ValueError("band_values: one place per vertex, at least one channel, at most 9 bytes a varint")
    cdef int status
    with nogil:  # a scan of the whole field: work, so without the GIL
        status = _varint_count(samples, n * channels, longest)
    if status != VALUES_OK:
        return status, None, None, None
    areas = np.empty(m, dtype=np.int64) if want_areas else None
    scratch = np.empty(n, dtype=np.int64)
    parent_arr = np.empty(n, dtype=np.int64)
    seq_arr = np.empty((n, channels), dtype=np.int64)
    fan_arr = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] pos = scratch, p = parent_arr, fan = fan_arr
    cdef int64_t[::1] steps = fan_arr  # the fan areas, then (in place) the steps
    cdef int64_t[:, ::1] seq = seq_arr
    cdef int64_t[::1] ar
    cdef int64_t* ar_ptr = NULL
    if want_areas and m:
        ar = areas
        ar_ptr = &ar[0]
    # the zigzag residuals first, then (in place) the samples
    cdef int64_t* zigzags = &seq[0, 0] if n * channels else NULL
    with nogil:
        for j in range(n):
            pos[j] = -1
            fan[j] = 0
            p[j] = -1
        # the varints (their count and lengths known good)
        if n * channels:
            _leb128_into(&samples[0], samples.shape[0], zigzags)
        for j in range(n * channels):
            # zigzag(r) <= 2 top iff |r| <= top (unsigned: a 9-byte varint may wrap)
            residual_bad |= <uint64_t>zigzags[j] > <uint64_t>(2 * top)
        for j in range(n):
            k = seq_order[j]
            if <uint64_t>k >= <uint64_t>n or pos[k] >= 0:
                order_bad = True
                break
            pos[k] = j
        if residual_bad or order_bad:
            # refused in this order: a corner beyond the vertices, a residual, the order
            status = (VALUES_CORNER if m and _corners_beyond(&triangles[0, 0], 3 * m, n)
                      else VALUES_RESIDUAL if residual_bad else VALUES_ORDER)
        else:
            checks = _vertices_inside(vertices, width, rows, &increasing)  # mesh_checks' vertex pass
            # one pass over the triangles (_triangle_pass)
            if m:
                status = _triangle_pass(&vertices[0, 0], n, &triangles[0, 0], m, &pos[0], ar_ptr, &fan[0], &p[0],
                                        &checks, &total, &crossed)
        if status == VALUES_OK:
            _steps_of_fans(fan, step, bound, m, steps)
            if top_pinned:
                for i in range(n):
                    if vertices[i, 1] == 0:
                        steps[i] = 1
            for j in range(n):
                q = p[j] if p[j] >= 0 else j - 1  # no earlier neighbour: the sample before
                for ch in range(channels):
                    u = <uint64_t>zigzags[j * channels + ch]
                    r = <int64_t>(u >> 1) ^ -<int64_t>(u & 1)
                    r *= steps[seq_order[j]]
                    if q >= 0:
                        r += seq[q, ch]
                    if r < 0 or r > top:
                        status = VALUES_SAMPLE
                    seq[j, ch] = r
                if status != VALUES_OK:
                    break
    if status != VALUES_OK:
        return status, None, None, None
    values = _in_vertex_order(seq_arr, seq_order, top)
    if channels == 1:
        values = values.reshape(n)
    if checks != MESH_OK:
        return status, values, areas, (checks, increasing, 0, 0)
    return status, values, areas, (checks, increasing, total, crossed)


ctypedef fused _sample_t:
    uint8_t
    uint16_t
    int64_t


cdef void _scatter(const int64_t[:, ::1] seq, const int64_t[::1] seq_order, _sample_t[:, ::1] out) noexcept nogil:
    """out[seq_order[j]] = seq[j], each sample already within out's type."""
    cdef int64_t j, ch, k
    for j in range(seq.shape[0]):
        k = seq_order[j]
        for ch in range(seq.shape[1]):
            out[k, ch] = <_sample_t>seq[j, ch]


cdef object _in_vertex_order(const int64_t[:, ::1] seq, const int64_t[::1] seq_order, int64_t top):
    """The samples of seq (in sequence order, each within 0..top) in vertex order, in
    the narrowest of uint8, uint16 and int64 that holds top."""
    out = np.empty((seq.shape[0], seq.shape[1]),
                   dtype=np.uint8 if top < 1 << 8 else np.uint16 if top < 1 << 16 else np.int64)
    cdef uint8_t[:, ::1] o8
    cdef uint16_t[:, ::1] o16
    cdef int64_t[:, ::1] o64
    if top < 1 << 8:
        o8 = out
        with nogil:
            _scatter(seq, seq_order, o8)
    elif top < 1 << 16:
        o16 = out
        with nogil:
            _scatter(seq, seq_order, o16)
    else:
        o64 = out
        with nogil:
            _scatter(seq, seq_order, o64)
    return out


cdef inline int64_t _hilbert_key(int64_t x, int64_t y, const int64_t* digit, const int64_t* nxt, int g,
                                 int64_t groups, int64_t start) noexcept nogil:
    """hilbert_keys of one point (the tables' sizes checked by the caller)."""
    cdef int64_t k = (groups - 1) * g, i, d = 0, state = start
    cdef int64_t mask = (1 << g) - 1, size = 4 << (2 * g)
    while k >= 0:
        i = ((((x >> k) & mask) << g) | ((y >> k) & mask) | state) & (size - 1)
        d = (d << (2 * g)) | digit[i]
        state = nxt[i]
        k -= g
    return d


def hilbert_keys(const int64_t[::1] x, const int64_t[::1] y, const int64_t[::1] digit,
                 const int64_t[::1] nxt, int g, int64_t groups, int64_t start):
    """coding.hilbert_keys' state machine, a point at a time: for each group of g
    levels from the top, look up (state, g bits of x, g bits of y) in the group tables
    (digit, nxt: 4 << 2g entries; nxt holds the next state shifted by 2g). Every lookup
    is masked into the tables, whatever x and y hold."""
    cdef int64_t n = x.shape[0], j
    cdef int64_t size = 4 << (2 * g)
    if y.shape[0] != n or digit.shape[0] != size or nxt.shape[0] != size or not 0 <= start < size:
        raise ValueError("hilbert_keys: x and y of one length, tables of 4 << 2g entries")
    out = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] o = out
    with nogil:
        for j in range(n):
            o[j] = _hilbert_key(x[j], y[j], &digit[0], &nxt[0], g, groups, start)
    return out


def curve_order(const int64_t[:, ::1] vertices, const int64_t[::1] places, const int64_t[::1] digit,
                const int64_t[::1] nxt, int g, int64_t groups, int64_t start, int64_t span):
    """The vertices at `places` (each checked to be a vertex) ordered along the
    Hilbert curve: hilbert_keys of their (x, y), sorted by argsort_keys' radix passes
    (keys below `span`), in one call (the sample order of a band whose free vertices
    are stored in raster order, ATM.md §4.2.4). None if a place is no vertex or a key
    not below span; equal keys keep their order."""
    cdef int64_t n = places.shape[0], j, nv = vertices.shape[0]
    cdef int64_t size = 4 << (2 * g)
    cdef bint bad = False
    if digit.shape[0] != size or nxt.shape[0] != size or not 0 <= start < size:
        raise ValueError("curve_order: tables of 4 << 2g entries")
    keys = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] k = keys
    with nogil:
        for j in range(n):
            if <uint64_t>places[j] >= <uint64_t>nv:
                bad = True
                break
            k[j] = _hilbert_key(vertices[places[j], 0], vertices[places[j], 1], &digit[0], &nxt[0], g, groups,
                                start)
    if bad:
        return None
    along = argsort_keys(keys, span)
    if along is None:
        return None
    out = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] o = out, a = along
    with nogil:
        for j in range(n):
            o[j] = places[a[j]]
    return out


cdef extern from "stdlib.h" nogil:
    void qsort(void *base, size_t nmemb, size_t size, int (*compar)(const void *, const void *) noexcept nogil)


cdef int _row_order(const void *p, const void *q) noexcept nogil:
    cdef const int64_t *a = <const int64_t *>p
    cdef const int64_t *b = <const int64_t *>q
    cdef int i
    for i in range(3):
        if a[i] != b[i]:
            return -1 if a[i] < b[i] else 1
    return 0


def canonical_triangles(const int64_t[:, ::1] triangles):
    """coding.canonical_triangles in one pass: each row rotated (orientation kept) to
    its lexicographically smallest rotation, then the rows sorted lexicographically
    (a counting sort on the first corner when the corners are indices of a mesh,
    qsort otherwise)."""
    cdef int64_t m = triangles.shape[0], k, a, b, c, r, lo = 0, hi = 0
    if triangles.shape[1] != 3:
        raise ValueError("canonical_triangles: an M x 3 array")
    out = np.empty((m, 3), dtype=np.int64)
    cdef int64_t[:, ::1] o = out
    with nogil:
        for k in range(m):
            # the smallest of the three rotations (the one from the smallest index,
            # for the distinct corners of a real triangle)
            o[k, 0] = triangles[k, 0]; o[k, 1] = triangles[k, 1]; o[k, 2] = triangles[k, 2]
            for r in range(2):
                a = triangles[k, (r + 1) % 3]; b = triangles[k, (r + 2) % 3]; c = triangles[k, r]
                if a < o[k, 0] or (a == o[k, 0] and (b < o[k, 1] or (b == o[k, 1] and c < o[k, 2]))):
                    o[k, 0] = a; o[k, 1] = b; o[k, 2] = c
        for k in range(m):
            lo = o[k, 0] if k == 0 or o[k, 0] < lo else lo
            hi = o[k, 0] if k == 0 or o[k, 0] > hi else hi
    if m > 1 and lo >= 0 and hi < 16 * m + 1024:
        # a counting sort on the first corner, then an insertion sort of each fan (a
        # vertex starts a few triangles), as _renumber does: linear, where a
        # comparison sort of the rows is not
        counted = np.empty((m, 3), dtype=np.int64)
        starts = np.zeros(hi + 2, dtype=np.int64)
        nexts = np.empty(hi + 2, dtype=np.int64)
        _sort_into(o, counted, starts, nexts)
        return counted
    if m > 1:
        with nogil:
            qsort(&o[0, 0], <size_t>m, 3 * sizeof(int64_t), _row_order)
    return out


cdef void _sort_into(const int64_t[:, ::1] rows, int64_t[:, ::1] out, int64_t[::1] start,
                     int64_t[::1] nxt) noexcept:
    with nogil:
        _count_sort_rows(rows, out, start, nxt)


cdef void _count_sort_rows(const int64_t[:, ::1] rows, int64_t[:, ::1] out, int64_t[::1] start,
                           int64_t[::1] nxt) noexcept nogil:
    """The rows (first entries in 0..len(start) - 2) sorted lexicographically into
    `out`: counted into place by the first entry, then each run of one first entry
    (a vertex's fan, short in a mesh) sorted by insertion, or by qsort when long.
    start: zeroed scratch; nxt: scratch of the same length."""
    cdef int64_t m = rows.shape[0], k, j, i, a, b, c, v
    for k in range(m):
        start[rows[k, 0] + 1] += 1
    for v in range(1, start.shape[0]):
        start[v] += start[v - 1]
    for v in range(start.shape[0]):
        nxt[v] = start[v]
    for k in range(m):
        j = nxt[rows[k, 0]]
        nxt[rows[k, 0]] += 1
        out[j, 0] = rows[k, 0]; out[j, 1] = rows[k, 1]; out[j, 2] = rows[k, 2]
    for v in range(start.shape[0] - 1):
        if start[v + 1] - start[v] > 32:
            qsort(&out[start[v], 0], <size_t>(start[v + 1] - start[v]), 3 * sizeof(int64_t), _row_order)
            continue
        for i in range(start[v] + 1, start[v + 1]):
            a = out[i, 0]; b = out[i, 1]; c = out[i, 2]
            j = i
            while j > start[v] and (out[j - 1, 1] > b or (out[j - 1, 1] == b and out[j - 1, 2] > c)):
                out[j, 0] = out[j - 1, 0]; out[j, 1] = out[j - 1, 1]; out[j, 2] = out[j - 1, 2]
                j -= 1
            out[j, 0] = a; out[j, 1] = b; out[j, 2] = c


cdef bint _position_keys(const int64_t* high, int64_t n, const uint8_t* packed, int bits, int64_t span,
                         int64_t* o) noexcept nogil:
    """position_keys' pass into o (n); False if a gap or a key reaches span."""
    cdef int64_t j, gap, key = -1, low, at
    cdef int b
    for j in range(n):
        if high[j] < 0 or high[j] >= span:
            return False
        low = 0
        at = j * bits
        for b in range(bits):
            low = (low << 1) | ((packed[(at + b) >> 3] >> (7 - ((at + b) & 7))) & 1)
        gap = (high[j] << bits) | low
        if gap >= span:
            return False
        key += gap + 1
        if key >= span:
            return False
        o[j] = key
    return True


def position_keys(const int64_t[::1] high, const uint8_t[::1] packed, int bits, int64_t span):
    """(ok, keys): the keys of the free vertices from their stored gaps (ATM.md
    §4.2.2): gap j is high[j] shifted left by `bits` plus the j-th `bits`-bit field of
    `packed` (big-endian bit order), each key the previous plus the gap plus one, from
    -1. ok is False (keys None) if a gap or a key reaches `span`, checked before the
    sum can overflow. packed must hold len(high) * bits bits (the caller checks)."""
    cdef int64_t n = high.shape[0]
    cdef bint ok = True
    if bits < 0 or bits > 32 or packed.shape[0] * 8 < n * bits or span < 0:
        raise ValueError("position_keys: 0..32 low bits, all of them in `packed`")
    out = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] o = out
    if n:
        with nogil:
            ok = _position_keys(&high[0], n, &packed[0] if packed.shape[0] else NULL, bits, span, &o[0])
    return (True, out) if ok else (False, None)


cdef inline void _hilbert_point(int64_t d, const int64_t* xy, const int64_t* back, int g, int64_t groups,
                                int64_t start, int64_t* px, int64_t* py) noexcept nogil:
    """hilbert_points of one key (the tables' sizes checked by the caller)."""
    cdef int64_t k = (groups - 1) * 2 * g, i, x = 0, y = 0, state = start
    cdef int64_t mask = (1 << (2 * g)) - 1, low = (1 << g) - 1, size = 4 << (2 * g)
    while k >= 0:
        i = (((d >> k) & mask) | state) & (size - 1)
        x = (x << g) | (xy[i] >> g)
        y = (y << g) | (xy[i] & low)
        state = back[i]
        k -= 2 * g
    px[0] = x
    py[0] = y


def hilbert_points(const int64_t[::1] d, const int64_t[::1] xy, const int64_t[::1] back,
                   int g, int64_t groups, int64_t start):
    """coding.hilbert_points' state machine, a key at a time: (x, y) of each key from
    the inverse group tables (xy, back: 4 << 2g entries; back holds the next state
    shifted by 2g). Every lookup is masked into the tables."""
    cdef int64_t n = d.shape[0], j
    cdef int64_t size = 4 << (2 * g)
    if xy.shape[0] != size or back.shape[0] != size or not 0 <= start < size:
        raise ValueError("hilbert_points: tables of 4 << 2g entries")
    xs = np.empty(n, dtype=np.int64)
    ys = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] ox = xs, oy = ys
    with nogil:
        for j in range(n):
            _hilbert_point(d[j], &xy[0], &back[0], g, groups, start, &ox[j], &oy[j])
    return xs, ys


def mesh_checks(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, areas, int64_t w, int64_t h):
    """mesh.validate's per-element checks in one pass: (status, keys increasing, total
    doubled area, rows crossed by all triangles plus their count). Vertices are
    checked first, then corners, then areas (given, or computed here once the corners
    are known good); the totals are 0 unless status is MESH_OK."""
    cdef int64_t n = vertices.shape[0], m = triangles.shape[0], j, k, i, total = 0, rows = 0
    cdef int64_t lo, hi, y
    cdef bint increasing = True, given = areas is not None
    cdef int status = MESH_OK
    cdef int64_t[::1] ar
    if not given:
        own = np.empty(m, dtype=np.int64)
        ar = own
    else:
        ar = areas
        if ar.shape[0] != m:
            raise ValueError("mesh_checks: one area per triangle")
    with nogil:
        status = _vertices_inside(vertices, w, h, &increasing)
        if status == MESH_OK and m and _corners_beyond(&triangles[0, 0], 3 * m, n):
            status = MESH_INDEX
        if status == MESH_OK and not given:
            _doubled_areas(vertices, triangles, ar)
        if status == MESH_OK:
            for k in range(m):
                if ar[k] <= 0:
                    status = MESH_DEGENERATE
                    break
                total += ar[k]
                lo = hi = vertices[triangles[k, 0], 1]
                for i in range(1, 3):
                    y = vertices[triangles[k, i], 1]
                    lo = y if y < lo else lo
                    hi = y if y > hi else hi
                rows += hi - lo + 1
    if status != MESH_OK:
        return status, increasing, 0, 0
    return status, increasing, total, rows


cpdef enum Chains:
    CHAINS_OK = 0
    CHAINS_LENGTHS = 1    # the lengths do not add up to the points, or one is below 2
    CHAINS_START = 2      # a polyline starts outside the band
    CHAINS_EMPTY = 3      # a step is (0, 0)
    CHAINS_LONG = 4       # a step is as long as the band or longer
    CHAINS_LEAVES = 5     # a polyline point lies outside the band


cdef inline int _quadrant(int64_t dx, int64_t dy) noexcept nogil:
    """meshcode.quadrants of one non-zero step."""
    if dx > 0:
        return 0 if dy >= 0 else 3
    if dy > 0:
        return 1
    return 2 if dx < 0 else 3


cdef int _chains(const int64_t* lengths, int64_t count, const int64_t* starts, bint started,
                 const int64_t* steps, bint given, int64_t total, int64_t width, int64_t rows,
                 int64_t* st, int64_t* o) noexcept nogil:
    """chains' passes (given: the steps' varints were good, and the starts'): the
    status, the keys in o (total) when CHAINS_OK and given; st: scratch of two per step."""
    cdef int64_t i, j, k, s = 0, key = 0, first, x, y, dx, dy, t
    cdef int64_t pixels = width * rows, nsteps = total - count
    cdef uint64_t u
    cdef int turn, q
    cdef int status = CHAINS_OK
    for i in range(count):
        if lengths[i] < 2:
            status = CHAINS_LENGTHS
        s += lengths[i]  # each below 2**35: no overflow
    if status == CHAINS_OK and s != total:
        status = CHAINS_LENGTHS
    if status == CHAINS_OK and started:
        for i in range(count):
            u = <uint64_t>starts[i]
            key += <int64_t>(u >> 1) ^ -<int64_t>(u & 1)
            if key < 0 or key >= pixels:
                status = CHAINS_START
                break
    if status == CHAINS_OK and given:
        for j in range(2 * nsteps):
            u = <uint64_t>steps[j]
            st[j] = <int64_t>(u >> 1) ^ -<int64_t>(u & 1)
        for j in range(nsteps):
            if st[2 * j] == 0 and st[2 * j + 1] == 0:
                status = CHAINS_EMPTY
                break
    if status == CHAINS_OK and given:
        # a step's turn is the sum of the stored quadrants before it on its polyline
        j = 0
        for i in range(count):
            turn = 0
            for k in range(lengths[i] - 1):
                dx = st[2 * j]; dy = st[2 * j + 1]
                q = _quadrant(dx, dy)
                if turn == 1:
                    t = dx; dx = -dy; dy = t
                elif turn == 2:
                    dx = -dx; dy = -dy
                elif turn == 3:
                    t = dx; dx = dy; dy = -t
                if dx >= width or -dx >= width or dy >= rows or -dy >= rows:
                    status = CHAINS_LONG
                st[2 * j] = dx; st[2 * j + 1] = dy
                turn = (turn + q) & 3
                j += 1
    if status == CHAINS_OK and given:
        key = 0
        j = 0
        first = 0
        for i in range(count):
            u = <uint64_t>starts[i]
            key += <int64_t>(u >> 1) ^ -<int64_t>(u & 1)
            x = key % width
            y = key // width
            o[first] = key
            for k in range(1, lengths[i]):
                x += st[2 * j]; y += st[2 * j + 1]
                j += 1
                if x < 0 or x >= width or y < 0 or y >= rows:
                    status = CHAINS_LEAVES
                    break
                o[first + k] = y * width + x
            if status != CHAINS_OK:
                break
            first += lengths[i]
    return status


def chains(const int64_t[::1] lengths, const int64_t[::1] starts, const int64_t[::1] steps,
           int64_t total, int64_t width, int64_t rows):
    """(status, chain keys): meshcode._polylines' passes over a band's polylines
    (ATM.md §4.2.2) in one call: the lengths checked against `total` points, the
    zigzag start gaps summed into pixel keys inside the band, the zigzag steps
    decoded, each turned back by the quadrants of the steps before it on its polyline
    and walked from the start; the key y * width + x of every polyline point. The
    checks come in meshcode's order, each over all of its field first, so a file
    wrong in two ways gets the same message; keys is None on an error. Every sum is
    checked before it can overflow: the varints are below 2**35. starts or steps
    None (their varints were bad): the checks stop before that field, keys None."""
    cdef int64_t count = lengths.shape[0], nsteps = total - count
    cdef bint given = steps is not None, started = starts is not None
    given = given and started
    if width < 1 or rows < 1 or (started and starts.shape[0] != count) or (given and steps.shape[0] != 2 * nsteps):
        raise ValueError("chains: a start per polyline and two numbers per step")
    keys = np.empty(total, dtype=np.int64)
    turned = np.empty(2 * nsteps if nsteps > 0 else 0, dtype=np.int64)
    cdef int64_t[::1] o = keys, st = turned
    cdef int status
    with nogil:
        status = _chains(&lengths[0] if count else NULL, count, &starts[0] if started and count else NULL, started,
                         &steps[0] if given and nsteps > 0 else NULL, given, total, width, rows,
                         &st[0] if nsteps > 0 else NULL, &o[0] if total else NULL)
    return status, (keys if status == CHAINS_OK and given else None)


cdef int64_t _line_ranks(const int64_t* keys, const int64_t* perm, int64_t total, int64_t* rank,
                         int64_t* first) noexcept nogil:
    """line_ranks' first pass: each point's rank among the distinct keys (rank), the
    first point of each (first); the number of distinct keys, -1 if perm is no
    argsort of keys."""
    cdef int64_t i, k, groups = 0
    for i in range(total):
        if <uint64_t>perm[i] >= <uint64_t>total:
            return -1
        rank[i] = -1
    for i in range(total):
        k = perm[i]
        if rank[k] >= 0 or (i and keys[k] < keys[perm[i - 1]]):
            return -1  # a place twice, or out of order: no argsort
        if i == 0 or keys[k] != keys[perm[i - 1]]:
            first[groups] = k
            groups += 1
        elif k < first[groups - 1]:
            first[groups - 1] = k
        rank[k] = groups - 1
    return groups


cdef void _distinct(const int64_t* keys, const int64_t* rank, const int64_t* first, int64_t total,
                    int64_t groups, int64_t* distinct, int64_t* appear) noexcept nogil:
    """line_ranks' second pass: the distinct keys in increasing order, and their ranks
    in the order the chains first reach them."""
    cdef int64_t r, j = 0, k
    for r in range(groups):
        distinct[r] = keys[first[r]]
    for k in range(total):
        r = rank[k]
        if first[r] == k:
            appear[j] = r
            j += 1


def line_ranks(const int64_t[::1] keys, const int64_t[::1] perm):
    """(distinct keys, rank, appearance): the distinct polyline point keys in
    increasing order, each point's rank among them, and the ranks in the order the
    chains first reach them (the sample order's polyline part, ATM.md §4.2.4), from
    `perm`, an argsort of `keys` (any: a key's first point is the least place in its
    group). None if perm is no permutation."""
    cdef int64_t total = keys.shape[0], groups = -1
    rank_arr = np.empty(total, dtype=np.int64)
    first_arr = np.empty(total, dtype=np.int64)
    cdef int64_t[::1] rank = rank_arr, first = first_arr
    if perm.shape[0] != total:
        return None
    if total:
        with nogil:
            groups = _line_ranks(&keys[0], &perm[0], total, &rank[0], &first[0])
        if groups < 0:
            return None
    else:
        groups = 0
    distinct = np.empty(groups, dtype=np.int64)
    appear_arr = np.empty(groups, dtype=np.int64)
    cdef int64_t[::1] d = distinct, appear = appear_arr
    if groups:
        with nogil:
            _distinct(&keys[0], &rank[0], &first[0], total, groups, &d[0], &appear[0])
    return distinct, rank_arr, appear_arr


cdef bint _band_vertices(const int64_t* line_keys, int64_t nl, const int64_t* free_keys, int64_t nf,
                         const int64_t* ranks, int64_t total, const int64_t* appear, int64_t na,
                         const int64_t* lengths, int64_t count, int64_t width, int64_t* v, int64_t* fp,
                         int64_t* lp, int64_t* flat, int64_t* walls, int64_t nwalls, int64_t* on_line) noexcept nogil:
    """band_vertices' passes into the caller's buffers (v: 2 (nl + nf), fp: nf, lp: nl
    scratch, flat: total, walls: 2 nwalls, on_line: na); False if a pixel is in both
    lists or an index is out of range."""
    cdef int64_t n = nl + nf, i = 0, j = 0, k, key, w = 0, at = 0, y = 0, row = 0
    for k in range(n):
        if j >= nf or (i < nl and line_keys[i] < free_keys[j]):
            key = line_keys[i]
            lp[i] = k
            i += 1
        else:
            key = free_keys[j]
            if i < nl and line_keys[i] == key:
                return False
            fp[j] = k
            j += 1
        # the keys increase: the row advances instead of a 64-bit division each
        while key - row >= width:
            row += width
            y += 1
        v[2 * k] = key - row
        v[2 * k + 1] = y
    if (total and _corners_beyond(ranks, total, nl)) or (na and _corners_beyond(appear, na, nl)):
        return False
    for k in range(total):
        flat[k] = lp[ranks[k]]
    for k in range(na):
        on_line[k] = lp[appear[k]]
    for i in range(count):
        for k in range(at, at + lengths[i] - 1):
            if k + 1 >= total or w >= nwalls:
                return False
            walls[2 * w] = flat[k]
            walls[2 * w + 1] = flat[k + 1]
            w += 1
        at += lengths[i]
    return True


def band_vertices(const int64_t[::1] line_keys, const int64_t[::1] free_keys,
                  const int64_t[::1] ranks, const int64_t[::1] appear, const int64_t[::1] lengths,
                  int64_t width):
    """(ok, vertices, free places, flat, walls, on_line): a band's vertices in raster
    order from its polyline pixels (line_keys, increasing and distinct) and the
    others (free_keys, increasing), merged; each free vertex's place; each polyline
    point's vertex (flat, chain after chain; ranks among line_keys from line_ranks);
    the polylines' steps as vertex pairs (walls); and the polyline vertices in the
    order line_ranks' `appear` gives. ok is False if a pixel is in both lists."""
    cdef int64_t nl = line_keys.shape[0], nf = free_keys.shape[0], n = nl + nf
    cdef int64_t total = ranks.shape[0], count = lengths.shape[0], na = appear.shape[0], nw = max(total - count, 0)
    cdef bint ok
    if width < 1:
        raise ValueError("band_vertices: a width of at least one pixel")
    vertices = np.empty((n, 2), dtype=np.int64)
    places = np.empty(nf + 1, dtype=np.int64)
    line_places = np.empty(nl + 1, dtype=np.int64)
    flat_arr = np.empty(total + 1, dtype=np.int64)
    walls_arr = np.empty((nw + 1, 2), dtype=np.int64)
    on_line_arr = np.empty(na + 1, dtype=np.int64)
    cdef int64_t[:, ::1] v = vertices, walls = walls_arr
    cdef int64_t[::1] fp = places, lp = line_places, flat = flat_arr, on_line = on_line_arr
    # (each buffer one longer than needed, so that &x[0] exists when it is empty)
    with nogil:
        ok = _band_vertices(&line_keys[0] if nl else NULL, nl, &free_keys[0] if nf else NULL, nf,
                            &ranks[0] if total else NULL, total, &appear[0] if na else NULL, na,
                            &lengths[0] if count else NULL, count, width, &v[0, 0] if n else NULL, &fp[0], &lp[0],
                            &flat[0], &walls[0, 0], nw, &on_line[0])
    if not ok:
        return False, None, None, None, None, None
    return True, vertices, places[:nf], flat_arr[:total], walls_arr[:nw], on_line_arr[:na]


cdef enum:
    ARGSORT_BUCKETS = 2048  # buckets _argsort's digits need at most (11-bit digits)


cdef inline void _digit_places(const uint64_t* words, int64_t n, int64_t shift, int64_t mask,
                               int64_t* count) noexcept nogil:
    """count[d]: the place the first of the n words whose digit (word >> shift) & mask is
    d goes in a radix pass (the digits counted, then an exclusive running sum)."""
    cdef int64_t j, b, c, total = 0
    memset(count, 0, (mask + 1) * sizeof(int64_t))
    for j in range(n):
        count[(words[j] >> shift) & mask] += 1
    for b in range(mask + 1):
        c = count[b]
        count[b] = total
        total += c


cdef inline bint _packed(int64_t n, int64_t span) noexcept nogil:
    """Whether _argsort moves each key and its place as one word (both below 2**32)."""
    return span <= (<int64_t>1 << 32) and n <= (<int64_t>1 << 32)


cdef inline int64_t _argsort_words(int64_t n, int64_t span) noexcept nogil:
    """The int64 words of buffer _argsort needs."""
    return (2 if _packed(n, span) else 4) * n + ARGSORT_BUCKETS


cdef int64_t* _argsort(const int64_t* keys, int64_t n, int64_t span, int64_t* buf) noexcept nogil:
    """argsort_keys' radix passes into buf (_argsort_words(n, span) entries); the
    sorted places (a pointer into buf), NULL if a key lies outside 0..span-1. Keys and
    places that fit 32 bits each (every band's) move as one word, key above place:
    half the stores and half the buffer of moving them apart."""
    cdef int64_t j, b, bits = 0, passes, digit, shift = 0, mask
    cdef bint bad = False
    cdef uint64_t* w_src
    cdef uint64_t* w_dst
    cdef uint64_t* w_tmp
    cdef uint64_t word, low32 = (<uint64_t>1 << 32) - 1  # (a key below 2**32 has at most 32 bits)
    while bits < 63 and (<int64_t>1 << bits) < span:
        bits += 1
    passes = (bits + 10) // 11
    digit = (bits + passes - 1) // passes if passes else 1
    mask = (<int64_t>1 << digit) - 1  # at most ARGSORT_BUCKETS - 1
    # raw pointers (memoryview indexing reloads its base at each of the scatter's stores)
    cdef int64_t* k_src = buf
    cdef int64_t* k_dst = buf + n
    cdef int64_t* i_src = buf + 2 * n
    cdef int64_t* i_dst = buf + 3 * n
    cdef int64_t* count = buf + 4 * n
    cdef int64_t* tmp
    for j in range(n):
        bad |= <uint64_t>keys[j] >= <uint64_t>span
    if bad:
        return NULL
    if _packed(n, span):
        w_src = <uint64_t*>buf
        w_dst = <uint64_t*>(buf + n)
        count = buf + 2 * n
        for j in range(n):
            w_src[j] = (<uint64_t>keys[j] << 32) | <uint64_t>j
        shift = 32
        while passes > 0:
            _digit_places(w_src, n, shift, mask, count)
            for j in range(n):
                word = w_src[j]
                b = (word >> shift) & mask
                w_dst[count[b]] = word
                count[b] += 1
            w_tmp = w_src
            w_src = w_dst
            w_dst = w_tmp
            shift += digit
            passes -= 1
        # the places, unpacked where their words were
        for j in range(n):
            (<int64_t*>w_src)[j] = <int64_t>(w_src[j] & low32)
        return <int64_t*>w_src
    for j in range(n):
        k_src[j] = keys[j]
        i_src[j] = j
    while passes > 0:
        _digit_places(<const uint64_t*>k_src, n, shift, mask, count)  # (keys checked >= 0)
        for j in range(n):
            b = (k_src[j] >> shift) & mask
            k_dst[count[b]] = k_src[j]
            i_dst[count[b]] = i_src[j]
            count[b] += 1
        tmp = k_src
        k_src = k_dst
        k_dst = tmp
        tmp = i_src
        i_src = i_dst
        i_dst = tmp
        shift += digit
        passes -= 1
    return i_src


def argsort_keys(const int64_t[::1] keys, int64_t span):
    """The permutation that sorts keys in 0..span-1, equal keys in their own order
    (numpy's stable argsort; any argsort of distinct keys): a least-significant-digit
    radix sort in as few
    passes of at most 11-bit digits as span needs, the keys moved with their indices,
    linear in the keys (the Hilbert order of a band's free vertices, where a comparison
    sort cost more than the rest of the field decoding). None if a key lies outside
    0..span-1."""
    cdef int64_t n = keys.shape[0]
    buf = np.empty(_argsort_words(n, span), dtype=np.int64)
    cdef int64_t[::1] whole = buf
    cdef int64_t* out
    with nogil:
        out = _argsort(&keys[0] if n else NULL, n, span, &whole[0])
    if out == NULL:
        return None
    # a view of the buffer (its indices' half)
    return buf[out - &whole[0] : out - &whole[0] + n]


ctypedef fused _bits_t:
    uint8_t
    uint16_t
    uint32_t


def fill_holes(_bits_t[:, ::1] pixels, const uint8_t[::1] holes, uint64_t value):
    """Every channel of each pixel whose hole byte is 1 set to `value` (the
    samples' bits, as unsigned integers of their width; value's low bits), the others
    left (hole bytes 0 or 1, a bool array's): what numpy's pixels[holes] = value does,
    without its branch per pixel, which ragged sensor holes mispredict (1 ms for 640 x
    480 pixels with a third of them holes at random)."""
    cdef int64_t n = pixels.shape[0], c = pixels.shape[1], i, ch
    cdef _bits_t word = <_bits_t>value, keep
    cdef uint64_t eight
    cdef _bits_t* p = &pixels[0, 0] if n and c else NULL
    cdef const uint8_t* h = &holes[0] if n else NULL
    if holes.shape[0] != n:
        raise ValueError("fill_holes: one hole byte per pixel")
    with nogil:
        if c == 1:
            # eight pixels' hole bytes at a time: runs without holes (most of an image)
            # skipped, runs of holes filled, the rest pixel by pixel without a branch
            i = 0
            while i + 8 <= n:
                memcpy(&eight, h + i, 8)
                if eight == <uint64_t>0x0101010101010101ULL:
                    for ch in range(8):
                        p[i + ch] = word
                elif eight != 0:
                    for ch in range(8):
                        keep = <_bits_t>(h[i + ch] == 0) * <_bits_t>-1  # all ones where the pixel stays
                        p[i + ch] = (p[i + ch] & keep) | (word & ~keep)
                i += 8
            for i in range(i, n):
                keep = <_bits_t>(h[i] == 0) * <_bits_t>-1
                p[i] = (p[i] & keep) | (word & ~keep)
        else:
            for i in range(n):
                keep = <_bits_t>(h[i] == 0) * <_bits_t>-1
                for ch in range(c):
                    p[i * c + ch] = (p[i * c + ch] & keep) | (word & ~keep)


cpdef enum Front:
    FRONT_OK = 0
    FRONT_REFUSED = 1     # a field is wrong: meshcode reads the fields again to say which, and how


cdef int64_t _varint_scan(const uint8_t* data, int64_t size, int64_t longest, bint* long_) noexcept nogil:
    """How many LEB128 numbers fill data (-1 if the last one does not end), and in
    long_ whether one has more than `longest` bytes (a run of `longest` continuation
    bytes)."""
    cdef int64_t i, ends = 0, run = 0
    long_[0] = False
    for i in range(size):
        if data[i] < 0x80:
            ends += 1
            run = 0
        else:
            run += 1
            long_[0] |= run >= longest
    return -1 if size and data[size - 1] >= 0x80 else ends


cdef int64_t _varint_ends(const uint8_t* data, int64_t size, int64_t longest) noexcept nogil:
    """How many LEB128 numbers fill data, -1 unless every number ends within it and has
    at most `longest` bytes (what unvarints accepts for that count)."""
    cdef bint long_ = False
    cdef int64_t ends = _varint_scan(data, size, longest, &long_)
    return -1 if long_ else ends


cdef void _leb128_into(const uint8_t* data, int64_t size, int64_t* out) noexcept nogil:
    """The LEB128 numbers of data, which _varint_ends accepted, into out."""
    cdef int64_t i, k = 0
    cdef uint64_t value = 0
    cdef int shift = 0
    for i in range(size):
        value |= <uint64_t>(data[i] & 0x7F) << shift
        shift += 7
        if data[i] < 0x80:
            out[k] = <int64_t>value
            k += 1
            value = 0
            shift = 0


cdef inline const uint8_t* _bytes(const uint8_t[::1] field) noexcept nogil:
    return &field[0] if field.shape[0] else NULL


cdef bint _front(const uint8_t* lengths_field, int64_t lengths_size, const uint8_t* starts_field,
                 int64_t starts_size, const uint8_t* steps_field, int64_t steps_size, int64_t count, int64_t total,
                 const uint8_t* positions, int64_t positions_size, const uint8_t* packed, int64_t packed_size,
                 int64_t n, int64_t nf, int64_t width, int64_t rows, bint by_rows, int64_t curve_span,
                 int64_t max_bits, const int64_t* digit, const int64_t* nxt, const int64_t* xy, const int64_t* back,
                 int g, int64_t groups, int64_t start, int64_t* lengths, int64_t* flat, int64_t* walls,
                 int64_t* vertices, int64_t* seq, int64_t* lines, int64_t* frees, int64_t* sort_buf) noexcept nogil:
    """band_front's passes, its fields' varint counts checked (nf + 1 positions), into
    its arrays; lines, frees and sort_buf: scratch as band_front sizes them. False if
    anything is wrong."""
    cdef int64_t nsteps = total - count, pixels = width * rows, span = pixels if by_rows else curve_span
    cdef int64_t nl = 0, j, bits, pad, x, y
    cdef int64_t* starts = lines
    cdef int64_t* steps = starts + count
    cdef int64_t* keys = steps + 2 * nsteps
    cdef int64_t* rank = keys + total
    cdef int64_t* first = rank + total
    cdef int64_t* line_keys = first + total
    cdef int64_t* appear = line_keys + total
    cdef int64_t* line_places = appear + total
    cdef int64_t* nums = frees
    cdef int64_t* free_keys = nums + nf + 1
    cdef int64_t* curve_keys = free_keys + nf
    cdef int64_t* places = curve_keys + nf
    cdef int64_t* order
    # the polylines: lengths, starts, steps, walked into their points' keys
    _leb128_into(lengths_field, lengths_size, lengths)
    _leb128_into(starts_field, starts_size, starts)
    _leb128_into(steps_field, steps_size, steps)
    if total:
        if _chains(lengths, count, starts, True, steps, True, total, width, rows, steps, keys) != CHAINS_OK:
            return False
        order = _argsort(keys, total, pixels, sort_buf)
        if order == NULL:
            return False
        nl = _line_ranks(keys, order, total, rank, first)
        if nl < 0:
            return False
        _distinct(keys, rank, first, total, nl, line_keys, appear)
    elif count:
        return False
    if n - nl != nf:  # the positions hold one number more than the free vertices
        return False
    # the free vertices: the gaps' high parts, their low bits, summed into keys
    _leb128_into(positions, positions_size, nums)
    bits = nums[0]
    if bits > max_bits or packed_size != (nf * bits + 7) // 8:
        return False
    pad = 8 * packed_size - nf * bits  # all in the last byte
    if pad and packed[packed_size - 1] & ((1 << pad) - 1):
        return False
    if nf and not _position_keys(nums + 1, nf, packed, <int>bits, span, free_keys if by_rows else curve_keys):
        return False
    if not by_rows:
        # keys along the curve: their pixels, sorted into raster order
        for j in range(nf):
            _hilbert_point(curve_keys[j], xy, back, g, groups, start, &x, &y)
            if x >= width or y >= rows:
                return False
            curve_keys[j] = y * width + x
        order = _argsort(curve_keys, nf, pixels, sort_buf)
        if order == NULL:
            return False
        for j in range(nf):
            free_keys[j] = curve_keys[order[j]]
    if not _band_vertices(line_keys, nl, free_keys, nf, rank, total, appear, nl, lengths, count, width, vertices,
                          places, line_places, flat, walls, nsteps, seq):
        return False
    # the sample order: the polyline vertices (seq[:nl], as the chains reach them),
    # then the free ones along the curve
    if by_rows:
        for j in range(nf):
            curve_keys[j] = _hilbert_key(vertices[2 * places[j]], vertices[2 * places[j] + 1], digit, nxt, g,
                                         groups, start)
        order = _argsort(curve_keys, nf, curve_span, sort_buf)
        if order == NULL:
            return False
        for j in range(nf):
            seq[nl + j] = places[order[j]]
    else:
        # order, from the sort above (untouched since), takes raster places to curve ones
        for j in range(nf):
            seq[nl + order[j]] = places[j]
    return True


def band_front(const uint8_t[::1] lengths_field, const uint8_t[::1] starts_field, const uint8_t[::1] steps_field,
               int64_t count, int64_t total, const uint8_t[::1] positions, const uint8_t[::1] position_bits,
               int64_t n, int64_t width, int64_t rows, bint by_rows, int64_t longest, int64_t max_bits,
               const int64_t[::1] digit, const int64_t[::1] nxt, int g, int64_t groups, int64_t start,
               const int64_t[::1] xy, const int64_t[::1] back, int64_t curve_span):
    """(status, vertices, flat, lengths, walls, sample order): the part of a band's
    MESH payload (ATM.md §4.2.2, §4.2.4) before its triangles in one call, with one
    release of the GIL for the work: the polylines (their varints, chains and distinct
    pixels: meshcode._polylines' passes), the free vertices' keys (meshcode._free_keys;
    in raster order, or along the Hilbert curve, whose inverse tables xy and back
    give their pixels), both merged into the vertices in raster order
    (band_vertices), and the sample sequence: the polyline vertices as the chains
    first reach them, then the free ones along the curve (keys from the tables digit
    and nxt, below curve_span: curve_order). count, total, n: the payload's polyline,
    polyline point and vertex counts; longest: the longest varint; max_bits: the
    most low bits a position gap may store apart. Anything wrong gives FRONT_REFUSED
    (arrays None) without saying what: the caller reads the fields again with the
    separate kernels, which refuse in the order of the fields. Every count is
    checked against the fields' own varints before anything is allocated."""
    cdef int64_t size = 4 << (2 * g), nsteps = total - count, np_ = -1, nf, most
    cdef bint ok = False
    cdef int64_t* lines
    cdef int64_t* frees
    cdef int64_t* sort_buf
    refused = (FRONT_REFUSED, None, None, None, None, None)
    if digit.shape[0] != size or nxt.shape[0] != size or xy.shape[0] != size or back.shape[0] != size or \
            not 0 <= start < size or longest > 9 or width < 1 or rows < 1 or max_bits > 32:
        raise ValueError("band_front: tables of 4 << 2g entries, at most 9 bytes a varint, a band of pixels")
    if count < 0 or nsteps < 0 or n < 0:
        return refused
    with nogil:
        ok = (_varint_ends(_bytes(lengths_field), lengths_field.shape[0], longest) == count
              and _varint_ends(_bytes(starts_field), starts_field.shape[0], longest) == count
              and _varint_ends(_bytes(steps_field), steps_field.shape[0], longest) == 2 * nsteps)
        if ok:
            np_ = _varint_ends(_bytes(positions), positions.shape[0], longest)
    # n - nf distinct polyline points: between 0 and total
    nf = np_ - 1
    if not ok or nf < 0 or n < nf or n - nf > total:
        return refused
    lengths = np.empty(count, dtype=np.int64)
    flat = np.empty(total, dtype=np.int64)
    walls = np.empty((nsteps, 2), dtype=np.int64)
    vertices = np.empty((n, 2), dtype=np.int64)
    seq = np.empty(n, dtype=np.int64)
    cdef int64_t[::1] L = lengths, F = flat, S = seq
    cdef int64_t[:, ::1] W = walls, V = vertices
    # scratch in three pieces, each smaller than the band's vertices and triangles
    # (one piece of them all was the decode's largest allocation, which glibc maps
    # afresh, page faults and all, every time): the polylines' starts, steps, keys,
    # rank, first, line keys, appear and line places; the positions' numbers, free
    # keys, curve keys and places; the radix sorts' buffer
    most = total if total > nf else nf
    lines = <int64_t*>malloc(sizeof(int64_t) * (count + 2 * nsteps + 6 * total + 1))
    frees = <int64_t*>malloc(sizeof(int64_t) * (4 * nf + 2))
    sort_buf = <int64_t*>malloc(sizeof(int64_t) * _argsort_words(most, max(width * rows, curve_span)))
    if lines == NULL or frees == NULL or sort_buf == NULL:
        free(lines)
        free(frees)
        free(sort_buf)
        raise MemoryError("band_front: no memory for a band's scratch")
    with nogil:
        ok = _front(_bytes(lengths_field), lengths_field.shape[0], _bytes(starts_field), starts_field.shape[0],
                    _bytes(steps_field), steps_field.shape[0], count, total, _bytes(positions), positions.shape[0],
                    _bytes(position_bits), position_bits.shape[0], n, nf, width, rows, by_rows, curve_span, max_bits,
                    &digit[0], &nxt[0], &xy[0], &back[0], g, groups, start, &L[0] if count else NULL,
                    &F[0] if total else NULL, &W[0, 0] if nsteps else NULL, &V[0, 0] if n else NULL,
                    &S[0] if n else NULL, lines, frees, sort_buf)
        free(lines)
        free(frees)
        free(sort_buf)
    if not ok:
        return refused
    return FRONT_OK, vertices, flat, lengths, walls, seq


def stack_bands(list vertex_arrays, list triangle_arrays, const int64_t[::1] rows_down):
    """(vertices, triangles): consecutive bands' vertices (each N x 2 int64) moved down
    by their band's rows_down, one after another, and their triangles (each M x 3
    int64) renumbered to follow (stream.stack_bands), in one pass over each array
    instead of numpy's temporaries per band."""
    cdef Py_ssize_t bands = len(vertex_arrays), b
    cdef int64_t nv = 0, nt = 0, at = 0, first = 0, j, shift, offset
    cdef const int64_t[:, ::1] v
    cdef const int64_t[:, ::1] t
    if len(triangle_arrays) != bands or rows_down.shape[0] != bands:
        raise ValueError("stack_bands: vertices, triangles and a shift for each band")
    for b in range(bands):
        nv += len(vertex_arrays[b])
        nt += len(triangle_arrays[b])
    vertices = np.empty((nv, 2), dtype=np.int64)
    triangles = np.empty((nt, 3), dtype=np.int64)
    cdef int64_t[:, ::1] ov = vertices, ot = triangles
    for b in range(bands):
        v = vertex_arrays[b]
        t = triangle_arrays[b]
        if v.shape[1] != 2 or t.shape[1] != 3:  # (the loops read columns unchecked)
            raise ValueError("stack_bands: vertices are N x 2 and triangles M x 3")
        shift = rows_down[b]
        offset = first
        with nogil:
            for j in range(v.shape[0]):
                ov[first + j, 0] = v[j, 0]
                ov[first + j, 1] = v[j, 1] + shift
            for j in range(t.shape[0]):
                ot[at + j, 0] = t[j, 0] + offset
                ot[at + j, 1] = t[j, 1] + offset
                ot[at + j, 2] = t[j, 2] + offset
        first += v.shape[0]
        at += t.shape[0]
    return vertices, triangles
