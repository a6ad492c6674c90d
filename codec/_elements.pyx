"""Encoder kernel: what the adaptive mesher measures of each triangle, in one walk over
the pixels it owns (codec.mesher.elements: the half-open rule, left and top edges
inclusive), row by row as the rasteriser walks them, with no span arrays in between.

triangle_statistics: per triangle, the sums over its row spans of the geometric moments and
of K prefix-summed planes (and of y times each), as codec.mesher.elements.Statistics
keeps them, and its squared error against a plane through its corners;
worst_pixels: per triangle, its pixel farthest from a plane through its corners.

Both give the very numbers of the numpy code they replace: the spans' edge crossings
are the same float64 quotients of exact integers, and the sums are taken span by span
in row order, as a sparse row-sum adds them. The GIL is released while they work.
"""

cimport cython
from libc.math cimport ceil, fabs
from libc.stdint cimport int32_t, int64_t, uint8_t, uint16_t, uint64_t

from codec.offsets cimport OFFSETS_DECREASE, OFFSETS_ENDS, offsets_fault
from codec.planefit cimport plane_sse

import numpy as np

ctypedef fused table_t:
    int32_t
    int64_t
    double

ctypedef fused plane_t:
    float
    double

# What triangle_statistics sums a span from: a prefix table (table_t's types), or one
# 8- or 16-bit plane itself, summed pixel by pixel in int64 (the integers the table's
# differences give, without the table: 12 bytes a pixel built per image, for a walk
# that then reads two of its cache lines a span instead of one of the plane's)
ctypedef fused source_t:
    uint8_t
    uint16_t
    int32_t
    int64_t
    double


cdef enum:
    # most planes prefix_table sums: the structure's three and two per fitted channel
    MAX_PLANES = 32


cdef inline void _sort3(int64_t* ys, int64_t* xs) noexcept nogil:
    # the compare-and-swap network of elements._sort3: stable for equal rows
    cdef int64_t t
    cdef int i, j, k
    for k in range(3):
        i = 0 if k != 1 else 1
        j = i + 1
        if ys[j] < ys[i]:
            t = ys[i]; ys[i] = ys[j]; ys[j] = t
            t = xs[i]; xs[i] = xs[j]; xs[j] = t


cdef extern from *:
    """
    /* The row walk in C, so that its helpers can be forced inline (Cython has no way to
       say so: its `inline` is a hint, which gcc's unit-growth limit overrides in this
       large module, leaving the calls a fifth of triangle_statistics' time). */
    #include "inline.hpp"
    /* ceil((n0 + s dy) / d) for dy = 0, 1, ..., d > 0: the quotient q and the
       remainder r = q d - n (0 <= r < d), stepped by s = sq d + sr (0 <= sr < d) */
    typedef struct { int64_t q, r, sq, sr, d; } atm_edge;
    /* a triangle's row spans (corners sorted by row, _sort3), row after row: the long
       edge (top to bottom corner) against the upper short edge down to row `up`, then
       the lower one (elements._triangle_spans' crossings, in exact integers: that
       function proves its float64 quotients' ceilings exact) */
    typedef struct { atm_edge long_edge, short_edge; int64_t dy, up, lower_n0, lower_s, lower_d; } atm_rows;

    static ATM_INLINE int64_t atm_floor_div(int64_t a, int64_t b) {
        /* a // b rounded toward minus infinity, b > 0 (C division truncates) */
        int64_t q = a / b;
        if (a % b != 0 && a < 0) q -= 1;
        return q;
    }
    static ATM_INLINE void atm_edge_start(atm_edge* e, int64_t n0, int64_t s, int64_t d, int64_t dy) {
        int64_t n = n0 + s * dy;
        e->d = d;
        e->q = -atm_floor_div(-n, d);
        e->r = e->q * d - n;
        e->sq = atm_floor_div(s, d);
        e->sr = s - e->sq * d;
    }
    static ATM_INLINE void atm_edge_step(atm_edge* e) {
        /* r - sr < 0 wraps the remainder and carries one into q, without a branch
           (which an edge's slope makes hard to predict) */
        int64_t r = e->r - e->sr;
        int64_t wrap = r >> 63;  /* -1 where r < 0, else 0 */
        e->r = r + (e->d & wrap);
        e->q += e->sq - wrap;
    }
    static ATM_INLINE void atm_rows_start(atm_rows* w, const int64_t* ys, const int64_t* xs, int64_t up) {
        int64_t tall = ys[2] - ys[0], upper = ys[1] - ys[0], lower = ys[2] - ys[1];
        w->dy = 0;
        w->up = up;
        if (tall > 0) atm_edge_start(&w->long_edge, xs[0] * tall, xs[2] - xs[0], tall, 0);
        else atm_edge_start(&w->long_edge, xs[0], 0, 1, 0);  /* no rows: never stepped */
        if (upper == 0) atm_edge_start(&w->short_edge, xs[1], 0, 1, 0);  /* a flat top: x = xb */
        else atm_edge_start(&w->short_edge, xs[0] * upper, xs[1] - xs[0], upper, 0);
        w->lower_d = lower > 1 ? lower : 1;
        w->lower_n0 = xs[1] * w->lower_d - (xs[2] - xs[1]) * upper;
        w->lower_s = xs[2] - xs[1];
    }
    static void atm_rows_lower(atm_rows* w) {
        /* the lower short edge takes over (kept out of atm_rows_next: once a triangle) */
        atm_edge_start(&w->short_edge, w->lower_n0, w->lower_s, w->lower_d, w->dy);
    }
    static ATM_INLINE void atm_rows_next(atm_rows* w, int64_t* left, int64_t* count) {
        /* columns [left, left + count) of the next row (row ya + dy, dy from 0) */
        int64_t a, b;
        if (w->dy == w->up) atm_rows_lower(w);
        a = w->long_edge.q;
        b = w->short_edge.q;
        if (a < b) { *left = a; *count = b - a; }
        else { *left = b; *count = a - b; }
        atm_edge_step(&w->long_edge);
        atm_edge_step(&w->short_edge);
        w->dy += 1;
    }
    """
    ctypedef struct _Rows "atm_rows":
        pass
    void _rows_start "atm_rows_start"(_Rows* w, const int64_t* ys, const int64_t* xs, int64_t up) noexcept nogil
    void _rows_next "atm_rows_next"(_Rows* w, int64_t* left, int64_t* count) noexcept nogil


cdef struct _Mesh:
    # the kernels' vertices (n x 2) and triangles (M x 3) as pointers: a memoryview
    # handed to a helper per triangle is a struct of some 200 bytes copied each time
    const int64_t* xy
    const int64_t* tri
    int64_t n, width, height


cdef _Mesh _mesh(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width,
                 int64_t height):
    cdef _Mesh mesh
    mesh.xy = &vertices[0, 0] if vertices.shape[0] else NULL
    mesh.tri = &triangles[0, 0] if triangles.shape[0] else NULL
    mesh.n = vertices.shape[0]
    mesh.width = width
    mesh.height = height
    return mesh


cdef inline bint _corners(const _Mesh* mesh, int64_t t, int64_t* ys, int64_t* xs) noexcept nogil:
    """The triangle's corners (False if an index or a coordinate is out of range)."""
    cdef int64_t i, v
    for i in range(3):
        v = mesh.tri[3 * t + i]
        if v < 0 or v >= mesh.n:
            return False
        xs[i] = mesh.xy[2 * v]
        ys[i] = mesh.xy[2 * v + 1]
        if xs[i] < 0 or xs[i] >= mesh.width or ys[i] < 0 or ys[i] >= mesh.height:
            return False
    return True


cdef inline bint _start(const _Mesh* mesh, int64_t t, int64_t* ys, int64_t* xs, int64_t* up) noexcept nogil:
    """The triangle's corners sorted by row and the rows of its upper piece (down to the
    middle corner's row, the last of all rows excluded); False if out of range."""
    if not _corners(mesh, t, ys, xs):
        return False
    _sort3(ys, xs)
    up[0] = ys[1] - ys[0] + 1
    if up[0] > ys[2] - ys[0]:
        up[0] = ys[2] - ys[0]
    return True


cdef inline void _origin(const int64_t* px, const int64_t* py, int64_t width, int64_t* ox,
                         int64_t* oy) noexcept nogil:
    """The triangle's origin: its first corner in raster order (elements.triangle_raster)."""
    cdef int i, best = 0
    for i in range(1, 3):
        if py[i] * width + px[i] < py[best] * width + px[best]:
            best = i
    ox[0] = px[best]
    oy[0] = py[best]


@cython.cdivision(True)
cdef inline void _affine(const int64_t* px, const int64_t* py, int64_t ox, int64_t oy, double z0,
                         double z1, double z2, double* f) noexcept nogil:
    """f = (a, b, c) of the plane a u + b v + c through the corners' values (listed order),
    u, v relative to (ox, oy), with the float64 operations of
    elements._triangle_coefficients and Raster.affine in their order: corner after
    corner, then / D."""
    cdef int64_t coef[3][3]
    cdef int i, j, k
    cdef double den
    for i in range(3):
        # w_i = (xk - xj)(y - yj) - (yk - yj)(x - xj)
        j = (i + 1) % 3
        k = (i + 2) % 3
        coef[i][0] = -(py[k] - py[j])
        coef[i][1] = px[k] - px[j]
        coef[i][2] = (px[k] - px[j]) * (oy - py[j]) - (py[k] - py[j]) * (ox - px[j])
    den = <double>(coef[0][2] + coef[1][2] + coef[2][2])
    for k in range(3):
        f[k] = <double>coef[0][k] * z0
        f[k] = f[k] + <double>coef[1][k] * z1
        f[k] = f[k] + <double>coef[2][k] * z2
        f[k] = f[k] / den


cdef inline bint _start_listed(const _Mesh* mesh, int64_t t, int64_t* py, int64_t* px, int64_t* ys,
                               int64_t* xs, int64_t* up) noexcept nogil:
    """_start, keeping the corners as listed too (py, px)."""
    cdef int i
    if not _corners(mesh, t, py, px):
        return False
    for i in range(3):
        ys[i] = py[i]
        xs[i] = px[i]
    _sort3(ys, xs)
    up[0] = ys[1] - ys[0] + 1
    if up[0] > ys[2] - ys[0]:
        up[0] = ys[2] - ys[0]
    return True


def _check(vertices, triangles, width, height):
    if vertices.shape[1] != 2 or triangles.shape[1] != 3:
        raise ValueError("vertices must be N x 2 and triangles M x 3")
    if not 0 < width < 2**20 or not 0 < height < 2**20:
        raise ValueError(f"image size {width} x {height} out of range")


cdef inline void _add_span(double* sums, const source_t* table, int64_t width, int64_t kk, int64_t y,
                           int64_t x0, int64_t n, const double* power1, const double* power2) noexcept nogil:
    """A span's terms (row y, columns [x0, x0 + n), n > 0) added to the raw sums
    sums[0 .. 6 + 2 kk) of triangle_statistics: n, X1, y n, X2, y X1, y (y n), then each
    plane's sum d_k and y d_k, from the plane itself (8 or 16 bits) or its prefix
    table ((H (W + 1)) x kk)."""
    cdef int64_t lo, hi, k, i, b, span_b, span_xb, span_bb
    cdef double yf = <double>y, nf = <double>n, x1s, x2s, yn, d
    cdef source_t dk
    cdef const source_t* pix
    x1s = power1[x0 + n] - power1[x0]
    x2s = power2[x0 + n] - power2[x0]
    yn = yf * nf
    sums[0] += nf
    sums[1] += x1s
    sums[2] += yn
    sums[3] += x2s
    sums[4] += yf * x1s
    sums[5] += yf * yn
    if source_t is uint8_t or source_t is uint16_t:
        pix = table + y * width + x0
        span_b = 0
        span_xb = 0
        span_bb = 0
        for i in range(n):
            b = pix[i]
            span_b += b
            span_xb += (x0 + i) * b
            span_bb += b * b
        d = <double>span_b
        sums[6] += d
        sums[9] += yf * d
        d = <double>span_xb
        sums[7] += d
        sums[10] += yf * d
        d = <double>span_bb
        sums[8] += d
        sums[11] += yf * d
    else:
        lo = (y * (width + 1) + x0) * kk
        hi = lo + n * kk
        for k in range(kk):
            dk = table[hi + k] - table[lo + k]
            d = <double>dk
            sums[6 + k] += d
            sums[6 + kk + k] += yf * d


cdef inline void _moved(double* row, double fx, double fy, const int64_t* blocks, int64_t nb) noexcept nogil:
    """A row of statistics in image coordinates moved to the origin (fx, fy):
    elements.Statistics._to_origin, operation for operation (blocks: the first
    columns of the image sums b, ub, vb)."""
    cdef double sn = row[0], sx = row[1], sy = row[2], sxx = row[3], sxy = row[4], syy = row[5], sb
    cdef int64_t j, first
    row[1] = sx - fx * sn
    row[2] = sy - fy * sn
    row[3] = sxx - 2 * fx * sx + fx * fx * sn
    row[4] = sxy - fx * sy - fy * sx + fx * fy * sn
    row[5] = syy - 2 * fy * sy + fy * fy * sn
    for j in range(nb):
        first = blocks[j]
        sb = row[first]
        row[first + 1] = row[first + 1] - fx * sb
        row[first + 2] = row[first + 2] - fy * sb


cdef void _triangle_sums(double* out, int64_t raw, const source_t* table, int64_t width, int64_t kk,
                         const int64_t* ys, const int64_t* xs, int64_t up, const double* power1,
                         const double* power2) noexcept nogil:
    """triangle_statistics' raw sums (out[0 .. raw)) of one triangle (corners sorted by row,
    _start_listed), span by span in row order. A function of its own, small enough that
    the compiler inlines the row walk into it (inside triangle_statistics it did not), and
    summing into a local array that the plane (char-sized: it may alias anything) and the
    power tables cannot alias, so the sums stay in registers."""
    cdef double sums[6 + 2 * MAX_PLANES]
    cdef _Rows rows
    cdef int64_t dy, x0, n, k
    for k in range(raw):
        sums[k] = 0.0
    _rows_start(&rows, ys, xs, up)
    for dy in range(ys[2] - ys[0]):
        _rows_next(&rows, &x0, &n)
        if n <= 0:
            continue  # an empty span adds nothing to any sum
        _add_span(sums, table, width, kk, ys[0] + dy, x0, n, power1, power2)
    for k in range(raw):
        out[k] = sums[k]


@cython.cdivision(True)
def triangle_statistics(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width,
                        int64_t height, const source_t[:, ::1] table, const double[::1] power1,
                        const double[::1] power2, const int64_t[::1] columns, const int64_t[::1] blocks,
                        const double[::1] z, const int64_t[::1] only=None, double[:, ::1] into=None,
                        double[::1] sse_into=None):
    """(M x C statistics, M squared errors or None) of the triangles: per triangle the sums
    over its spans (row y, columns [x0, x1), n pixels) in row order of n, X1, y n, X2,
    y X1, y (y n) (Xk = power_k[x1] - power_k[x0]), then of d_k = table[y s + x1, k] -
    table[y s + x0, k] for each of the K planes (s = width + 1: a row's prefix sums,
    elements.Planes), then of y d_k; of these, columns[c] is statistic c, moved to the
    triangle's origin (its first corner in raster order) as
    elements.Statistics._to_origin moves them (blocks: the first columns of the image
    sums b, ub, vb). With z (a value per vertex; empty: none), also each triangle's
    squared error against the plane through its corners' values, as
    elements.element_sse gives it (the same float64 operations in the same order, so
    the same numbers). `table` may instead be the one plane itself (H x W, 8 or 16
    bits, K = 3: b, x b, b b), whose spans are summed pixel by pixel in int64: the
    integers an integer table's differences give, so the same statistics. only (with
    into, and sse_into if z is given): measure only the triangles only[i] of
    `triangles`, each written to that row of into (and of sse_into), which are
    returned (refinement keeps its triangles' numbers by the triangulation's slots,
    with no gather and scatter of them). ValueError on an index or coordinate out of
    range."""
    _check(vertices, triangles, width, height)
    cdef _Mesh geometry = _mesh(vertices, triangles, width, height)
    cdef bint direct = source_t is uint8_t or source_t is uint16_t
    cdef int64_t m = triangles.shape[0], kk = 3 if direct else table.shape[1], stride = width + 1
    cdef int64_t nc = columns.shape[0], nb = blocks.shape[0], raw = 6 + 2 * kk
    if direct and (table.shape[0] != height or table.shape[1] != width):
        raise ValueError("triangle_statistics: the plane does not match the image size")
    if (not direct and table.shape[0] != height * stride) or power1.shape[0] <= width or power2.shape[0] <= width:
        raise ValueError("triangle_statistics: tables do not match the image size")
    cdef int64_t q
    if nc < 10:
        raise ValueError("triangle_statistics: fewer than 10 statistics")
    for q in range(nc):
        if not 0 <= columns[q] < raw:
            raise ValueError("triangle_statistics: a column out of range")
    for q in range(nb):
        if not 6 <= blocks[q] < nc - 2:
            raise ValueError("triangle_statistics: a column out of range")
    cdef bint errors = z.shape[0] > 0
    if errors and z.shape[0] != vertices.shape[0]:
        raise ValueError("triangle_statistics: z needs a value per vertex")
    cdef int64_t count = m, i
    if only is not None:
        if into is None or into.shape[0] < m or into.shape[1] != nc or (
                errors and (sse_into is None or sse_into.shape[0] < m)):
            raise ValueError("triangle_statistics: only needs into (and sse_into) with a row per triangle")
        for i in range(only.shape[0]):
            if not 0 <= only[i] < m:
                raise ValueError("triangle_statistics: a row beyond the triangles")
        count = only.shape[0]
        out = into
        sse_out = sse_into if errors else np.empty(0, dtype=np.float64)
    else:
        out = np.empty((m, nc), dtype=np.float64)
        sse_out = np.empty(m if errors else 0, dtype=np.float64)
    if kk > MAX_PLANES:
        raise ValueError("triangle_statistics: more planes than MAX_PLANES")
    cdef double[:, ::1] o = out
    cdef double[::1] e = sse_out
    cdef const int64_t* which = &only[0] if only is not None and count else NULL
    cdef double sums[6 + 2 * MAX_PLANES]
    cdef int64_t t, dy, x0, n, k, up, c, ox, oy
    cdef _Rows rows
    cdef int64_t ys[3]
    cdef int64_t xs[3]
    cdef int64_t px[3]
    cdef int64_t py[3]
    cdef double f[3]
    cdef bint bad = False
    with nogil:
        for i in range(count):
            t = which[i] if which != NULL else i
            if not _start_listed(&geometry, t, py, px, ys, xs, &up):
                bad = True
                break
            _triangle_sums(sums, raw, &table[0, 0], width, kk, ys, xs, up, &power1[0], &power2[0])
            for c in range(nc):
                o[t, c] = sums[columns[c]]
            _origin(px, py, width, &ox, &oy)
            _moved(&o[t, 0], <double>ox, <double>oy, &blocks[0] if nb else NULL, nb)
            if not errors:
                continue
            _affine(px, py, ox, oy, z[triangles[t, 0]], z[triangles[t, 1]], z[triangles[t, 2]], f)
            # elements.squared_error (codec/planefit.pxd)
            e[t] = plane_sse(f[0], f[1], f[2], o[t, 0], o[t, 1], o[t, 2], o[t, 3], o[t, 4], o[t, 5],
                             o[t, 6], o[t, 7], o[t, 8], o[t, 9])
    if bad:
        raise ValueError("triangle_statistics: a corner index or coordinate out of range")
    return out, (sse_out if errors else None)


cdef inline double _span_worst(const plane_t* line, int64_t y, int64_t x0, int64_t n, int64_t ox, double a,
                               double row, double c, double best, int64_t* bx, int64_t* by) noexcept nogil:
    """The span's pixels (line: its row of the plane) against the mesh a (x - ox) + row + c,
    summed in that order as elements.Raster.worst_pixels sums it: the largest error
    (from best), its first pixel in (bx, by)."""
    cdef int64_t x
    cdef double mesh, e
    for x in range(x0, x0 + n):
        mesh = a * <double>(x - ox)
        mesh += row
        mesh += c
        e = fabs(<double>line[x] - mesh)
        if e > best:
            best = e
            bx[0] = x
            by[0] = y
    return best


def span_statistics(const source_t[:, ::1] table, const int64_t[::1] bounds, const int64_t[::1] span_y,
                    const int64_t[::1] span_x, const int64_t[::1] span_n, const int64_t[:, ::1] origin,
                    const double[::1] power1, const double[::1] power2, const int64_t[::1] columns,
                    const int64_t[::1] blocks):
    """Statistics.__call__ of a raster from its spans (element e's are bounds[e] ..
    bounds[e + 1] - 1) and origins: triangle_statistics' sums over given spans instead
    of a triangle's, the same numbers as the numpy columns and their row sums. `table`:
    an 8- or 16-bit plane (H x W) or a prefix table ((H (W + 1)) x K, W = len(power1) - 1).
    ValueError on a span outside the image or tables that do not match."""
    cdef int64_t e_count = bounds.shape[0] - 1, s = span_y.shape[0], nc = columns.shape[0], nb = blocks.shape[0]
    cdef int64_t width = power1.shape[0] - 1, height, kk, e, j, c
    cdef bint direct = source_t is uint8_t or source_t is uint16_t
    if direct:
        height = table.shape[0]
        kk = 3
        if table.shape[1] != width:
            raise ValueError("span_statistics: the plane does not match the image size")
    else:
        height = table.shape[0] // (width + 1)
        kk = table.shape[1]
        if table.shape[0] != height * (width + 1):
            raise ValueError("span_statistics: tables do not match the image size")
    if (e_count < 0 or span_x.shape[0] != s or span_n.shape[0] != s or origin.shape[0] != e_count
            or origin.shape[1] != 2 or power2.shape[0] != width + 1 or kk > MAX_PLANES or nc < 10):
        raise ValueError("span_statistics: the arrays do not match")
    for c in range(nc):
        if not 0 <= columns[c] < 6 + 2 * kk:
            raise ValueError("span_statistics: a column out of range")
    for c in range(nb):
        if not 6 <= blocks[c] < nc - 2:
            raise ValueError("span_statistics: a column out of range")
    fault = offsets_fault(bounds, e_count, s)
    if fault == OFFSETS_ENDS:
        raise ValueError("span_statistics: bounds must run from 0 to the number of spans")
    if fault == OFFSETS_DECREASE:
        raise ValueError("span_statistics: bounds must not decrease")
    for j in range(s):
        if span_n[j] > 0 and not (0 <= span_y[j] < height and 0 <= span_x[j] and span_x[j] + span_n[j] <= width):
            raise ValueError("span_statistics: a span outside the image")
    out = np.empty((e_count, nc), dtype=np.float64)
    cdef double[:, ::1] o = out
    cdef double sums[6 + 2 * MAX_PLANES]
    with nogil:
        for e in range(e_count):
            for c in range(6 + 2 * kk):
                sums[c] = 0.0
            for j in range(bounds[e], bounds[e + 1]):
                if span_n[j] > 0:  # an empty span adds nothing to any sum
                    _add_span(sums, &table[0, 0], width, kk, span_y[j], span_x[j], span_n[j], &power1[0], &power2[0])
            for c in range(nc):
                o[e, c] = sums[columns[c]]
            _moved(&o[e, 0], <double>origin[e, 0], <double>origin[e, 1], &blocks[0] if nb else NULL, nb)
    return out


def _worst_outputs(int64_t k):
    """(x, y, |error|) per element for the worst-pixel kernels: none found yet."""
    return np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), np.full(k, -1.0)


def worst_pixels(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width,
                 int64_t height, const double[::1] z, const plane_t[:, ::1] plane):
    """Per triangle, its owned pixel farthest from the plane through its corners' values
    z (elements.Raster.affine's plane, relative to its origin) against `plane` (H x W),
    the first in raster order of those tied: (x, y, |error| (-1 where the triangle owns
    no pixel)). ValueError on an index or coordinate out of range."""
    _check(vertices, triangles, width, height)
    cdef _Mesh geometry = _mesh(vertices, triangles, width, height)
    cdef int64_t m = triangles.shape[0]
    if z.shape[0] != vertices.shape[0]:
        raise ValueError("worst_pixels: z needs a value per vertex")
    if plane.shape[0] != height or plane.shape[1] != width:
        raise ValueError("worst_pixels: the plane does not match the image size")
    xs_out, ys_out, err_out = _worst_outputs(m)
    cdef int64_t[::1] bx = xs_out, by = ys_out
    cdef double[::1] be = err_out
    cdef int64_t t, dy, y, x0, n, up, ox, oy
    cdef _Rows rows
    cdef int64_t ys[3]
    cdef int64_t xs[3]
    cdef int64_t px[3]
    cdef int64_t py[3]
    cdef double f[3]
    cdef double row, best
    cdef bint bad = False
    with nogil:
        for t in range(m):
            if not _start_listed(&geometry, t, py, px, ys, xs, &up):
                bad = True
                break
            _origin(px, py, width, &ox, &oy)
            _affine(px, py, ox, oy, z[triangles[t, 0]], z[triangles[t, 1]], z[triangles[t, 2]], f)
            best = -1.0
            _rows_start(&rows, ys, xs, up)
            for dy in range(ys[2] - ys[0]):
                _rows_next(&rows, &x0, &n)
                y = ys[0] + dy
                row = f[1] * <double>(y - oy)
                best = _span_worst(&plane[y, 0], y, x0, n, ox, f[0], row, f[2], best, &bx[t], &by[t])
            be[t] = best
    if bad:
        raise ValueError("worst_pixels: a corner index or coordinate out of range")
    return xs_out, ys_out, err_out


def triangle_pixels(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width,
                    int64_t height):
    """(triangle, x, y) of every pixel the triangles own, triangle by triangle, row by
    row, left to right (Raster.pixels of their triangle_raster). ValueError on an
    index or coordinate out of range."""
    _check(vertices, triangles, width, height)
    cdef _Mesh geometry = _mesh(vertices, triangles, width, height)
    cdef int64_t m = triangles.shape[0], total = 0, t, dy, y, x0, n, x, up, j = 0
    cdef _Rows rows
    cdef int64_t ys[3]
    cdef int64_t xs[3]
    cdef bint bad = False
    with nogil:
        for t in range(m):
            if not _start(&geometry, t, ys, xs, &up):
                bad = True
                break
            _rows_start(&rows, ys, xs, up)
            for dy in range(ys[2] - ys[0]):
                _rows_next(&rows, &x0, &n)
                total += n
    if bad:
        raise ValueError("triangle_pixels: a corner index or coordinate out of range")
    e_out = np.empty(total, dtype=np.int64)
    x_out = np.empty(total, dtype=np.int64)
    y_out = np.empty(total, dtype=np.int64)
    cdef int64_t[::1] pe = e_out, px = x_out, py = y_out
    with nogil:
        for t in range(m):
            _start(&geometry, t, ys, xs, &up)
            _rows_start(&rows, ys, xs, up)
            for dy in range(ys[2] - ys[0]):
                _rows_next(&rows, &x0, &n)
                y = ys[0] + dy
                for x in range(x0, x0 + n):
                    pe[j] = t
                    px[j] = x
                    py[j] = y
                    j += 1
    return e_out, x_out, y_out


def evaluate(const double[:, ::1] affine, const int64_t[:, ::1] origin, const int64_t[::1] elem,
             const int64_t[::1] x, const int64_t[::1] y):
    """f = a (x - ox) + b (y - oy) + c at each pixel (x, y) of element elem (affine's
    and origin's rows), summed in that order as Raster.evaluate sums it. ValueError on
    an element out of range."""
    cdef int64_t k = elem.shape[0], e = affine.shape[0], i
    if x.shape[0] != k or y.shape[0] != k or origin.shape[0] != e or affine.shape[1] != 3 or origin.shape[1] != 2:
        raise ValueError("evaluate: an element, x and y per pixel; an affine and an origin per element")
    out_a = np.empty(k, dtype=np.float64)
    cdef double[::1] out = out_a
    cdef bint bad = False
    with nogil:
        for i in range(k):
            if elem[i] < 0 or elem[i] >= e:
                bad = True
                break
            out[i] = (affine[elem[i], 0] * <double>(x[i] - origin[elem[i], 0])
                      + affine[elem[i], 1] * <double>(y[i] - origin[elem[i], 1]) + affine[elem[i], 2])
    if bad:
        raise ValueError("evaluate: an element index out of range")
    return out_a


def prefix_table(const table_t[:, ::1] structure, const table_t[:, :, ::1] channels):
    """(H (W + 1)) x K prefix sums along the rows of the planes b, x b, b b of the
    structure b (H x W) and b_c, x b_c of each of the C channels (C x H x W), in the
    structure's type and interleaved (elements.Planes: row y, columns [x, x + n) of
    plane k is table[y (W + 1) + x + n, k] - table[y (W + 1) + x, k]); each sum taken
    left to right, as numpy's cumsum takes it."""
    cdef int64_t h = structure.shape[0], w = structure.shape[1], c = channels.shape[0]
    cdef int64_t kk = 3 + 2 * c, y, x, k, base
    if kk > MAX_PLANES or (c and (channels.shape[1] != h or channels.shape[2] != w)):
        raise ValueError("prefix_table: the channels must match the structure, at most 14 of them")
    if table_t is int32_t:
        kind = np.int32
    elif table_t is int64_t:
        kind = np.int64
    else:
        kind = np.float64
    out = np.zeros((h * (w + 1), kk), dtype=kind)
    cdef table_t[:, ::1] o = out
    cdef table_t acc[MAX_PLANES]
    cdef table_t b, xv
    with nogil:
        for y in range(h):
            base = y * (w + 1)
            for k in range(kk):
                acc[k] = 0
            for x in range(w):
                xv = <table_t>x
                b = structure[y, x]
                acc[0] += b
                acc[1] += b * xv
                acc[2] += b * b
                o[base + x + 1, 0] = acc[0]
                o[base + x + 1, 1] = acc[1]
                o[base + x + 1, 2] = acc[2]
                for k in range(c):
                    b = channels[k, y, x]
                    acc[3 + 2 * k] += b
                    acc[4 + 2 * k] += b * xv
                    o[base + x + 1, 3 + 2 * k] = acc[3 + 2 * k]
                    o[base + x + 1, 4 + 2 * k] = acc[4 + 2 * k]
    return out


def span_totals(const double[:, ::1] per_span, const int64_t[::1] bounds):
    """E x K: for each element e, the sum of the columns bounds[e] .. bounds[e+1]-1 of
    per_span (K x S), taken column after column from 0.0 (as a sparse row-sum of ones
    takes it). ValueError unless bounds run from 0 to S without decreasing."""
    cdef int64_t kk = per_span.shape[0], s = per_span.shape[1], e = bounds.shape[0] - 1, i, j, k
    fault = OFFSETS_ENDS if e < 0 else offsets_fault(bounds, e, s)
    if fault == OFFSETS_ENDS:
        raise ValueError("span_totals: bounds must run from 0 to the number of spans")
    if fault == OFFSETS_DECREASE:
        raise ValueError("span_totals: bounds must not decrease")
    out = np.zeros((e, kk), dtype=np.float64)
    cdef double[:, ::1] o = out
    with nogil:
        for i in range(e):
            for j in range(bounds[i], bounds[i + 1]):
                for k in range(kk):
                    o[i, k] += per_span[k, j]
    return out


cdef inline int64_t _slot(uint64_t key, int bits) noexcept nogil:
    # Fibonacci hashing: the high bits of the key times 2^64 / golden ratio
    return <int64_t>((key * <uint64_t>0x9E3779B97F4A7C15) >> (64 - bits))


def cached(const int64_t[::1] pixel, const int64_t[:, ::1] triangles, int64_t base,
           const int64_t[::1] old_keys, const int64_t[::1] old_rows, const double[::1] old_sse,
           int64_t next_row):
    """A refinement round's triangles against the last round's (codec.mesher.refine):
    (keys, rows, sse, fresh). Each triangle's key is (low base + middle) base + high of
    its corners' pixel numbers `pixel` (below base; base**3 < 2**62; base 0: no keys,
    all fresh), so it names the same triangle however the vertices are numbered or the
    corners listed; a triangle whose key is in old_keys gets that key's row (where its
    statistics are kept) and squared error, the others are listed in fresh (ascending)
    and get the rows next_row, next_row + 1, ... in that order, their squared errors
    left for the caller. A hash table, not a sort: the cache is kept in triangle order.
    ValueError on a corner index out of range or arrays that do not match."""
    cdef int64_t m = triangles.shape[0], n_old = old_keys.shape[0]
    cdef int64_t npix = pixel.shape[0], t, j, s, nf = 0, a, b, c, low, high, k
    cdef int bits = 4
    if triangles.shape[1] != 3 or old_rows.shape[0] != n_old or old_sse.shape[0] != n_old:
        raise ValueError("cached: triangles M x 3, and a row and a squared error per old key")
    if base < 0 or (<object>base) ** 3 >= 2 ** 62:
        raise ValueError("cached: a base of pixel numbers out of range (keys would overflow)")
    while (<int64_t>1 << bits) < 2 * n_old:
        bits += 1
    keys_out = np.empty(m if base else 0, dtype=np.int64)
    rows_out = np.empty(m, dtype=np.int64)
    sse_out = np.empty(m, dtype=np.float64)
    fresh_out = np.empty(m, dtype=np.int64)
    cdef int64_t[::1] keys = keys_out, rows = rows_out
    cdef double[::1] se = sse_out
    cdef int64_t[::1] fresh = fresh_out
    cdef int64_t size = <int64_t>1 << bits
    table_arr = np.full(size, -1, dtype=np.int64)
    cdef int64_t[::1] table = table_arr
    cdef bint bad = False
    with nogil:
        for j in range(n_old if base else 0):
            s = _slot(<uint64_t>old_keys[j], bits)
            while table[s] >= 0:
                s = (s + 1) & (size - 1)
            table[s] = j
        for t in range(m):
            if base == 0:
                j = -1
            else:
                a = triangles[t, 0]
                b = triangles[t, 1]
                c = triangles[t, 2]
                if a < 0 or a >= npix or b < 0 or b >= npix or c < 0 or c >= npix:
                    bad = True
                    break
                a = pixel[a]
                b = pixel[b]
                c = pixel[c]
                low = a if a < b else b
                low = low if low < c else c
                high = a if a > b else b
                high = high if high > c else c
                k = (low * base + (a + b + c - low - high)) * base + high
                keys[t] = k
                j = -1
                if n_old:
                    s = _slot(<uint64_t>k, bits)
                    while table[s] >= 0 and old_keys[table[s]] != k:
                        s = (s + 1) & (size - 1)
                    j = table[s]
            if j < 0:
                rows[t] = next_row + nf
                fresh[nf] = t
                nf += 1
            else:
                rows[t] = old_rows[j]
                se[t] = old_sse[j]
    if bad:
        raise ValueError("cached: a corner index out of range")
    return keys_out, rows_out, sse_out, fresh_out[:nf]


def triangle_weights(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width,
                     int64_t height, int64_t room=0):
    """(origin M x 2, coef M x 3 x 3, den M), int64, of elements.triangle_raster: each
    triangle's first corner in raster order, the integer coefficients (alpha, beta,
    gamma) of each listed corner's weight numerator relative to it, and their common
    denominator (twice the area). Integers, so the very numbers numpy gave. room: make
    the arrays that many rows long if more than M, the rows after M left for the caller
    (a mesh's border lines, with no copy of the triangles' rows to join them).
    ValueError on an index or coordinate out of range."""
    _check(vertices, triangles, width, height)
    cdef _Mesh geometry = _mesh(vertices, triangles, width, height)
    cdef int64_t m = triangles.shape[0], t, i, j, k, ox, oy
    cdef int64_t rows = room if room > m else m
    origin_out = np.empty((rows, 2), dtype=np.int64)
    coef_out = np.empty((rows, 3, 3), dtype=np.int64)
    den_out = np.empty(rows, dtype=np.int64)
    cdef int64_t[:, ::1] origin = origin_out
    cdef int64_t[:, :, ::1] coef = coef_out
    cdef int64_t[::1] den = den_out
    cdef int64_t px[3]
    cdef int64_t py[3]
    cdef bint bad = False
    with nogil:
        for t in range(m):
            if not _corners(&geometry, t, py, px):
                bad = True
                break
            _origin(px, py, width, &ox, &oy)
            origin[t, 0] = ox
            origin[t, 1] = oy
            for i in range(3):
                # w_i = (xk - xj)(y - yj) - (yk - yj)(x - xj)
                j = (i + 1) % 3
                k = (i + 2) % 3
                coef[t, i, 0] = -(py[k] - py[j])
                coef[t, i, 1] = px[k] - px[j]
                coef[t, i, 2] = (px[k] - px[j]) * (oy - py[j]) - (py[k] - py[j]) * (ox - px[j])
            den[t] = coef[t, 0, 2] + coef[t, 1, 2] + coef[t, 2, 2]
    if bad:
        raise ValueError("triangle_weights: a corner index or coordinate out of range")
    return origin_out, coef_out, den_out


def first_of_each(const int64_t[::1] keys):
    """A mask of the entries of `keys` that are the first of their value (a hash table
    of the keys seen: one pass, where np.unique sorts). For refinement's merge() of a
    round's new vertices into the vertices there are."""
    cdef int64_t n = keys.shape[0], i, s, size
    cdef int bits = 4
    while (<int64_t>1 << bits) < 2 * n:
        bits += 1
    size = <int64_t>1 << bits
    first_out = np.zeros(n, dtype=bool)
    table_arr = np.full(size, -1, dtype=np.int64)
    cdef uint8_t[::1] first = first_out.view(np.uint8)
    cdef int64_t[::1] table = table_arr
    with nogil:
        for i in range(n):
            s = _slot(<uint64_t>keys[i], bits)
            while table[s] >= 0 and keys[table[s]] != keys[i]:
                s = (s + 1) & (size - 1)
            if table[s] < 0:
                table[s] = i
                first[i] = 1
    return first_out


ctypedef fused pixel_t:
    uint8_t
    uint16_t
    float
    double


def outlier_sums(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles, int64_t width, int64_t height,
                 const double[:, ::1] affine, const int64_t[:, ::1] origin, const pixel_t[:, ::1] image,
                 double limit):
    """(count, drop): the pixels of the triangles (walked as triangle_pixels lists them)
    whose value b lies more than `limit` from the mesh f = a (x - ox) + b (y - oy) + c
    of their triangle (affine's and origin's rows, as evaluate sums it), and per
    triangle their sums of 1, u, v, u u, u v, v v, b, u b, v b, b b (u = x - ox,
    v = y - oy), added pixel after pixel as np.bincount adds them: what
    values._planar_refit took from every pixel's (element, x, y) arrays, without them.
    ValueError on an index or coordinate out of range or tables that do not match."""
    _check(vertices, triangles, width, height)
    cdef _Mesh geometry = _mesh(vertices, triangles, width, height)
    cdef int64_t m = triangles.shape[0], t, dy, y, x0, n, x, up, count = 0
    if affine.shape[0] < m or affine.shape[1] != 3 or origin.shape[0] < m or origin.shape[1] != 2:
        raise ValueError("outlier_sums: an affine and an origin per triangle")
    if image.shape[0] != height or image.shape[1] != width:
        raise ValueError("outlier_sums: the image does not match its size")
    drop_a = np.zeros((m, 10), dtype=np.float64)
    cdef double[:, ::1] drop = drop_a
    cdef _Rows rows
    cdef int64_t ys[3]
    cdef int64_t xs[3]
    cdef double a, bb, c, u, v, b, f
    cdef int64_t ox, oy
    cdef bint bad = False
    with nogil:
        for t in range(m):
            if not _start(&geometry, t, ys, xs, &up):
                bad = True
                break
            a = affine[t, 0]
            bb = affine[t, 1]
            c = affine[t, 2]
            ox = origin[t, 0]
            oy = origin[t, 1]
            _rows_start(&rows, ys, xs, up)
            for dy in range(ys[2] - ys[0]):
                _rows_next(&rows, &x0, &n)
                y = ys[0] + dy
                v = <double>(y - oy)
                for x in range(x0, x0 + n):
                    u = <double>(x - ox)
                    f = a * u + bb * v + c
                    b = <double>image[y, x]
                    if fabs(b - f) > limit:
                        count += 1
                        drop[t, 0] += 1.0
                        drop[t, 1] += u
                        drop[t, 2] += v
                        drop[t, 3] += u * u
                        drop[t, 4] += u * v
                        drop[t, 5] += v * v
                        drop[t, 6] += b
                        drop[t, 7] += u * b
                        drop[t, 8] += v * b
                        drop[t, 9] += b * b
    if bad:
        raise ValueError("outlier_sums: a corner index or coordinate out of range")
    return count, drop_a


def line_elements(const int64_t[:, ::1] vertices, int64_t width, int64_t height):
    """(corners, origin, coef, den, span_elem, span_y, span_x, span_n), int64, of the
    border lines' elements (elements.line_raster): the bottom row's pixels 0 .. W-1,
    then (if H > 1) the right column's 0 .. H-2, each line cut into pieces between
    consecutive vertices on it, the last vertex owning its own pixel: a piece from
    vertex a at position p to b at q has corners (a, b, b), origin a, weight
    numerators (q - p - s, s) along the line (s = x - p on the row, y - p on the
    column) and denominator q - p; the row's pieces are one span each, the column's
    one span a pixel. ValueError on a vertex outside the image, two at one border
    pixel, or a line with none."""
    cdef int64_t n = vertices.shape[0], lines = 2 if height > 1 else 1, i, line, axis, fixed, length, p
    cdef int64_t k, e, s, a, b, la, start, count, elements = 0, spans = 0, last
    if vertices.shape[1] != 2:
        raise ValueError("line_elements: vertices must be N x 2")
    if not 0 < width < 2**20 or not 0 < height < 2**20:
        raise ValueError(f"line_elements: image size {width} x {height} out of range")
    for i in range(n):
        if not (0 <= vertices[i, 0] < width and 0 <= vertices[i, 1] < height):
            raise ValueError("line_elements: a vertex outside the image")
    # each line's vertices by position along it (positions are distinct: distinct pixels)
    at_arr = np.full((2, max(width, height)), -1, dtype=np.int64)
    cdef int64_t[:, ::1] at = at_arr
    cdef int64_t on[2]
    cdef bint twice = False
    on[0] = on[1] = 0
    with nogil:
        for i in range(n):
            if vertices[i, 1] == height - 1:
                twice = twice or at[0, vertices[i, 0]] >= 0
                at[0, vertices[i, 0]] = i
                on[0] += 1
            if lines == 2 and vertices[i, 0] == width - 1:
                twice = twice or at[1, vertices[i, 1]] >= 0
                at[1, vertices[i, 1]] = i
                on[1] += 1
    if twice:
        # each would count an element the table cannot hold: rows left unwritten
        raise ValueError("line_elements: two vertices at one border pixel")
    for line in range(lines):
        if on[line] == 0:
            raise ValueError("line_elements: a border line without a vertex (the image corners are vertices)")
        elements += on[line]
        length = width if line == 0 else height - 1
        # the row's pieces are a span each (all start inside it); the column's pixels
        # below its last vertex's row are spans of their own
        spans += on[line] if line == 0 else length
    corners_a = np.empty((elements, 3), dtype=np.int64)
    origin_a = np.empty((elements, 2), dtype=np.int64)
    coef_a = np.zeros((elements, 3, 3), dtype=np.int64)
    den_a = np.empty(elements, dtype=np.int64)
    elem_a = np.empty(spans, dtype=np.int64)
    y_a = np.empty(spans, dtype=np.int64)
    x_a = np.empty(spans, dtype=np.int64)
    n_a = np.empty(spans, dtype=np.int64)
    cdef int64_t[:, ::1] corners = corners_a, origin = origin_a
    cdef int64_t[:, :, ::1] coef = coef_a
    cdef int64_t[::1] den = den_a, span_elem = elem_a, span_y = y_a, span_x = x_a, span_n = n_a
    e = 0
    s = 0
    with nogil:
        for line in range(lines):
            axis = line
            fixed = height - 1 if line == 0 else width - 1
            length = width if line == 0 else height - 1
            a = -1
            for p in range(length + 1 if line == 1 else length):
                b = at[line, p]
                if b < 0:
                    continue
                if a >= 0:
                    la = vertices[b, axis] - vertices[a, axis]
                    _line_piece(corners, origin, coef, den, e, a, b, vertices[a, 0], vertices[a, 1], axis, la)
                    s = _line_spans(span_elem, span_y, span_x, span_n, s, e, axis, fixed, vertices[a, axis], la, length)
                    e += 1
                a = b
            # the last vertex: its own pixel (on the column, the corner the row owns: none)
            _line_piece(corners, origin, coef, den, e, a, a, vertices[a, 0], vertices[a, 1], axis, 0)
            start = vertices[a, axis]
            if start < length:
                s = _line_spans(span_elem, span_y, span_x, span_n, s, e, axis, fixed, start, 1, length)
            e += 1
    return corners_a, origin_a, coef_a, den_a, elem_a[:s], y_a[:s], x_a[:s], n_a[:s]


cdef void _line_piece(int64_t[:, ::1] corners, int64_t[:, ::1] origin, int64_t[:, :, ::1] coef,
                      int64_t[::1] den, int64_t e, int64_t a, int64_t b, int64_t ox, int64_t oy, int64_t axis,
                      int64_t la) noexcept nogil:
    # a piece from a to b (la > 0), or the last vertex alone (a == b, la == 0)
    corners[e, 0] = a
    corners[e, 1] = b
    corners[e, 2] = b
    origin[e, 0] = ox
    origin[e, 1] = oy
    if la > 0:
        coef[e, 0, axis] = -1
        coef[e, 0, 2] = la
        coef[e, 1, axis] = 1
        den[e] = la
    else:
        coef[e, 0, 2] = 1
        den[e] = 1


cdef int64_t _line_spans(int64_t[::1] span_elem, int64_t[::1] span_y, int64_t[::1] span_x, int64_t[::1] span_n,
                         int64_t s, int64_t e, int64_t axis, int64_t fixed, int64_t start, int64_t count,
                         int64_t length) noexcept nogil:
    # the spans of element e: pixels start .. start + count - 1 of its line, cut at length
    cdef int64_t j
    if count > length - start:
        count = length - start
    if axis == 0:
        span_elem[s] = e
        span_y[s] = fixed
        span_x[s] = start
        span_n[s] = count
        return s + 1
    for j in range(count):
        span_elem[s] = e
        span_y[s] = start + j
        span_x[s] = fixed
        span_n[s] = 1
        s += 1
    return s


def gather_rows(list parts, const int64_t[::1] rows, double[:, ::1] out):
    """Set out[i] to row rows[i] of the parts (K-column float64 arrays) stacked one
    after another, for every i: refinement's statistics of its last triangulation from the
    parts measured round by round, in one pass a part instead of a mask and a fancy
    index a part. ValueError on a row beyond the parts or shapes that do not match."""
    cdef int64_t r = rows.shape[0], k = out.shape[1], first = 0, i, j, at
    cdef double[:, ::1] part
    cdef bint bad = False
    if out.shape[0] != r:
        raise ValueError("gather_rows: a row of out per row asked for")
    for i in range(r):
        if rows[i] < 0:
            raise ValueError("gather_rows: a row beyond the parts")
    for p in parts:
        part = p
        if part.shape[1] != k:
            raise ValueError("gather_rows: the parts' columns do not match out's")
        with nogil:
            for i in range(r):
                at = rows[i] - first
                if 0 <= at < part.shape[0]:
                    for j in range(k):
                        out[i, j] = part[at, j]
        first += part.shape[0]
    for i in range(r):
        if rows[i] >= first:
            raise ValueError("gather_rows: a row beyond the parts")


def element_worst_pixels(const int64_t[:, ::1] corners, const int64_t[:, :, ::1] coef, const int64_t[::1] den,
                         const int64_t[:, ::1] origin, const int64_t[::1] bounds, const int64_t[::1] span_y,
                         const int64_t[::1] span_x, const int64_t[::1] span_n, const int64_t[::1] elements,
                         const double[::1] z, const plane_t[:, ::1] plane):
    """Raster.worst_pixels of a raster's `elements` from its arrays (element e's spans
    are bounds[e] .. bounds[e + 1] - 1): per element, its pixel farthest from the plane
    through its corners' values z (Raster.affine's: corner after corner, then / D;
    evaluated as a u, then + b v, then + c), the first of those tied in span order:
    (x, y, |error| (-1 where it owns no pixel)). ValueError on an index out of range."""
    cdef int64_t ne = den.shape[0], ns = span_y.shape[0], k = elements.shape[0], i, j, e, c, x, y, n
    cdef int64_t h = plane.shape[0], w = plane.shape[1], ox, oy
    if (corners.shape[0] != ne or corners.shape[1] != 3 or coef.shape[0] != ne or coef.shape[1] != 3
            or coef.shape[2] != 3 or origin.shape[0] != ne or origin.shape[1] != 2 or bounds.shape[0] != ne + 1
            or span_x.shape[0] != ns or span_n.shape[0] != ns):
        raise ValueError("element_worst_pixels: the raster's arrays do not match")
    for i in range(k):
        e = elements[i]
        if not 0 <= e < ne or not 0 <= bounds[e] <= bounds[e + 1] <= ns:
            raise ValueError("element_worst_pixels: an element or its spans out of range")
        for c in range(3):
            if not 0 <= corners[e, c] < z.shape[0]:
                raise ValueError("element_worst_pixels: a corner out of range")
        for j in range(bounds[e], bounds[e + 1]):
            if span_n[j] > 0 and not (0 <= span_y[j] < h and 0 <= span_x[j] and span_x[j] + span_n[j] <= w):
                raise ValueError("element_worst_pixels: a span outside the plane")
    xs_out, ys_out, err_out = _worst_outputs(k)
    cdef int64_t[::1] bx = xs_out, by = ys_out
    cdef double[::1] be = err_out
    cdef double f[3]
    cdef double row, best
    with nogil:
        for i in range(k):
            e = elements[i]
            for c in range(3):
                f[c] = <double>coef[e, 0, c] * z[corners[e, 0]]
                f[c] = f[c] + <double>coef[e, 1, c] * z[corners[e, 1]]
                f[c] = f[c] + <double>coef[e, 2, c] * z[corners[e, 2]]
                f[c] = f[c] / <double>den[e]
            ox = origin[e, 0]
            oy = origin[e, 1]
            best = -1.0
            for j in range(bounds[e], bounds[e + 1]):
                if span_n[j] <= 0:
                    continue
                y = span_y[j]
                row = f[1] * <double>(y - oy)
                best = _span_worst(&plane[y, 0], y, span_x[j], span_n[j], ox, f[0], row, f[2], best, &bx[i], &by[i])
            be[i] = best
    return xs_out, ys_out, err_out
