"""Encoder kernel: the per-pixel arithmetic the adaptive mesher does on OpenCV's
derivatives, in one pass each instead of a numpy temporary per operation (a 512²
image's float32 planes are a megabyte each): the gradient magnitude and Canny's
fixed-point derivatives (codec.mesher.edges), the norm of the Hessian
(codec.mesher.sampling), and the region samples' inverse-CDF walk over the tiles
(codec.mesher.sampling.sample). Each gives the very numbers numpy gave (the same
operations in the same order, without contraction). The GIL is released while they
work."""

from libc.math cimport rintf, sqrt, sqrtf
from libc.stdint cimport int16_t, int64_t, uint8_t

import numpy as np


cdef extern from *:
    """
    /* edge_gradient's pass in blocks: each block's inputs are read into local arrays
       before its outputs are written, so the compiler may vectorise the arithmetic
       (the planes may alias: the magnitude may go into sx's own plane, and on
       pointers it could not tell, which left every pixel scalar: 2 ns a pixel) */
    #define ATM_GRADIENT_BLOCK 256
    static void atm_edge_gradient(const float* a, const float* b, float* mag, int16_t* ix,
                                  int16_t* iy, Py_ssize_t n, float limit, float scale) {
        float m[ATM_GRADIENT_BLOCK];
        int32_t qx[ATM_GRADIENT_BLOCK], qy[ATM_GRADIENT_BLOCK];
        const float lo = -limit, quarter = 0.25f, shift = 12582912.0f;
        for (Py_ssize_t i0 = 0; i0 < n; i0 += ATM_GRADIENT_BLOCK) {
            int len = n - i0 < ATM_GRADIENT_BLOCK ? (int)(n - i0) : ATM_GRADIENT_BLOCK;
            for (int j = 0; j < len; j++) {
                /* times 1/4 is sx / 4 exactly (a power of two) */
                float dx = a[i0 + j] * quarter, dy = b[i0 + j] * quarter;
                m[j] = sqrtf(dx * dx + dy * dy);
                /* np.clip: NaN stays NaN (and would not fit int16 anyway) */
                dx = dx < lo ? lo : (dx > limit ? limit : dx);
                dy = dy < lo ? lo : (dy > limit ? limit : dy);
                /* round half to even by adding and taking away 1.5 * 2^23 (exact below
                   2^22, and |dx scale| <= 32767): rintf is a library call */
                qx[j] = (int32_t)((dx * scale + shift) - shift);
                qy[j] = (int32_t)((dy * scale + shift) - shift);
            }
            for (int j = 0; j < len; j++) {
                mag[i0 + j] = m[j];
                ix[i0 + j] = (int16_t)qx[j];
                iy[i0 + j] = (int16_t)qy[j];
            }
        }
    }
    """
    void atm_edge_gradient(const float* a, const float* b, float* mag, int16_t* ix, int16_t* iy,
                           Py_ssize_t n, float limit, float scale) noexcept nogil


def edge_gradient(const float[:, ::1] sx, const float[:, ::1] sy, float limit, float scale, out=None,
                  ix_out=None, iy_out=None):
    """(magnitude, ix, iy) of Sobel derivatives sx, sy (H x W float32): dx = sx / 4,
    dy = sy / 4, magnitude = sqrt(dx dx + dy dy) (float32), and ix, iy = dx, dy clipped
    to +-limit, times scale, rounded half to even (int16; limit * scale within int16).
    out: an H x W float32 plane to write the magnitude into (sx or sy itself may be
    it: each pixel is read before it is written), instead of a new one; ix_out,
    iy_out: H x W int16 planes for ix and iy (sharing no memory with sx or sy)."""
    cdef Py_ssize_t h = sx.shape[0], w = sx.shape[1]
    if sy.shape[0] != h or sy.shape[1] != w:
        raise ValueError("edge_gradient: dx and dy differ in size")
    if not (0 <= limit and rintf(limit * scale) <= 32767):
        raise ValueError("edge_gradient: the clipped derivatives do not fit int16")
    mag_out = _plane_out(out, h, w, "edge_gradient")
    ix_out = _plane_out(ix_out, h, w, "edge_gradient", np.int16)
    iy_out = _plane_out(iy_out, h, w, "edge_gradient", np.int16)
    if any(np.may_share_memory(o, i) for o in (ix_out, iy_out) for i in (sx, sy, mag_out)) \
            or np.may_share_memory(ix_out, iy_out):
        raise ValueError("edge_gradient: ix_out and iy_out must share no memory with the other planes")
    if h == 0 or w == 0:
        return mag_out, ix_out, iy_out
    # flat pointers over the C-contiguous planes: a loop the compiler can vectorise
    cdef const float* a = &sx[0, 0]
    cdef const float* b = &sy[0, 0]
    cdef float[:, ::1] mag_v = mag_out
    cdef int16_t[:, ::1] ix_v = ix_out, iy_v = iy_out
    cdef float* mag = &mag_v[0, 0]
    cdef int16_t* ix = &ix_v[0, 0]
    cdef int16_t* iy = &iy_v[0, 0]
    with nogil:
        atm_edge_gradient(a, b, mag, ix, iy, h * w, limit, scale)
    return mag_out, ix_out, iy_out


def _plane_out(out, Py_ssize_t h, Py_ssize_t w, str who, dtype=np.float32):
    """`out` checked as a writable C-contiguous H x W plane of `dtype`, or a new one if None."""
    if out is None:
        return np.empty((h, w), dtype=dtype)
    if (not isinstance(out, np.ndarray) or out.dtype != dtype or out.shape != (h, w)
            or not out.flags.c_contiguous or not out.flags.writeable):
        raise ValueError(f"{who}: out must be a writable C-contiguous {h} x {w} {np.dtype(dtype)} plane")
    return out


def hessian_norm(const float[:, ::1] dxx, const float[:, ::1] dyy, const float[:, ::1] dxy, out=None):
    """sqrt(dxx dxx + 2 dxy dxy + dyy dyy) (H x W float32) of second derivatives; out:
    an H x W float32 plane to write it into (one of the derivatives itself may be it:
    each pixel is read before it is written), instead of a new one."""
    cdef Py_ssize_t h = dxx.shape[0], w = dxx.shape[1]
    if dyy.shape[0] != h or dyy.shape[1] != w or dxy.shape[0] != h or dxy.shape[1] != w:
        raise ValueError("hessian_norm: the derivatives differ in size")
    out = _plane_out(out, h, w, "hessian_norm")
    if h == 0 or w == 0:
        return out
    cdef float[:, ::1] o_v = out
    cdef float* o = &o_v[0, 0]
    cdef const float* pa = &dxx[0, 0]
    cdef const float* pb = &dxy[0, 0]
    cdef const float* pc = &dyy[0, 0]
    cdef Py_ssize_t i, n = h * w
    cdef float a, b, c, two = 2  # a float: a literal 2 would make Cython compute in double
    with nogil:
        for i in range(n):
            a = pa[i]
            b = pb[i]
            c = pc[i]
            o[i] = sqrtf(a * a + two * b * b + c * c)
    return out


cdef inline Py_ssize_t _lower_bound(const double* a, Py_ssize_t n, double v) noexcept nogil:
    """The first i with a[i] >= v (n if none): numpy's searchsorted(side="left")."""
    cdef Py_ssize_t lo = 0, hi = n, mid
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


cdef Py_ssize_t _shares(const double* cum, Py_ssize_t n, Py_ssize_t lo, Py_ssize_t hi, int64_t k,
                        int64_t* pos) noexcept nogil:
    """sampling._inverse_cdf for one interval [lo, hi) of the cumulative sum cum (n
    long): the k positions splitting its mass into equal shares, at the middle of each,
    with its float64 operations in their order; returns k."""
    cdef double base = cum[lo - 1] if lo > 0 else 0.0
    cdef double total = cum[hi - 1] - base
    cdef int64_t j
    cdef Py_ssize_t p
    for j in range(k):
        p = _lower_bound(cum, n, base + (<double>j + 0.5) / <double>k * total)
        pos[j] = lo if p < lo else (hi - 1 if p > hi - 1 else p)
    return k


def tile_samples(const double[:, ::1] dens, const int64_t[::1] xb, const int64_t[::1] yb, int64_t r,
                 int64_t z):
    """sampling.sample's samples before its last filter (N x 2 (x, y), tile row after
    tile row): in each tile row, r columns per tile by inverse-CDF sampling of the
    column sums (rows added in turn, as numpy sums axis 0), those of zero mass dropped,
    then along each distinct chosen column (m times chosen: m * z samples) the same on
    the columns' cumulative sums, stacked into one increasing sequence (each column's
    after the last one's end + 1). The float64 operations of the numpy code in their
    order, so the same pixels. ValueError unless the tile bounds increase strictly
    within the image and r, z >= 1."""
    cdef Py_ssize_t h = dens.shape[0], w = dens.shape[1], nh = xb.shape[0] - 1, nv = yb.shape[0] - 1
    cdef Py_ssize_t t, x, y, c, i, count = 0, ncols, nchosen, height, y0, y1, j
    if nh < 1 or nv < 1 or r < 1 or z < 1 or xb[0] != 0 or xb[nh] != w or yb[0] != 0 or yb[nv] != h:
        raise ValueError("tile_samples: tile bounds from 0 to the image's size, r and z >= 1")
    for t in range(nh):
        if xb[t + 1] <= xb[t]:
            raise ValueError("tile_samples: tile bounds must increase")
    for t in range(nv):
        if yb[t + 1] <= yb[t]:
            raise ValueError("tile_samples: tile bounds must increase")
    # the buffer sizes below in Python integers first: as C products they could wrap
    if (<object>nv) * nh * r * z > 2 ** 40 or (<object>nh) * r * max(h, z) > 2 ** 40:
        raise ValueError("tile_samples: more samples asked for than can be held")
    out_a = np.empty((nv * nh * r * z, 2), dtype=np.int64)
    colsum_a = np.empty(w, dtype=np.float64)
    cum_a = np.empty(w, dtype=np.float64)
    chosen_a = np.empty(nh * r, dtype=np.int64)
    mult_a = np.empty(nh * r, dtype=np.int64)
    pos_a = np.empty(max(nh * r, nh * r * z), dtype=np.int64)
    seq_a = np.empty(nh * r * h, dtype=np.float64)
    cdef int64_t[:, ::1] out = out_a
    cdef double[::1] colsum = colsum_a, cum = cum_a, seq = seq_a
    cdef int64_t[::1] chosen = chosen_a, mult = mult_a, pos = pos_a
    cdef double offset, run
    cdef int64_t col, last
    with nogil:
        for t in range(nv):
            y0 = yb[t]
            y1 = yb[t + 1]
            height = y1 - y0
            for x in range(w):
                colsum[x] = dens[y0, x]
            for y in range(y0 + 1, y1):
                for x in range(w):
                    colsum[x] = colsum[x] + dens[y, x]
            run = 0.0
            for x in range(w):
                run = colsum[x] if x == 0 else run + colsum[x]
                cum[x] = run
            ncols = 0
            for i in range(nh):
                _shares(&cum[0], w, xb[i], xb[i + 1], r, &pos[ncols])
                ncols += r
            # the chosen columns of some mass, distinct and sorted, with their counts
            # (chosen tile by tile, each tile's in increasing order: already sorted)
            nchosen = 0
            last = -1
            for i in range(ncols):
                col = pos[i]
                if not colsum[col] > 0:
                    continue
                if col == last:
                    mult[nchosen - 1] += 1
                else:
                    chosen[nchosen] = col
                    mult[nchosen] = 1
                    nchosen += 1
                    last = col
            if nchosen == 0:
                continue
            # the chosen columns' cumulative sums down the tile row, one after another
            offset = 0.0
            for c in range(nchosen):
                col = chosen[c]
                run = 0.0
                for y in range(height):
                    run = dens[y0, col] if y == 0 else run + dens[y0 + y, col]
                    seq[c * height + y] = run + offset
                offset = offset + (run + 1.0)
            for c in range(nchosen):
                _shares(&seq[0], nchosen * height, c * height, (c + 1) * height, mult[c] * z, &pos[0])
                for j in range(mult[c] * z):
                    out[count, 0] = chosen[c]
                    out[count, 1] = pos[j] - c * height + y0
                    count += 1
    return out_a[:count]


def off_edge_share(const float[:, ::1] laplacian, const uint8_t[:, ::1] found):
    """The share of sum(laplacian**2) (summed in float64) over the pixels with no `found`
    pixel among their 3 x 3 neighbours (cv2.dilate's 3 x 3 square, the border adding
    nothing), 0.0 if the sum is 0: adaptive._off_edge_curvature without its squared,
    dilated and masked image-sized temporaries. Sums in row order, four running sums a
    row (numpy's are pairwise: the share may differ in its last bits)."""
    cdef Py_ssize_t h = laplacian.shape[0], w = laplacian.shape[1]
    if found.shape[0] != h or found.shape[1] != w:
        raise ValueError("off_edge_share: the Laplacian and the edges differ in size")
    if h == 0 or w == 0:
        return 0.0
    near_a = np.empty(w + 2, dtype=np.uint8)
    cdef uint8_t[::1] near_v = near_a
    # col[x + 1]: whether column x of the three rows has an edge; col[0] and col[w + 1]
    # stay 0 (the border adds nothing)
    cdef uint8_t* col = &near_v[0]
    cdef Py_ssize_t y, x
    cdef const uint8_t* up
    cdef const uint8_t* mid
    cdef const uint8_t* down
    cdef const float* row
    cdef double e, total = 0.0, off = 0.0, row_total, row_off
    with nogil:
        col[0] = 0
        col[w + 1] = 0
        for y in range(h):
            mid = &found[y, 0]
            up = &found[y - 1, 0] if y > 0 else mid
            down = &found[y + 1, 0] if y + 1 < h else mid
            for x in range(w):
                col[x + 1] = up[x] | mid[x] | down[x]
            row = &laplacian[y, 0]
            row_total = 0.0
            row_off = 0.0
            for x in range(w):
                e = <double>row[x]
                e = e * e
                row_total += e
                if not (col[x] | col[x + 1] | col[x + 2]):
                    row_off += e
            total += row_total
            off += row_off
    return off / total if total != 0 else 0.0


# tan(22.5 degrees) in Q15, as OpenCV's Canny classifies gradient directions
cdef int _TG22 = 13573


def canny(const int16_t[:, ::1] ix, const int16_t[:, ::1] iy, double low, double high):
    """cv2.Canny(ix, iy, low, high, L2gradient=True) > 0 in one thread (OpenCV's runs
    its stripes on its own threads, which cost more CPU than they save on an image of a
    few hundred thousand pixels): the squared magnitude ix^2 + iy^2 (int32), thinned to
    its maxima across the gradient direction (the same Q15 sector test, ties and zero
    border as OpenCV's), then the pixels above floor(low^2) joined 8-connected to those
    above floor(high^2). The same edges, bit for bit, for derivatives up to 20,000 in
    magnitude (tests/test_encode_front.py; from about 24,000 a few edges differ: the
    scalar code this follows is OpenCV's, so most likely its vector code); the encoder's are at most
    16 x 255 (edges.gradient: a Sobel step of an 8-bit scale, fixed point _SCALE)."""
    cdef Py_ssize_t h = ix.shape[0], w = ix.shape[1]
    if iy.shape[0] != h or iy.shape[1] != w:
        raise ValueError("canny: dx and dy differ in size")
    if not (low >= 0 and high >= 0):
        raise ValueError("canny: thresholds must be >= 0")
    if low > high:
        low, high = high, low
    # OpenCV's order: capped at 32767, squared, then floored (its cvFloor)
    low = min(32767.0, low)
    high = min(32767.0, high)
    cdef int lo = <int>(low * low) if low > 0 else 0
    cdef int hi = <int>(high * high) if high > 0 else 0
    if h == 0 or w == 0:
        return np.zeros((h, w), dtype=bool)
    cdef Py_ssize_t stride = w + 2
    # map: 0 a candidate, 1 not an edge, 2 an edge; a border of 1s all round
    map_a = np.empty((h + 2) * stride, dtype=np.uint8)
    # three rows of magnitudes, each with a zero at both ends
    mag_a = np.zeros(3 * stride, dtype=np.int32)
    stack_a = np.empty(h * w, dtype=np.int64)
    cdef uint8_t[::1] map_v = map_a
    cdef int[::1] mag_v = mag_a
    cdef int64_t[::1] stack_v = stack_a
    cdef uint8_t* pmap = &map_v[0]
    cdef int* rows = &mag_v[0]
    cdef int64_t* stack = &stack_v[0]
    cdef int* prev
    cdef int* cur
    cdef int* nxt
    cdef int* tmp
    cdef const int16_t* dxr
    cdef const int16_t* dyr
    cdef uint8_t* mrow
    cdef Py_ssize_t y, x, top = 0, p, q
    cdef int m, ax, ay, tg22x, s, dx, dy
    cdef int64_t k
    cdef Py_ssize_t[8] around
    around[0] = -stride - 1
    around[1] = -stride
    around[2] = -stride + 1
    around[3] = -1
    around[4] = 1
    around[5] = stride - 1
    around[6] = stride
    around[7] = stride + 1
    with nogil:
        for x in range(stride):
            pmap[x] = 1
            pmap[(h + 1) * stride + x] = 1
        # prev (row y - 1), cur (row y) and nxt (row y + 1), each at offset 1
        prev = rows + 1
        cur = rows + stride + 1
        nxt = rows + 2 * stride + 1
        dxr = &ix[0, 0]
        dyr = &iy[0, 0]
        for x in range(w):
            dx = dxr[x]
            dy = dyr[x]
            cur[x] = dx * dx + dy * dy
        for y in range(h):
            if y + 1 < h:
                dxr = &ix[y + 1, 0]
                dyr = &iy[y + 1, 0]
                for x in range(w):
                    dx = dxr[x]
                    dy = dyr[x]
                    nxt[x] = dx * dx + dy * dy
            else:
                for x in range(w):
                    nxt[x] = 0
            dxr = &ix[y, 0]
            dyr = &iy[y, 0]
            mrow = pmap + (y + 1) * stride + 1
            mrow[-1] = 1
            mrow[w] = 1
            for x in range(w):
                m = cur[x]
                mrow[x] = 1
                if m > lo:
                    dx = dxr[x]
                    dy = dyr[x]
                    ax = dx if dx >= 0 else -dx
                    ay = (dy if dy >= 0 else -dy) << 15
                    tg22x = ax * _TG22
                    # the two neighbours across the gradient; a tie is allowed with
                    # the second one except on diagonals
                    if ay < tg22x:
                        if not (m > cur[x - 1] and m >= cur[x + 1]):
                            continue
                    elif ay > tg22x + (ax << 16):
                        if not (m > prev[x] and m >= nxt[x]):
                            continue
                    else:
                        s = -1 if (dx ^ dy) < 0 else 1
                        if not (m > prev[x - s] and m > nxt[x + s]):
                            continue
                    if m > hi:
                        mrow[x] = 2
                        stack[top] = (y + 1) * stride + 1 + x
                        top += 1
                    else:
                        mrow[x] = 0
            tmp = prev
            prev = cur
            cur = nxt
            nxt = tmp
        # hysteresis: every candidate 8-connected to an edge becomes one
        while top > 0:
            top -= 1
            p = stack[top]
            for k in range(8):
                q = p + around[k]
                if pmap[q] == 0:
                    pmap[q] = 2
                    stack[top] = q
                    top += 1
    # the edges (2s) inside the border, in one vectorised comparison
    return map_a.reshape(h + 2, stride)[1 : h + 1, 1 : w + 1] == 2


def otsu_level(const float[:, ::1] magnitude, float scale):
    """cv2.threshold(levels, 0, 255, THRESH_OTSU)[0] of the 8-bit levels
    np.clip(magnitude * scale, 0, 255).astype(np.uint8) (the float32 product,
    truncated), in one pass with no image-sized temporaries and in one thread: the
    histogram, then Otsu's between-class variance in OpenCV's arithmetic and order
    (its first maximum wins)."""
    cdef Py_ssize_t h = magnitude.shape[0], w = magnitude.shape[1], y, x, x0, n
    cdef int64_t[256] hist
    # four histograms counted in turn: a run of pixels at one level (a flat region's
    # zero gradient) made each count wait for the one before (0.45 ms at 741 x 500)
    cdef int64_t[4][256] part
    cdef uint8_t[256] levels
    cdef int i
    cdef float v, top = 255, zero = 0
    cdef const float* row
    cdef double mu = 0, mu1 = 0, q1 = 0, q2, mu2, p_i, sigma, max_sigma = 0, level = 0
    cdef double eps = 1.1920928955078125e-07  # FLT_EPSILON
    if h == 0 or w == 0:
        raise ValueError("otsu_level: an empty image")
    cdef double each = 1.0 / <double>(h * w)
    with nogil:
        for i in range(256):
            part[0][i] = 0
            part[1][i] = 0
            part[2][i] = 0
            part[3][i] = 0
        for y in range(h):
            row = &magnitude[y, 0]
            for x0 in range(0, w, 256):
                n = min(256, w - x0)
                # the levels of up to 256 pixels first (a loop the compiler vectorises)
                for x in range(n):
                    v = row[x0 + x] * scale
                    v = zero if v < zero else (top if v > top else v)
                    levels[x] = <uint8_t>v
                for x in range(0, n - 3, 4):
                    part[0][levels[x]] += 1
                    part[1][levels[x + 1]] += 1
                    part[2][levels[x + 2]] += 1
                    part[3][levels[x + 3]] += 1
                for x in range(n - n % 4, n):
                    part[0][levels[x]] += 1
        for i in range(256):
            hist[i] = part[0][i] + part[1][i] + part[2][i] + part[3][i]
        for i in range(256):
            mu += i * <double>hist[i]
        mu *= each
        for i in range(256):
            p_i = hist[i] * each
            mu1 *= q1
            q1 += p_i
            q2 = 1.0 - q1
            if min(q1, q2) < eps or max(q1, q2) > 1.0 - eps:
                continue
            mu1 = (mu1 + i * p_i) / q1
            mu2 = (mu - q1 * mu1) / q2
            sigma = q1 * q2 * (mu1 - mu2) * (mu1 - mu2)
            if sigma > max_sigma:
                max_sigma = sigma
                level = i
    return level


cdef extern from *:
    """
    /* numpy's pairwise sum of a float64 array (add.reduce of a contiguous one, which
       np.mean divides by the count), of the values d[i] of the pixels with x[i] == 0 in
       raster order, read as the sum reaches them: no array of them is made */
    typedef struct { const double* d; const uint8_t* x; Py_ssize_t i; } atm_free_values;
    /* the next n free values into a (n <= 128), without a branch a pixel: each pixel's
       value is written and kept only if the pixel is free */
    static inline void atm_take_free(atm_free_values* v, double* a, Py_ssize_t n) {
        Py_ssize_t j = 0, i = v->i;
        while (j < n) {
            a[j] = v->d[i];
            j += v->x[i] == 0;
            i++;
        }
        v->i = i;
    }
    static double atm_pairwise_free(atm_free_values* v, Py_ssize_t n) {
        double a[128];
        if (n < 8) {
            double res = 0.;
            atm_take_free(v, a, n);
            for (Py_ssize_t i = 0; i < n; i++) res += a[i];
            return res;
        }
        if (n <= 128) {  /* numpy's PW_BLOCKSIZE: eight running sums */
            double r[8], res;
            Py_ssize_t i;
            atm_take_free(v, a, n);
            for (int j = 0; j < 8; j++) r[j] = a[j];
            for (i = 8; i < n - (n % 8); i += 8)
                for (int j = 0; j < 8; j++) r[j] += a[i + j];
            res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
            for (; i < n; i++) res += a[i];
            return res;
        }
        Py_ssize_t n2 = n / 2;
        n2 -= n2 % 8;
        double first = atm_pairwise_free(v, n2);  /* the first half's values come first */
        double second = atm_pairwise_free(v, n - n2);
        return first + second;
    }
    """
    ctypedef struct atm_free_values:
        const double* d
        const uint8_t* x
        Py_ssize_t i
    double atm_pairwise_free(atm_free_values* v, Py_ssize_t n) noexcept nogil


def density_roots(const float[:, ::1] curvature, const uint8_t[:, ::1] excluded):
    """(d, mean): d = sqrt(curvature) in float64 (H x W; numpy's square root of the
    float64 value, so the same numbers), and the mean of the d of the pixels not
    excluded (0.0 if none), as numpy's d[~excluded].mean() sums them (pairwise, in
    raster order), for sampling.density."""
    cdef Py_ssize_t h = curvature.shape[0], w = curvature.shape[1]
    if excluded.shape[0] != h or excluded.shape[1] != w:
        raise ValueError("density_roots: the curvature and the exclusion mask differ in size")
    d_out = np.empty((h, w), dtype=np.float64)
    if h == 0 or w == 0:
        return d_out, 0.0
    cdef double[:, ::1] d_v = d_out
    cdef const float* c = &curvature[0, 0]
    cdef const uint8_t* x = &excluded[0, 0]
    cdef double* d = &d_v[0, 0]
    cdef Py_ssize_t i, n = h * w, nf = 0
    cdef atm_free_values values
    cdef double total = 0.0
    with nogil:
        # the roots and the count apart, each a loop the compiler vectorises
        for i in range(n):
            d[i] = sqrt(<double>c[i])
        for i in range(n):
            nf += x[i] == 0
        if nf:
            values.d = d
            values.x = x
            values.i = 0
            # the reduction starts from add's identity, 0.0, then adds the pairwise sum
            total = 0.0 + atm_pairwise_free(&values, nf)
    return d_out, total / nf if nf else 0.0


def density_scale(double[:, ::1] d, const uint8_t[:, ::1] excluded, double mean, double floor):
    """In place: d / mean (0 where mean is not above 0) plus floor, and 0 on excluded
    pixels: sampling.density's numpy steps, operation for operation."""
    cdef Py_ssize_t h = d.shape[0], w = d.shape[1]
    if excluded.shape[0] != h or excluded.shape[1] != w:
        raise ValueError("density_scale: the density and the exclusion mask differ in size")
    if h == 0 or w == 0:
        return
    cdef double* p = &d[0, 0]
    cdef const uint8_t* x = &excluded[0, 0]
    cdef Py_ssize_t i, n = h * w
    cdef bint scale = mean > 0
    with nogil:
        for i in range(n):
            if x[i]:
                p[i] = 0.0
            elif scale:
                p[i] = p[i] / mean + floor
            else:
                p[i] = 0.0 + floor
