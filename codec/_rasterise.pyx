"""The CPU decoder's kernel: exact integer scanline rasterisation of a mesh, with the
GIL released (see codec.decoder_cpu for the rule it implements, ATM.md §5).

Every quantity is an int64 integer: the pixel centres and vertices are integer
points, so a span's ends and a pixel's value are exact fractions, walked from row to
row and pixel to pixel as quotient and remainder (a float64 division, corrected to
the exact floor, per triangle edge and per span; none per pixel). Bounds: with
W*H <= 2**32 and samples below 2**16, every numerator is below 2**53 (see the plane
in _triangles), so the float64 quotients are off by at most one before correction."""

from libc.stdint cimport int64_t, uint8_t, uint16_t

ctypedef fused sample_t:
    uint8_t
    uint16_t

# rasterise()'s status codes; the caller turns them into CorruptError
cpdef enum Status:
    OK = 0
    BAD_VERTEX = 1      # a vertex outside the image (detail: its index)
    BAD_INDEX = 2       # a triangle corner beyond the vertices (detail: the triangle)
    UNCOVERED = 3       # detail: the first pixel (raster order) no triangle writes
    TWICE = 4           # detail: the first pixel written twice or more


cdef inline int64_t _floor_div_fast(int64_t a, int64_t b) noexcept nogil:
    """floor(a / b) for b > 0 and |a| < 2**53: the float64 quotient truncated (no
    integer division, which costs several times more), then corrected to the exact
    floor (the truncation and the rounding are each off by at most one)."""
    cdef int64_t q = <int64_t>(<double>a / <double>b)
    cdef int64_t r = a - q * b
    while r < 0:
        q -= 1
        r += b
    while r >= b:
        q += 1
        r -= b
    return q


cdef struct Walk:
    # a fraction num/den (den > 0) as floor q and remainder r in [0, den), and its
    # step per unit as the same pair
    int64_t q, r, den, dq, dr


cdef inline void _walk_init(Walk* w, int64_t num, int64_t den, int64_t step) noexcept nogil:
    w.den = den
    w.q = _floor_div_fast(num, den)
    w.r = num - w.q * den
    w.dq = _floor_div_fast(step, den)
    w.dr = step - w.dq * den


cdef inline void _walk_step(Walk* w) noexcept nogil:
    cdef int64_t carry
    w.q += w.dq
    w.r += w.dr
    carry = w.r >= w.den  # without a branch: it goes either way from row to row
    w.r -= carry * w.den
    w.q += carry


cdef inline int64_t _ceil(Walk* w) noexcept nogil:
    return w.q + (w.r != 0)


cdef inline void _sort3(int64_t* i, const int64_t[:, ::1] v) noexcept nogil:
    """Order three vertex indices by raster position (row, then column)."""
    cdef int64_t t
    if v[i[1], 1] < v[i[0], 1] or (v[i[1], 1] == v[i[0], 1] and v[i[1], 0] < v[i[0], 0]):
        t = i[0]; i[0] = i[1]; i[1] = t
    if v[i[2], 1] < v[i[1], 1] or (v[i[2], 1] == v[i[1], 1] and v[i[2], 0] < v[i[1], 0]):
        t = i[1]; i[1] = i[2]; i[2] = t
        if v[i[1], 1] < v[i[0], 1] or (v[i[1], 1] == v[i[0], 1] and v[i[1], 0] < v[i[0], 0]):
            t = i[0]; i[0] = i[1]; i[1] = t


cdef int _triangles(const int64_t[:, ::1] v, const int64_t[:, ::1] vals,
                    const int64_t[:, ::1] tris, sample_t[:, ::1] out, uint8_t[::1] cover,
                    int64_t w, int64_t h, int64_t* detail) noexcept nogil:
    """Write every triangle's pixels into `out` and count them in `cover` (capped at
    2); the status code, with `detail` set on an error."""
    cdef int64_t nv = v.shape[0], m = tris.shape[0], c = vals.shape[1]
    cdef int64_t k, ch, y, x, last, lo, hi, row, d, d2, n, q, r
    cdef int64_t tx, ty, mx, my, bx, by, dxm, dym, dxb, dyb, dxl, dyl, vt, vm, vb
    cdef int64_t corner[3]
    # per channel (at most 4): the plane and its step per column as quotient and
    # remainder over 2D
    cdef int64_t ga[4]
    cdef int64_t gb[4]
    cdef int64_t gc[4]
    cdef int64_t qa[4]
    cdef int64_t ra[4]
    cdef int64_t qs[4]
    cdef int64_t rs[4]
    cdef Walk long_edge, short_edge
    cdef bint el, es
    cdef uint8_t seen
    cdef int64_t carry
    cdef sample_t* pixels = &out[0, 0]
    cdef sample_t* p
    for k in range(nv):
        if not (0 <= v[k, 0] < w and 0 <= v[k, 1] < h):
            detail[0] = k
            return BAD_VERTEX
    for k in range(m):
        corner[0] = tris[k, 0]; corner[1] = tris[k, 1]; corner[2] = tris[k, 2]
        if not (0 <= corner[0] < nv and 0 <= corner[1] < nv and 0 <= corner[2] < nv):
            detail[0] = k
            return BAD_INDEX
        _sort3(corner, v)  # T, M, B
        tx = v[corner[0], 0]; ty = v[corner[0], 1]
        mx = v[corner[1], 0]; my = v[corner[1], 1]
        bx = v[corner[2], 0]; by = v[corner[2], 1]
        dxm = mx - tx; dym = my - ty; dxb = bx - tx; dyb = by - ty
        dxl = bx - mx; dyl = by - my
        d = dxm * dyb - dxb * dym
        if d == 0:
            continue  # degenerate: no area, so no pixel (a validated mesh has none)
        # The plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc of each channel, with the
        # weights and D of the corners in the order T, M, B (at T they are (D, 0, 0),
        # which gives gc); |ga| <= 4 H vmax, |gb| <= 4 W vmax, |gc| < 14 W H (vmax + 1):
        # below 2**53. Either orientation: negating the plane and D together leaves a
        # pixel's value floor(plane / 2D) as it is.
        d2 = 2 * d if d > 0 else -2 * d
        for ch in range(c):
            vt = vals[corner[0], ch]; vm = vals[corner[1], ch]; vb = vals[corner[2], ch]
            ga[ch] = 2 * (dyb * vm - dyl * vt - dym * vb)
            gb[ch] = 2 * (dxl * vt - dxb * vm + dxm * vb)
            gc[ch] = (2 * vt + 1) * d - ga[ch] * tx - gb[ch] * ty
            if d < 0:
                ga[ch] = -ga[ch]; gb[ch] = -gb[ch]; gc[ch] = -gc[ch]
            qa[ch] = _floor_div_fast(ga[ch], d2)
            ra[ch] = ga[ch] - qa[ch] * d2
        # Rows ty .. by - 1, and by too on the image's last row. The long edge T -> B
        # (dyb > 0, as the triangle has area); the short one T -> M above M's row (and
        # on it if the bottom is flat), M -> B from there on.
        last = by if by == h - 1 else by - 1
        _walk_init(&long_edge, tx * dyb, dyb, dxb)
        if dym > 0:
            _walk_init(&short_edge, tx * dym, dym, dxm)
        else:
            _walk_init(&short_edge, mx * dyl, dyl, dxl)
        for y in range(ty, last + 1):
            if y == my and dym > 0 and dyl > 0:
                _walk_init(&short_edge, mx * dyl, dyl, dxl)
            # [xl, xr]: the two edges' exact x on this row. Column x is the triangle's
            # if xl <= x < xr, or xl < x = xr = W - 1: from ceil(xl) to ceil(xr) - 1,
            # and W - 1 when one edge is exactly there and the other is not.
            lo = _ceil(&long_edge)
            hi = _ceil(&short_edge)
            el = long_edge.r == 0 and lo == w - 1
            es = short_edge.r == 0 and hi == w - 1
            if hi < lo:
                lo, hi = hi, lo
            if el != es:
                hi = w
            if lo < hi:
                row = y * w
                # the value at (lo, y) of each channel as quotient and remainder over
                # 2D, then stepped along the row without a branch to mispredict; one
                # loop over the span, so that only its exit is hard to predict
                for ch in range(c):
                    n = ga[ch] * lo + gb[ch] * y + gc[ch]
                    qs[ch] = _floor_div_fast(n, d2)
                    rs[ch] = n - qs[ch] * d2
                if c == 1:
                    q = qs[0]
                    r = rs[0]
                    for x in range(row + lo, row + hi):
                        seen = cover[x]
                        cover[x] = seen + 1 if seen < 2 else 2
                        pixels[x] = <sample_t>q
                        q += qa[0]
                        r += ra[0]
                        carry = r >= d2
                        q += carry
                        r -= carry * d2
                else:
                    p = pixels + (row + lo) * c
                    for x in range(row + lo, row + hi):
                        seen = cover[x]
                        cover[x] = seen + 1 if seen < 2 else 2
                        for ch in range(c):
                            p[ch] = <sample_t>qs[ch]
                            qs[ch] += qa[ch]
                            rs[ch] += ra[ch]
                            carry = rs[ch] >= d2
                            qs[ch] += carry
                            rs[ch] -= carry * d2
                        p += c
            _walk_step(&long_edge)
            _walk_step(&short_edge)
    return OK


def rasterise(const int64_t[:, ::1] vertices, const int64_t[:, ::1] values,
              const int64_t[:, ::1] triangles, sample_t[:, ::1] out, uint8_t[::1] cover,
              int64_t width, int64_t height):
    """Rasterise the triangles into `out` (H*W x C, C <= 4), counting each pixel's
    writes in `cover` (H*W zeros on entry). Checks every index it reads: returns
    (status, detail) with status OK or one of the codes above. Releases the GIL."""
    cdef int64_t detail = 0, p, npix = width * height
    cdef int status
    if values.shape[1] > 4 or values.shape[0] != vertices.shape[0] or vertices.shape[1] != 2:
        raise ValueError("rasterise: at most 4 channels, one row of values per vertex")
    if triangles.shape[1] != 3 or out.shape[0] != npix or out.shape[1] != values.shape[1]:
        raise ValueError("rasterise: M x 3 triangles and an H*W x C output")
    if cover.shape[0] != npix:
        raise ValueError("rasterise: one cover count per pixel")
    with nogil:
        status = _triangles(vertices, values, triangles, out, cover, width, height, &detail)
        if status == OK:
            for p in range(npix):
                if cover[p] != 1:
                    status = UNCOVERED if cover[p] == 0 else TWICE
                    detail = p
                    break
    return status, detail
