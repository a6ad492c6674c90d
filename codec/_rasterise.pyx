"""The CPU decoder's kernel: exact integer scanline rasterisation of a mesh, with the
GIL released (see codec.decoder_cpu for the rule it implements, ATM.md §5).

Every quantity is an int64 integer: the pixel centres and vertices are integer
points, so a span's ends and a pixel's value are exact fractions, walked from row to
row and pixel to pixel as quotient and remainder. A division (float64, corrected to
the exact floor) happens only when a triangle or one of its edges starts; rows and
pixels add quotient and remainder steps with a carry. Bounds: with W*H <= 2**32 and
samples below 2**16, every numerator is below 2**53 (see the plane in _triangles), so
the float64 quotients are off by at most one before correction.

Coverage (every pixel written exactly once) is checked per span, not per pixel: row
y's spans [lo, hi) tile 0..W exactly when the multiset of their starts plus W equals
that of their ends plus 0 (then the number of spans over each column, starts up to it
less ends up to it, is one), so each span adds one at lo and takes one at hi of a row
of W + 1 counters, and every row must end as (1, 0, ..., 0, -1). The counters are 16
bits, wrapping: exact for a row of fewer than 2**15 spans (a tiling's row has at most
W), which is counted when there are 2**15 triangles or more (each gives a row one
span at most). Only when the check fails is the image rasterised again counting
each pixel's writes, to name the first pixel uncovered or covered twice."""

from libc.stdint cimport int64_t, uint8_t, uint16_t, uint64_t
from libc.stdlib cimport calloc, free

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
    NO_MEMORY = 5       # the coverage counters could not be allocated


cdef inline int64_t _floor_div_fast(int64_t a, int64_t b) noexcept nogil:
    """floor(a / b) for b > 0 and |a| < 2**53: the float64 quotient truncated (no
    integer division, which costs several times more), then corrected without a
    branch. Division in binary64 is correctly rounded and both integers around the
    true quotient are representable, so the rounded quotient lies between them and
    truncating it gives the floor or one more: one correction suffices."""
    cdef int64_t q = <int64_t>(<double>a / <double>b)
    q -= (a - q * b) < 0
    return q


cdef inline void _edge_step(int64_t den, int64_t step, int64_t* dq, int64_t* dr) noexcept nogil:
    """An edge's step per row, `step` columns over `den` rows, as whole columns dq and
    remainder dr in [0, den)."""
    dq[0] = _floor_div_fast(step, den)
    dr[0] = step - dq[0] * den


cdef inline void _sort3(int64_t* i, const int64_t[:, ::1] v, int64_t w) noexcept nogil:
    """Order three vertex indices by raster position (row, then column): a sorting
    network of conditional moves on their pixel keys, as the order is different from
    triangle to triangle."""
    cdef int64_t a = i[0], b = i[1], c = i[2], t, kt
    cdef int64_t ka = v[a, 1] * w + v[a, 0], kb = v[b, 1] * w + v[b, 0], kc = v[c, 1] * w + v[c, 0]
    cdef bint s
    s = kb < ka
    t = b if s else a; b = a if s else b; a = t
    kt = kb if s else ka; kb = ka if s else kb; ka = kt
    s = kc < kb
    t = c if s else b; c = b if s else c; b = t
    kt = kc if s else kb; kc = kb if s else kc; kb = kt
    s = kb < ka
    t = b if s else a; b = a if s else b; a = t
    i[0] = a; i[1] = b; i[2] = c


cdef struct Plane:
    # one channel's value on the triangle: the numerator ga*x + gb*y + gc over d2 = 2D
    # at the left end of the current row's span as floor q and remainder r, its step
    # per column (qa, ra) and per row along the left edge (qs, rs: one row down and the
    # edge's whole columns dq across; one column more costs (qa, ra) again)
    int64_t q, r, qa, ra, qs, rs, ga, gb


cdef inline void _plane_row_step(Plane* p, int64_t extra, int64_t d2) noexcept nogil:
    """The value one row down the left edge, which moved its whole step plus `extra`
    (0 or 1) columns: two steps below d2 each, so two carries at most."""
    cdef int64_t carry
    p.q += p.qs + extra * p.qa
    p.r += p.rs + extra * p.ra
    carry = p.r >= d2
    p.r -= carry * d2
    p.q += carry
    carry = p.r >= d2
    p.r -= carry * d2
    p.q += carry


cdef inline void _plane_edge(Plane* p, int64_t dq, int64_t d2) noexcept nogil:
    """(qs, rs) for a left edge whose whole step per row is dq columns."""
    cdef int64_t n = p.gb + p.ga * dq
    p.qs = _floor_div_fast(n, d2)
    p.rs = n - p.qs * d2


cdef int _triangles(const int64_t[:, ::1] v, const int64_t[:, ::1] vals,
                    const int64_t[:, ::1] tris, sample_t* pixels, uint16_t* counts,
                    int64_t* spans, uint8_t* cover, int64_t w, int64_t h) noexcept nogil:
    """Write every triangle's pixels into `pixels` and account for its spans: in
    `counts` (a row of W + 1 counters per image row, see the module's docstring) and
    `spans` (non-empty spans per row), or, when `cover` is given instead, by counting
    each pixel's writes (capped at 2). Vertices and corners are checked by the
    caller. The walks are plain locals: a sample store may alias any memory, and
    through a pointer they would be reloaded after each one."""
    cdef int64_t m = tris.shape[0], c = vals.shape[1]
    cdef int64_t k, ch, y, x, last, lo, hi, d, d2, half, q, r, carry, stop, extra, qa, ra, row
    cdef int64_t tx, ty, mx, my, bx, by, dxm, dym, dxb, dyb, dxl, dyl, vt, vm, vb
    # the left and right edges' x on the current row as floor and remainder over their
    # rows (den), and their steps per row the same way
    cdef int64_t lq, lr, lden, ldq, ldr, rq, rr, rden, rdq, rdr
    cdef int64_t corner[3]
    cdef Plane pl[4]   # per channel (at most 4)
    cdef bint long_left, turns
    cdef uint8_t seen
    cdef int64_t stride = w + 1
    cdef sample_t* p
    for k in range(m):
        corner[0] = tris[k, 0]; corner[1] = tris[k, 1]; corner[2] = tris[k, 2]
        _sort3(corner, v, w)  # T, M, B
        tx = v[corner[0], 0]; ty = v[corner[0], 1]
        mx = v[corner[1], 0]; my = v[corner[1], 1]
        bx = v[corner[2], 0]; by = v[corner[2], 1]
        dxm = mx - tx; dym = my - ty; dxb = bx - tx; dyb = by - ty
        dxl = bx - mx; dyl = by - my
        d = dxm * dyb - dxb * dym
        if d == 0:
            continue  # degenerate: no area, so no pixel (a validated mesh has none)
        # The plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc of each channel, with the
        # weights and D of the corners in the order T, M, B; |ga| <= 4 H vmax,
        # |gb| <= 4 W vmax, |gc| < 14 W H (vmax + 1): below 2**53. Either orientation:
        # negating the plane and D together leaves a pixel's value floor(plane / 2D)
        # as it is. At a corner the plane is (2 v + 1) D: quotient v, remainder D.
        half = d if d > 0 else -d
        d2 = 2 * half
        for ch in range(c):
            vt = vals[corner[0], ch]; vm = vals[corner[1], ch]; vb = vals[corner[2], ch]
            pl[ch].ga = 2 * (dyb * vm - dyl * vt - dym * vb)
            pl[ch].gb = 2 * (dxl * vt - dxb * vm + dxm * vb)
            if d < 0:
                pl[ch].ga = -pl[ch].ga; pl[ch].gb = -pl[ch].gb
            pl[ch].qa = _floor_div_fast(pl[ch].ga, d2)
            pl[ch].ra = pl[ch].ga - pl[ch].qa * d2
            pl[ch].q = vt
            pl[ch].r = half
        # Rows ty .. by - 1, and by too on the image's last row. The long edge T -> B
        # (dyb > 0, as the triangle has area); the short one T -> M above M's row (and
        # on it if the bottom is flat), M -> B from there on. M lies right of the long
        # edge when d > 0: the long edge is then the left one on every row, else the
        # short one. The span starts at the left edge, where the value is walked.
        last = by if by == h - 1 else by - 1
        long_left = d > 0
        turns = dym > 0 and dyl > 0
        if long_left:
            lq = tx; lr = 0; lden = dyb
            _edge_step(dyb, dxb, &ldq, &ldr)
            rq = tx if dym > 0 else mx
            rr = 0
            rden = dym if dym > 0 else dyl
            _edge_step(rden, dxm if dym > 0 else dxl, &rdq, &rdr)
        else:  # then dym > 0: a flat top has M right of T
            lq = tx; lr = 0; lden = dym
            _edge_step(dym, dxm, &ldq, &ldr)
            rq = tx; rr = 0; rden = dyb
            _edge_step(dyb, dxb, &rdq, &rdr)
        for ch in range(c):
            _plane_edge(&pl[ch], ldq, d2)
        y = ty
        # at most two runs of rows: above M's row, then from it (the short edge turns
        # at M unless the bottom is flat)
        while y <= last:
            if y == my and turns:
                if long_left:
                    rq = mx; rr = 0; rden = dyl
                    _edge_step(dyl, dxl, &rdq, &rdr)
                else:
                    lq = mx; lr = 0; lden = dyl
                    _edge_step(dyl, dxl, &ldq, &ldr)
                    for ch in range(c):
                        pl[ch].q = vals[corner[1], ch]
                        pl[ch].r = half
                        _plane_edge(&pl[ch], ldq, d2)
            stop = my if (y < my and turns) else last + 1
            while y < stop:
                # [xl, xr]: the two edges' exact x on this row. Column x is the
                # triangle's if xl <= x < xr, or xl < x = xr = W - 1: from ceil(xl)
                # to ceil(xr) - 1, and W - 1 when the right edge is exactly there and
                # the left one is not.
                lo = lq + (lr != 0)
                hi = rq + (rr != 0)
                hi += (rr == 0) & (hi == w - 1) & ((lr != 0) | (lo != w - 1))
                if lo < hi:
                    row = y * w
                    if c == 1:
                        q = pl[0].q
                        r = pl[0].r
                        qa = pl[0].qa
                        ra = pl[0].ra
                        p = pixels + row
                        # stepped along the row without a branch to mispredict
                        for x in range(lo, hi):
                            p[x] = <sample_t>q
                            # a conditional move, not a multiply, on the carry chain
                            q += qa
                            r += ra - d2
                            q += r >= 0
                            r = r if r >= 0 else r + d2
                    else:
                        p = pixels + (row + lo) * c
                        for ch in range(c):
                            q = pl[ch].q
                            r = pl[ch].r
                            qa = pl[ch].qa
                            ra = pl[ch].ra
                            for x in range(hi - lo):
                                p[x * c + ch] = <sample_t>q
                                q += qa
                                r += ra - d2
                                q += r >= 0
                                r = r if r >= 0 else r + d2
                    if cover == NULL:
                        counts[y * stride + lo] += 1
                        counts[y * stride + hi] -= 1
                        if spans != NULL:
                            spans[y] += 1
                    else:
                        for x in range(row + lo, row + hi):
                            seen = cover[x]
                            cover[x] = seen + 1 if seen < 2 else 2
                # one row down: each edge's x by its step, with a carry
                lq += ldq
                lr += ldr
                carry = lr >= lden
                lr -= carry * lden
                lq += carry
                rq += rdq
                rr += rdr
                carry = rr >= rden
                rr -= carry * rden
                rq += carry
                # the left end moved its edge's whole step, or one column more
                extra = lq + (lr != 0) - lo - ldq
                for ch in range(c):
                    _plane_row_step(&pl[ch], extra, d2)
                y += 1
    return OK


cdef int _check_counts(const uint16_t* counts, const int64_t* spans, int64_t w, int64_t h) noexcept nogil:
    """Whether every row's counters are (1, 0, ..., 0, -1) and exact: its spans
    tile it."""
    cdef int64_t y, x, stride = w + 1
    cdef uint16_t acc
    cdef const uint16_t* row
    for y in range(h):
        if spans != NULL and spans[y] >= 1 << 15:
            return 0
        row = counts + y * stride
        acc = (row[0] ^ 1) | (row[w] ^ 0xFFFF)
        for x in range(1, w):
            acc |= row[x]
        if acc:
            return 0
    return 1


cdef int _render(const int64_t[:, ::1] v, const int64_t[:, ::1] vals, const int64_t[:, ::1] tris,
                 sample_t* pixels, int64_t w, int64_t h, int64_t* detail) noexcept nogil:
    """Check the indices, rasterise, check the coverage; the status code, with
    `detail` set on an error."""
    cdef int64_t nv = v.shape[0], m = tris.shape[0], k, p, npix = w * h
    cdef uint16_t* counts
    cdef int64_t* spans
    cdef uint8_t* cover
    cdef int status = OK
    for k in range(nv):
        if not (0 <= v[k, 0] < w and 0 <= v[k, 1] < h):
            detail[0] = k
            return BAD_VERTEX
    for k in range(m):
        # unsigned: a negative index is beyond too
        if (<uint64_t>tris[k, 0] >= <uint64_t>nv) | (<uint64_t>tris[k, 1] >= <uint64_t>nv) | (<uint64_t>tris[k, 2] >= <uint64_t>nv):
            detail[0] = k
            return BAD_INDEX
    counts = <uint16_t*>calloc(<size_t>((w + 1) * h), sizeof(uint16_t))
    # a triangle gives a row one span at most: with fewer than 2**15 triangles no row
    # can have more spans, and they need no count
    spans = <int64_t*>calloc(<size_t>h, sizeof(int64_t)) if m >= 1 << 15 else NULL
    if counts == NULL or (spans == NULL and m >= 1 << 15):
        free(counts)
        free(spans)
        return NO_MEMORY
    _triangles(v, vals, tris, pixels, counts, spans, NULL, w, h)
    status = _check_counts(counts, spans, w, h)
    free(counts)
    free(spans)
    if status:
        return OK
    # not a tiling: again, counting every pixel's writes, to name the first bad one
    cover = <uint8_t*>calloc(<size_t>npix, 1)
    if cover == NULL:
        return NO_MEMORY
    _triangles(v, vals, tris, pixels, NULL, NULL, cover, w, h)
    status = OK
    for p in range(npix):
        if cover[p] != 1:
            status = UNCOVERED if cover[p] == 0 else TWICE
            detail[0] = p
            break
    free(cover)
    return status


def rasterise(const int64_t[:, ::1] vertices, const int64_t[:, ::1] values,
              const int64_t[:, ::1] triangles, sample_t[:, ::1] out,
              int64_t width, int64_t height):
    """Rasterise the triangles into `out` (H*W x C, C <= 4), checking that every pixel
    is written exactly once. Checks every index it reads: returns (status, detail)
    with status OK or one of the codes above. Releases the GIL."""
    cdef int64_t detail = 0
    cdef int status
    if values.shape[1] > 4 or values.shape[1] < 1 or values.shape[0] != vertices.shape[0] or vertices.shape[1] != 2:
        raise ValueError("rasterise: 1 to 4 channels, one row of values per vertex")
    if triangles.shape[1] != 3 or out.shape[0] != width * height or out.shape[1] != values.shape[1]:
        raise ValueError("rasterise: M x 3 triangles and an H*W x C output")
    if width < 1 or height < 1:
        raise ValueError("rasterise: an image of at least one pixel")
    with nogil:
        status = _render(vertices, values, triangles, &out[0, 0], width, height, &detail)
    if status == NO_MEMORY:
        raise MemoryError(f"rasterise: no memory for the coverage counters of a {width}x{height} image")
    return status, detail
