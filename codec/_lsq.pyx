"""Encoder kernel: the least-squares normal equations of triangles, summed over the
pixels each one owns, for refitting vertex values after refinement changed a part of
the mesh (codec.mesher.values.refit). Small triangles own a few pixels each, so one
pass over their pixels costs less than the numpy route (row spans, prefix-sum look-ups
per span, per-element reductions and the 3 x 3 products), which took most of a
max_error encode. The GIL is released while it works."""

from libc.math cimport sqrt
from libc.stdint cimport int64_t, uint8_t, uint16_t

from codec.planefit cimport plane_sse

import numpy as np

ctypedef fused sample_t:
    uint8_t
    uint16_t
    double


cdef inline int64_t ceil_div(int64_t num, int64_t den) noexcept nogil:
    """ceil(num / den) for den > 0, exactly (C division truncates towards zero)."""
    cdef int64_t q = num // den
    if num % den != 0 and num > 0:
        q += 1
    return q


def triangle_normals(const int64_t[:, ::1] vertices, const int64_t[:, ::1] triangles,
                     const sample_t[:, :, ::1] image, const int64_t[::1] number=None,
                     const double[:, ::1] known=None, int64_t spare=0):
    """Per triangle, its part of A^T W A (M x 3 x 3, corner by corner, as listed) and of
    A^T W b (M x C x 3), where a pixel's row of A holds its corners' weights
    w_i = (alpha_i u + beta_i v + gamma_i) / D of the decoder (ATM.md, "Decoding"), u and
    v relative to the triangle's first corner in raster order: what
    values.normal_equations gives from elements.Statistics of elements.triangle_raster,
    over the same pixels (those of [0, W-1) x [0, H-1) the triangle owns, left and top
    edges inclusive), here summed pixel by pixel. image: H x W x C (uint8, uint16 or
    float64).

    With `number` (per vertex: its unknown's number, or -1 if held) and `known` (N x C,
    the held vertices' values), only the triangles with a free corner are summed (the
    rows of the results are theirs, in order), and the held corners are eliminated as
    values.refit needs: their part of the equations moves to the right-hand side, their
    rows and columns of the element matrix are zeroed, and a third result gives the
    corners in the unknowns' numbering, held ones pointing at a sink numbered after the
    largest.

    spare: rows of zeros left at the end of every result, for the caller's own elements
    (refit's border lines), so that adding them copies nothing.

    ValueError if a corner index or a vertex lies outside the arrays or the image, or a
    triangle is not counter-clockwise in raster coordinates (D <= 0)."""
    cdef int64_t m = triangles.shape[0], n = vertices.shape[0]
    cdef int64_t height = image.shape[0], width = image.shape[1], channels = image.shape[2]
    if vertices.shape[1] != 2 or triangles.shape[1] != 3:
        raise ValueError("triangle_normals: vertices N x 2 and triangles M x 3")
    cdef bint eliminate = number is not None
    cdef int64_t sink = -1
    if eliminate:
        if known is None or number.shape[0] != n or known.shape[0] != n or known.shape[1] != image.shape[2]:
            raise ValueError("triangle_normals: number (N) and known (N x C) go together")
        sink = max(np.max(number) if n else -1, -1) + 1
    cdef int64_t t, i, j, k, l, ch, dy, x, y, left, right, rows, up, upper, lower, tall
    # the triangles to sum: all, or (eliminating) those with a free corner
    keep_array = np.arange(m, dtype=np.int64)
    cdef int64_t[::1] keep = keep_array
    cdef int64_t count = m, o, a
    if eliminate:
        count = 0
        with nogil:
            for t in range(m):
                for i in range(3):
                    a = triangles[t, i]
                    if a < 0 or a >= n:
                        count = -1
                        break
                    if number[a] >= 0:
                        keep[count] = t
                        count += 1
                        break
                if count < 0:
                    break
        if count < 0:
            raise ValueError("triangle_normals: a corner index beyond the vertices")
    if spare < 0:
        raise ValueError("triangle_normals: spare must be >= 0")
    numbered_array = np.zeros((count + spare if eliminate else 0, 3), dtype=np.int64)
    cdef int64_t[:, ::1] numbered = numbered_array
    cdef double corr
    gram_array = np.zeros((count + spare, 3, 3), dtype=np.float64)
    rhs_array = np.zeros((count + spare, channels, 3), dtype=np.float64)
    sums_array = np.zeros((channels, 3), dtype=np.float64)
    cdef double[:, :, ::1] gram = gram_array
    cdef double[:, :, ::1] rhs = rhs_array
    cdef double[:, ::1] s = sums_array  # per channel: b, u b, v b
    cdef int64_t px[3]
    cdef int64_t py[3]
    cdef int64_t coef[3][3]
    cdef int64_t xa, xb, xc, ya, yb, yc, r, sx, sl, sd, cl, cs, ox, oy, den
    cdef double mom[6]  # 1, u, v, uu, uv, vv
    cdef double mat[3][3]  # rows and columns (u, v, 1): sum of p p^T
    cdef double cm[3][3]
    cdef double su, suu, sb, sub, u, v, b, dd
    cdef int status = 0
    with nogil:
        for o in range(count):
            t = keep[o]
            for i in range(3):
                j = triangles[t, i]
                if j < 0 or j >= n:
                    status = 1
                    break
                px[i] = vertices[j, 0]
                py[i] = vertices[j, 1]
                if px[i] < 0 or px[i] >= width or py[i] < 0 or py[i] >= height:
                    status = 2
                    break
            if status:
                break
            # the origin: the first corner in raster order
            k = 0
            for i in range(1, 3):
                if py[i] < py[k] or (py[i] == py[k] and px[i] < px[k]):
                    k = i
            ox = px[k]
            oy = py[k]
            den = 0
            for i in range(3):
                j = (i + 1) % 3
                l = (i + 2) % 3
                # w_i = (xl - xj)(y - yj) - (yl - yj)(x - xj), x = u + ox, y = v + oy
                coef[i][0] = -(py[l] - py[j])
                coef[i][1] = px[l] - px[j]
                coef[i][2] = (px[l] - px[j]) * (oy - py[j]) - (py[l] - py[j]) * (ox - px[j])
                den += coef[i][2]
            if den <= 0:
                status = 3
                break
            # the corners by row, as elements._sort3 orders them (its compare-and-swap
            # network, so that ties in y resolve alike)
            ya = py[0]; yb = py[1]; yc = py[2]
            xa = px[0]; xb = px[1]; xc = px[2]
            if yb < ya:
                r = ya; ya = yb; yb = r
                r = xa; xa = xb; xb = r
            if yc < yb:
                r = yb; yb = yc; yc = r
                r = xb; xb = xc; xc = r
            if yb < ya:
                r = ya; ya = yb; yb = r
                r = xa; xa = xb; xb = r
            tall = yc - ya
            upper = yb - ya
            lower = yc - yb
            rows = tall  # the bottom row is never owned: half-open in y
            up = min(upper + 1, tall)
            for i in range(6):
                mom[i] = 0.0
            for ch in range(channels):
                s[ch, 0] = 0.0
                s[ch, 1] = 0.0
                s[ch, 2] = 0.0
            for dy in range(rows):
                # the row's span lies between the long edge (top to bottom corner) and
                # the upper or lower short edge (elements._triangle_spans)
                if dy < up:
                    if upper == 0:
                        sx = xb; sl = 0; sd = 1
                    else:
                        sx = xa * upper; sl = xb - xa; sd = upper
                else:
                    sd = max(lower, 1)
                    sx = xb * sd - (xc - xb) * upper
                    sl = xc - xb
                cl = ceil_div(xa * tall + (xc - xa) * dy, tall)
                cs = ceil_div(sx + sl * dy, sd)
                left = min(cl, cs)
                right = max(cl, cs)
                if right <= left:
                    continue
                y = ya + dy
                v = <double>(y - oy)
                su = 0.0
                suu = 0.0
                for x in range(left, right):
                    u = <double>(x - ox)
                    su += u
                    suu += u * u
                mom[0] += <double>(right - left)
                mom[1] += su
                mom[2] += v * (right - left)
                mom[3] += suu
                mom[4] += v * su
                mom[5] += v * v * (right - left)
                for ch in range(channels):
                    sb = 0.0
                    sub = 0.0
                    for x in range(left, right):
                        b = <double>image[y, x, ch]
                        sb += b
                        sub += (x - ox) * b
                    s[ch, 0] += sb
                    s[ch, 1] += sub
                    s[ch, 2] += v * sb
            # gram = C M C^T / D^2, C's rows the corners' (alpha, beta, gamma)
            mat[0][0] = mom[3]; mat[0][1] = mom[4]; mat[0][2] = mom[1]
            mat[1][0] = mom[4]; mat[1][1] = mom[5]; mat[1][2] = mom[2]
            mat[2][0] = mom[1]; mat[2][1] = mom[2]; mat[2][2] = mom[0]
            for i in range(3):
                for l in range(3):
                    cm[i][l] = coef[i][0] * mat[0][l] + coef[i][1] * mat[1][l] + coef[i][2] * mat[2][l]
            dd = <double>den
            for i in range(3):
                for j in range(i, 3):
                    b = (cm[i][0] * coef[j][0] + cm[i][1] * coef[j][1] + cm[i][2] * coef[j][2]) / (dd * dd)
                    gram[o, i, j] = b
                    gram[o, j, i] = b
            for ch in range(channels):
                for i in range(3):
                    rhs[o, ch, i] = (coef[i][0] * s[ch, 1] + coef[i][1] * s[ch, 2] + coef[i][2] * s[ch, 0]) / dd
            if eliminate:
                for ch in range(channels):
                    for i in range(3):
                        corr = 0.0
                        for j in range(3):
                            if number[triangles[t, j]] < 0:
                                corr = corr + gram[o, i, j] * known[triangles[t, j], ch]
                        rhs[o, ch, i] -= corr
                for i in range(3):
                    numbered[o, i] = number[triangles[t, i]]
                    if numbered[o, i] < 0:
                        numbered[o, i] = sink
                        for j in range(3):
                            gram[o, i, j] = 0.0
                            gram[o, j, i] = 0.0
    if status == 1:
        raise ValueError("triangle_normals: a corner index beyond the vertices")
    if status == 2:
        raise ValueError("triangle_normals: a vertex outside the image")
    if status == 3:
        raise ValueError("triangle_normals: a triangle that is not counter-clockwise (area <= 0)")
    if eliminate:
        return gram_array, rhs_array, numbered_array
    return gram_array, rhs_array


def conjugate_gradients(const int64_t[:, ::1] corners, const double[:, :, ::1] gram,
                        const double[:, :, ::1] rhs, const double[:, ::1] start,
                        const double[::1] ridge, const double[:, ::1] anchor,
                        double rtol, int64_t max_iter):
    """x (N x C) minimising, per channel, the sum over elements of the squared error plus
    ridge_k |x_k - anchor_k|^2: (A^T W A + diag(ridge)) x = A^T W b + ridge anchor, by
    conjugate gradients with a diagonal preconditioner from `start`, matrix-free
    element by element (corners E x 3 into 0..N-1, gram E x 3 x 3, rhs E x C x 3), until
    the residual is below rtol times the right-hand side or after max_iter steps: the
    iteration values.solve describes. ValueError if a corner is out of range."""
    cdef int64_t m = corners.shape[0], n = start.shape[0], channels = start.shape[1]
    cdef int64_t e, i, k, ch, it
    if (corners.shape[1] != 3 or gram.shape[0] != m or rhs.shape[0] != m or rhs.shape[1] != channels
            or ridge.shape[0] != n or anchor.shape[0] != n or anchor.shape[1] != channels):
        raise ValueError("conjugate_gradients: the arrays' shapes do not match")
    for e in range(m):
        for i in range(3):
            if corners[e, i] < 0 or corners[e, i] >= n:
                raise ValueError("conjugate_gradients: a corner out of range")
    out_array = np.empty((n, channels), dtype=np.float64)
    work = np.zeros((6, n), dtype=np.float64)
    cdef double[:, ::1] out = out_array
    cdef double[::1] b = work[0], r = work[1], z = work[2], p = work[3], q = work[4], diag = work[5]
    cdef double rz, previous, pq, alpha, norm_b, norm_r, limit, y
    with nogil:
        for k in range(n):
            diag[k] = ridge[k]
        for e in range(m):
            for i in range(3):
                diag[corners[e, i]] += gram[e, i, i]
        for ch in range(channels):
            for k in range(n):
                b[k] = ridge[k] * anchor[k, ch]
                out[k, ch] = start[k, ch]
            for e in range(m):
                for i in range(3):
                    b[corners[e, i]] += rhs[e, ch, i]
            _apply(corners, gram, ridge, out, ch, q)
            norm_b = 0.0
            rz = 0.0
            for k in range(n):
                r[k] = b[k] - q[k]
                norm_b += b[k] * b[k]
                z[k] = r[k] / diag[k]
                p[k] = z[k]
                rz += r[k] * z[k]
            limit = rtol * sqrt(norm_b)
            for it in range(max_iter):
                norm_r = 0.0
                for k in range(n):
                    norm_r += r[k] * r[k]
                if sqrt(norm_r) <= limit:
                    break
                _apply_vector(corners, gram, ridge, p, q)
                pq = 0.0
                for k in range(n):
                    pq += p[k] * q[k]
                alpha = rz / pq
                previous = rz
                rz = 0.0
                for k in range(n):
                    out[k, ch] += alpha * p[k]
                    r[k] -= alpha * q[k]
                    z[k] = r[k] / diag[k]
                    rz += r[k] * z[k]
                for k in range(n):
                    p[k] = z[k] + (rz / previous) * p[k]
    return out_array


cdef void _apply(const int64_t[:, ::1] corners, const double[:, :, ::1] gram, const double[::1] ridge,
                 const double[:, ::1] x, int64_t ch, double[::1] y) noexcept nogil:
    """y = (A^T W A + diag(ridge)) x[:, ch]."""
    cdef int64_t e, i, k, n = y.shape[0]
    cdef double x0, x1, x2
    for k in range(n):
        y[k] = ridge[k] * x[k, ch]
    for e in range(corners.shape[0]):
        x0 = x[corners[e, 0], ch]
        x1 = x[corners[e, 1], ch]
        x2 = x[corners[e, 2], ch]
        for i in range(3):
            y[corners[e, i]] += gram[e, i, 0] * x0 + gram[e, i, 1] * x1 + gram[e, i, 2] * x2


cdef void _apply_vector(const int64_t[:, ::1] corners, const double[:, :, ::1] gram, const double[::1] ridge,
                        const double[::1] x, double[::1] y) noexcept nogil:
    """y = (A^T W A + diag(ridge)) x."""
    cdef int64_t e, i, k, n = y.shape[0]
    cdef double x0, x1, x2
    for k in range(n):
        y[k] = ridge[k] * x[k]
    for e in range(corners.shape[0]):
        x0 = x[corners[e, 0]]
        x1 = x[corners[e, 1]]
        x2 = x[corners[e, 2]]
        for i in range(3):
            y[corners[e, i]] += gram[e, i, 0] * x0 + gram[e, i, 1] * x1 + gram[e, i, 2] * x2


def element_normals(const int64_t[:, :, :] coef, const int64_t[:] den, const double[:, :] moments,
                    const double[:, :, :] image_sums):
    """values.normal_equations from its elements' weighted moments: per element e,
    gram[e] = C M C^T / D^2 (3 x 3, corner by corner; C's rows the corners' (alpha, beta,
    gamma) = coef[e], M the sums of p p^T over its pixels, p = (u, v, 1), from
    moments[e] = (1, u, v, uu, uv, vv)) and rhs[e, c] = C (ub, vb, b) / D for every
    channel c of image_sums[e, c] = (b, ub, vb). The float64 operations of the numpy
    code it replaces, in its order (each sum from 0 as Python's sum() starts, so the
    same numbers), in one pass instead of some fifty over the elements. ValueError if
    the shapes disagree."""
    cdef Py_ssize_t m = den.shape[0], ch = image_sums.shape[1], e, i, j, k, l, c
    if (coef.shape[0] != m or coef.shape[1] != 3 or coef.shape[2] != 3 or moments.shape[0] != m
            or moments.shape[1] < 6 or image_sums.shape[0] != m or image_sums.shape[2] < 3):
        raise ValueError("element_normals: E x 3 x 3 coef, E den, E x 6 moments, E x C x 3 sums")
    gram_out = np.empty((m, 3, 3), dtype=np.float64)
    rhs_out = np.empty((m, ch, 3), dtype=np.float64)
    cdef double[:, :, ::1] gram = gram_out
    cdef double[:, :, ::1] rhs = rhs_out
    cdef double cf[3][3]
    cdef double mm[3][3]
    cdef double cm[3][3]
    cdef double d, dd, g
    with nogil:
        for e in range(m):
            for i in range(3):
                for k in range(3):
                    cf[i][k] = <double>coef[e, i, k]
            d = <double>den[e]
            # rows ((uu, uv, u), (uv, vv, v), (u, v, 1))
            mm[0][0] = moments[e, 3]; mm[0][1] = moments[e, 4]; mm[0][2] = moments[e, 1]
            mm[1][0] = moments[e, 4]; mm[1][1] = moments[e, 5]; mm[1][2] = moments[e, 2]
            mm[2][0] = moments[e, 1]; mm[2][1] = moments[e, 2]; mm[2][2] = moments[e, 0]
            for i in range(3):
                for l in range(3):
                    g = 0.0 + cf[i][0] * mm[0][l]
                    g = g + cf[i][1] * mm[1][l]
                    cm[i][l] = g + cf[i][2] * mm[2][l]
            dd = d * d
            for i in range(3):
                for j in range(i, 3):
                    g = 0.0 + cm[i][0] * cf[j][0]
                    g = g + cm[i][1] * cf[j][1]
                    g = (g + cm[i][2] * cf[j][2]) / dd
                    gram[e, i, j] = g
                    gram[e, j, i] = g
            for c in range(ch):
                for i in range(3):
                    rhs[e, c, i] = (cf[i][0] * image_sums[e, c, 1] + cf[i][1] * image_sums[e, c, 2]
                                    + cf[i][2] * image_sums[e, c, 0]) / d
    return gram_out, rhs_out


def plane_errors(const int64_t[:, ::1] corners, const int64_t[:, :, :] coef, const int64_t[:] den,
                 const double[::1] z, const double[:, :] moments, const double[:, :] sums):
    """elements.element_sse: per element, the squared error of the mesh through z (a
    value per vertex) against the image over its pixels, from its moments (1, u, v, uu,
    uv, vv) and image sums (b, ub, vb, bb). The plane as elements.Raster.affine makes
    it (corner after corner, then / D) and its squared error as
    elements.squared_error (codec/planefit.pxd): numpy's float64 operations in their
    order, so the same numbers, without its twenty-odd temporaries over the elements.
    ValueError if the shapes disagree or a corner is out of range."""
    cdef Py_ssize_t m = den.shape[0], n = z.shape[0], e, k
    if (corners.shape[0] != m or corners.shape[1] != 3 or coef.shape[0] != m or coef.shape[1] != 3
            or coef.shape[2] != 3 or moments.shape[0] != m or moments.shape[1] < 6 or sums.shape[0] != m
            or sums.shape[1] < 4):
        raise ValueError("plane_errors: E x 3 corners and coef, E den, E x 6 moments, E x 4 sums")
    for e in range(m):
        for k in range(3):
            if not 0 <= corners[e, k] < n:
                raise ValueError("plane_errors: a corner out of range")
    out_a = np.empty(m, dtype=np.float64)
    cdef double[::1] out = out_a
    cdef double f[3]
    with nogil:
        for e in range(m):
            for k in range(3):
                f[k] = <double>coef[e, 0, k] * z[corners[e, 0]]
                f[k] = f[k] + <double>coef[e, 1, k] * z[corners[e, 1]]
                f[k] = f[k] + <double>coef[e, 2, k] * z[corners[e, 2]]
                f[k] = f[k] / <double>den[e]
            out[e] = plane_sse(f[0], f[1], f[2], moments[e, 0], moments[e, 1], moments[e, 2], moments[e, 3],
                               moments[e, 4], moments[e, 5], sums[e, 0], sums[e, 1], sums[e, 2], sums[e, 3])
    return out_a
