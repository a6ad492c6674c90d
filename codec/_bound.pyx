"""Encoder kernel for refinement to an error bound (codec.error_bound): the squared
error of a mesh's decode against the image, kept per pixel and measured again only
over the triangles a round changed, and the next round's vertices chosen from it.
Rendering and measuring the whole image every round took a third of a max_error
encode of a float DEM, while a round changes a small part of it. The GIL is released
while it works.

A pixel's value is the decoder's (ATM.md, "Decoding"; codec.decoder_cpu): with the
integer edge functions w_i and doubled area D > 0 of a triangle holding it,
floor((2 sum_i w_i v_i + D) / (2 D)). Every pixel of a triangle's closed area is
measured, its edges too: a pixel on an edge two triangles share gets the same value
from either (its weights along the edge are the same exact fractions), so no
ownership rule is needed and measuring a triangle never changes a pixel that another
triangle holding it gives differently."""

from libc.stdint cimport int64_t, uint8_t, uint16_t

ctypedef fused sample_t:
    uint8_t
    uint16_t
    double

import numpy as np


cdef inline int64_t _floor_div_fast(int64_t a, int64_t b) noexcept nogil:
    """floor(a / b) for b > 0 and |a| < 2**53 (as the decoder's kernel computes it): the
    float64 quotient truncated, then corrected by one."""
    cdef int64_t q = <int64_t>(<double>a / <double>b)
    q -= (a - q * b) < 0
    return q


def measure(const int64_t[:, ::1] vertices, const int64_t[:, ::1] values,
            const int64_t[:, ::1] triangles, const uint8_t[::1] changed,
            const sample_t[:, ::1] reference, const uint8_t[::1] valid,
            double[::1] worst, double[:, ::1] sq, int64_t width, int64_t height,
            int64_t[:, ::1] rows=None, sample_t[:, ::1] decoded=None):
    """Measure the decoded error of every triangle (of every one with a corner marked in
    `changed`, per vertex, when given): for each pixel of its closed area, the squared
    difference of the decoded value and `reference` (H*W x C, the image: uint8, uint16
    or float64; the smaller types keep it in cache) per
    channel into `sq` (H*W x C; may be None) and their largest into `worst` (H*W), both
    0 where `valid` (H*W, may be None) is 0. Triangles with no area are skipped (they
    hold no pixel a decoder writes). Returns the number of triangles measured.

    rows (H x C, may be None; integer `reference` only, with `sq` or `decoded` unless C
    is 1): each row's sum of the squared errors per channel, kept as the pixels are
    measured again (each new error minus the one it replaces: from `decoded`, else from
    `sq`, or `worst` for one channel). The errors of integer samples are whole numbers,
    so these sums are exact and equal any float64 sum of them below 2**53, in whatever
    order: refinement's RMS test then reads H x C sums instead of adding H*W*C errors
    each round (a tenth of an RGB photo's encode to a quality).

    decoded (H*W x C, may be None; `values` then in the samples' range): each measured
    pixel's decoded value; before a pixel is first measured it must hold the pixel's
    `reference` sample (an error of 0). Where the errors are kept only as their row
    sums, it stands for `sq` at an eighth of the memory for 8-bit samples (replaying
    an RGB photo's rounds, keeping `sq` and the row sums took 207 ms against 144 ms
    for `worst` alone, most of it waiting for `sq`'s cache lines).

    ValueError if an array's shape does not fit, a corner index is beyond the vertices,
    a vertex lies outside the image, or the image has more than 2**32 pixels (the exact
    arithmetic's bound, as the decoder's)."""
    cdef int64_t n = vertices.shape[0], m = triangles.shape[0], c = values.shape[1]
    cdef int64_t npix
    # the bound checked before the product, which could wrap
    if width < 1 or height < 1 or width > ((<int64_t>1) << 32) // height:
        raise ValueError("measure: an image of 1 to 2**32 pixels")
    npix = width * height
    if vertices.shape[1] != 2 or triangles.shape[1] != 3 or values.shape[0] != n or c < 1 or c > 4:
        raise ValueError("measure: N x 2 vertices, N x C values (C <= 4), M x 3 triangles")
    if reference.shape[0] != npix or reference.shape[1] != c or worst.shape[0] != npix:
        raise ValueError("measure: reference H*W x C and worst H*W")
    if sq is not None and (sq.shape[0] != npix or sq.shape[1] != c):
        raise ValueError("measure: sq H*W x C")
    if valid is not None and valid.shape[0] != npix:
        raise ValueError("measure: valid H*W")
    if changed is not None and changed.shape[0] != n:
        raise ValueError("measure: changed, one flag per vertex")
    if rows is not None and (rows.shape[0] != height or rows.shape[1] != c or sample_t is double
                             or (sq is None and decoded is None and c > 1)):
        raise ValueError("measure: rows H x C, for integer samples and with sq or decoded unless one channel")
    if decoded is not None and (decoded.shape[0] != npix or decoded.shape[1] != c):
        raise ValueError("measure: decoded H*W x C")
    cdef int64_t k, i, t, status = 0
    with nogil:
        for k in range(n):
            if not (0 <= vertices[k, 0] < width and 0 <= vertices[k, 1] < height):
                status = 1
                break
        if status == 0:
            for t in range(m):
                for i in range(3):
                    if not (0 <= triangles[t, i] < n):
                        status = 2
                if status:
                    break
    cdef int64_t top_value = 0
    if decoded is not None and sample_t is not double and status == 0:
        top_value = 255 if sample_t is uint8_t else 65535
        with nogil:
            for k in range(n):
                for i in range(c):
                    if not (0 <= values[k, i] <= top_value):
                        status = 3
    if status == 3:
        raise ValueError("measure: a value beyond the samples' range (decoded)")
    if status == 1:
        raise ValueError("measure: a vertex outside the image")
    if status == 2:
        raise ValueError("measure: a corner index beyond the vertices")
    cdef bint has_sq = sq is not None, has_valid = valid is not None, has_changed = changed is not None
    cdef bint has_rows = rows is not None, has_decoded = decoded is not None, hole
    cdef int64_t ri, di, si, most_i
    cdef int64_t count = 0, ch, x, y, lo, hi, p, j, l, q, r
    cdef int64_t c0, c1, c2, x0, y0, x1, y1, x2, y2, d, d2, xmin, xmax, ymin, ymax, e, rest
    cdef int64_t a[3]
    cdef int64_t b[3]
    cdef int64_t cc[3]
    cdef int64_t ga[4]
    cdef int64_t gb[4]
    cdef int64_t g0[4]
    cdef int64_t plane[4]
    cdef int64_t vq[4]  # a channel's value at the current pixel: floor over 2D
    cdef int64_t vr[4]  # and remainder, in [0, 2D)
    cdef int64_t sq_[4]  # its step per column: floor and remainder
    cdef int64_t sr[4]
    cdef int64_t px[3]
    cdef int64_t py[3]
    cdef int64_t added[4]  # the row's change of each channel's sum
    # a remainder's carry, without a branch: it is taken about as often as not, in no
    # order a predictor can learn
    cdef int64_t carry
    cdef double diff, s, most
    # the triangles to measure, by their top row (a counting sort): the kernel then
    # walks the image from top to bottom and the rows it writes stay in cache, where
    # the triangulation's own order (by slot) scattered its writes over the image
    # (0.83 of the time on an RGB photo's rounds); the order changes no pixel's
    # error, as any triangle holding a pixel gives it the same value
    start_array = np.zeros(height + 1, dtype=np.int64)
    top_array = np.empty(m, dtype=np.int64)  # each triangle's top row, -1: not measured
    order_array = np.empty(m, dtype=np.int64)
    cdef int64_t[::1] start = start_array
    cdef int64_t[::1] top = top_array
    cdef int64_t[::1] order = order_array
    cdef int64_t o, todo = 0
    with nogil:
        for t in range(m):
            c0 = triangles[t, 0]
            c1 = triangles[t, 1]
            c2 = triangles[t, 2]
            if has_changed and not (changed[c0] or changed[c1] or changed[c2]):
                top[t] = -1
                continue
            top[t] = min(vertices[c0, 1], min(vertices[c1, 1], vertices[c2, 1]))
            start[top[t] + 1] += 1
        for y in range(height):
            start[y + 1] += start[y]
        for t in range(m):
            y = top[t]
            if y >= 0:
                order[start[y]] = t
                start[y] += 1
                todo += 1
        for o in range(todo):
            t = order[o]
            c0 = triangles[t, 0]
            c1 = triangles[t, 1]
            c2 = triangles[t, 2]
            x0 = vertices[c0, 0]; y0 = vertices[c0, 1]
            x1 = vertices[c1, 0]; y1 = vertices[c1, 1]
            x2 = vertices[c2, 0]; y2 = vertices[c2, 1]
            d = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if d == 0:
                continue
            if d < 0:  # the same values in the other orientation
                c1, c2 = c2, c1
                x1, x2 = x2, x1
                y1, y2 = y2, y1
                d = -d
            count += 1
            px[0] = x0; px[1] = x1; px[2] = x2
            py[0] = y0; py[1] = y1; py[2] = y2
            # w_i = (x_k - x_j)(y - y_j) - (y_k - y_j)(x - x_j) = a_i x + b_i y + cc_i,
            # j = i + 1, k = i + 2: >= 0 on the closed triangle, w_i = D at corner i;
            # here relative to corner 0, so that every term stays small
            for i in range(3):
                j = (i + 1) % 3
                l = (i + 2) % 3
                a[i] = -(py[l] - py[j])
                b[i] = px[l] - px[j]
                cc[i] = (px[l] - px[j]) * (y0 - py[j]) - (py[l] - py[j]) * (x0 - px[j])
            # 2 sum_i w_i v_i + D = ga u + gb v + g0 with u = x - x0, v = y - y0; at
            # corner 0 it is (2 v_0 + 1) D
            for ch in range(c):
                ga[ch] = 2 * (a[0] * values[c0, ch] + a[1] * values[c1, ch] + a[2] * values[c2, ch])
                gb[ch] = 2 * (b[0] * values[c0, ch] + b[1] * values[c1, ch] + b[2] * values[c2, ch])
                g0[ch] = (2 * values[c0, ch] + 1) * d
            d2 = 2 * d
            for ch in range(c):
                sq_[ch] = _floor_div_fast(ga[ch], d2)
                sr[ch] = ga[ch] - sq_[ch] * d2
            xmin = min(x0, min(x1, x2)); xmax = max(x0, max(x1, x2))
            ymin = min(y0, min(y1, y2)); ymax = max(y0, max(y1, y2))
            for y in range(ymin, ymax + 1):
                # the row's columns where every w_i >= 0: a_i (x - x0) >= -(b_i v + cc_i)
                lo = xmin
                hi = xmax
                for i in range(3):
                    rest = -(b[i] * (y - y0) + cc[i])
                    if a[i] > 0:
                        e = x0 - _floor_div_fast(-rest, a[i])  # x0 + ceil(rest / a)
                        if e > lo:
                            lo = e
                    elif a[i] < 0:
                        e = x0 + _floor_div_fast(-rest, -a[i])  # x0 + floor(rest / a)
                        if e < hi:
                            hi = e
                    elif rest > 0:
                        hi = lo - 1
                if lo > hi:
                    continue
                # each channel's value as floor and remainder over 2D, stepped along
                # the row (one division per row, not per pixel)
                for ch in range(c):
                    plane[ch] = ga[ch] * (lo - x0) + gb[ch] * (y - y0) + g0[ch]
                    vq[ch] = _floor_div_fast(plane[ch], d2)
                    vr[ch] = plane[ch] - vq[ch] * d2
                p = y * width + lo
                if c == 1 and not has_sq and not has_decoded:
                    q = vq[0]
                    r = vr[0]
                    e = 0
                    for x in range(lo, hi + 1):
                        diff = <double>q - <double>reference[p, 0]
                        s = diff * diff
                        if has_valid and not valid[p]:
                            s = 0.0
                        if has_rows:
                            e += <int64_t>s - <int64_t>worst[p]
                        worst[p] = s
                        p += 1
                        q += sq_[0]
                        r += sr[0]
                        carry = r >= d2
                        r -= d2 & -carry
                        q += carry
                    if has_rows:
                        rows[y, 0] += e
                    continue
                for ch in range(c):
                    added[ch] = 0
                if sample_t is not double and has_decoded:
                    # in integers (the values are checked to be samples, so every
                    # error is below 2**32): no conversion to and from float64 a
                    # channel, the same errors
                    for x in range(lo, hi + 1):
                        hole = has_valid and not valid[p]
                        most_i = 0
                        for ch in range(c):
                            ri = <int64_t>reference[p, ch]
                            di = vq[ch] - ri
                            si = 0 if hole else di * di
                            if has_rows:
                                di = <int64_t>decoded[p, ch] - ri
                                added[ch] += si - (0 if hole else di * di)
                            decoded[p, ch] = <sample_t>vq[ch]
                            if has_sq:
                                sq[p, ch] = <double>si
                            most_i = si if si > most_i else most_i
                            vq[ch] += sq_[ch]
                            vr[ch] += sr[ch]
                            carry = vr[ch] >= d2
                            vr[ch] -= d2 & -carry
                            vq[ch] += carry
                        worst[p] = <double>most_i
                        p += 1
                    if has_rows:
                        for ch in range(c):
                            rows[y, ch] += added[ch]
                    continue
                for x in range(lo, hi + 1):
                    most = 0.0
                    for ch in range(c):
                        diff = <double>vq[ch] - <double>reference[p, ch]
                        s = diff * diff
                        if has_valid and not valid[p]:
                            s = 0.0
                        if has_rows:  # (integer samples: with decoded they took the loop above)
                            added[ch] += <int64_t>s - <int64_t>(sq[p, ch] if has_sq else worst[p])
                        if has_decoded:
                            decoded[p, ch] = <sample_t>vq[ch]
                        if has_sq:
                            sq[p, ch] = s
                        most = s if s > most else most  # (maxsd: no branch)
                        vq[ch] += sq_[ch]
                        vr[ch] += sr[ch]
                        carry = vr[ch] >= d2
                        vr[ch] -= d2 & -carry
                        vq[ch] += carry
                    worst[p] = most
                    p += 1
                if has_rows:
                    for ch in range(c):
                        rows[y, ch] += added[ch]
    return count


def count(const double[:, ::1] worst, const double[::1] row_limit, double over_limit,
          const uint8_t[:, ::1] is_vertex, const uint8_t[:, ::1] walls):
    """Over `worst` (H x W squared errors): (pixels over `over_limit` in any row, bad
    pixels: over their row's `row_limit` (H), bad ones that are no vertex (`is_vertex`)
    and off the walls (`walls`, may be None): the candidates, bad ones on the walls that
    are no vertex)."""
    cdef int64_t h = worst.shape[0], w = worst.shape[1], x, y
    cdef int64_t over = 0, bad = 0, candidates = 0, on_walls = 0
    if row_limit.shape[0] != h or is_vertex.shape[0] != h or is_vertex.shape[1] != w:
        raise ValueError("count: row_limit (H) and is_vertex (H x W) must fit worst")
    if walls is not None and (walls.shape[0] != h or walls.shape[1] != w):
        raise ValueError("count: walls (H x W) must fit worst")
    cdef bint has_walls = walls is not None
    cdef double limit, e
    cdef int64_t bad_here, off_vertex, on_wall
    with nogil:
        for y in range(h):
            limit = row_limit[y]
            # counted without branches (a bad pixel is found in no order a predictor
            # learns)
            for x in range(w):
                e = worst[y, x]
                over += e > over_limit
                bad_here = e > limit
                off_vertex = bad_here & (is_vertex[y, x] == 0)
                on_wall = off_vertex & (walls[y, x] != 0) if has_walls else 0
                bad += bad_here
                on_walls += on_wall
                candidates += off_vertex - on_wall
    return over, bad, candidates, on_walls


def spread(const double[:, ::1] worst, const double[::1] row_limit, const uint8_t[:, ::1] is_vertex,
           const uint8_t[:, ::1] walls, int64_t cell):
    """The worst candidate (a pixel over its row's `row_limit`, no vertex, off `walls`
    if given) of each cell x cell block of the image, blocks in raster order, the first
    in a block's raster order among equals: K x 2 (x, y). What error_bound._spread
    gives for the candidates' errors (and 0 elsewhere)."""
    cdef int64_t h = worst.shape[0], w = worst.shape[1], x, y, bx, by, blocks_x
    if cell < 1:
        raise ValueError("spread: cell must be >= 1")
    if row_limit.shape[0] != h or is_vertex.shape[0] != h or is_vertex.shape[1] != w:
        raise ValueError("spread: row_limit (H) and is_vertex (H x W) must fit worst")
    if walls is not None and (walls.shape[0] != h or walls.shape[1] != w):
        raise ValueError("spread: walls (H x W) must fit worst")
    blocks_x = (w + cell - 1) // cell  # (cdivision: no floor of negatives)
    best_array = np.zeros(blocks_x, dtype=np.float64)
    at_array = np.zeros(blocks_x, dtype=np.int64)
    out_array = np.empty((((h + cell - 1) // cell) * blocks_x, 2), dtype=np.int64)
    cdef double[::1] best = best_array
    cdef int64_t[::1] at = at_array
    cdef int64_t[:, ::1] out = out_array
    cdef bint has_walls = walls is not None
    cdef int64_t k = 0
    cdef double limit, e
    with nogil:
        by = 0
        while by < h:
            for bx in range(blocks_x):
                best[bx] = 0.0
            for y in range(by, min(by + cell, h)):
                limit = row_limit[y]
                # block by block (a division a pixel took most of the pass)
                for bx in range(blocks_x):
                    for x in range(bx * cell, min(bx * cell + cell, w)):
                        e = worst[y, x]
                        # strictly greater: the first of equals stays, as argmax keeps it
                        if e > limit and e > best[bx] and not is_vertex[y, x] and not (has_walls and walls[y, x]):
                            best[bx] = e
                            at[bx] = y * w + x
            for bx in range(blocks_x):
                if best[bx] > 0.0:
                    out[k, 0] = at[bx] % w
                    out[k, 1] = at[bx] // w
                    k += 1
            by += cell
    return out_array[:k].copy()


def around(const int64_t[:, ::1] triangles, const uint8_t[::1] marked):
    """Per vertex (as many as `marked`), whether it is a corner of a triangle that has a
    marked corner: the vertices a refit after inserting the marked ones frees (one pass
    over the triangles; numpy's gathers and scatters over them took a tenth of a
    max_error encode of a float DEM). ValueError if a corner is beyond the vertices."""
    cdef int64_t m = triangles.shape[0], n = marked.shape[0], t, i, status = 0
    if triangles.shape[1] != 3:
        raise ValueError("around: M x 3 triangles")
    out_array = np.zeros(n, dtype=bool)
    cdef uint8_t[::1] out = out_array.view(np.uint8)
    cdef int64_t a, b, c
    with nogil:
        for t in range(m):
            a = triangles[t, 0]
            b = triangles[t, 1]
            c = triangles[t, 2]
            if not (0 <= a < n and 0 <= b < n and 0 <= c < n):
                status = 1
                break
            if marked[a] or marked[b] or marked[c]:
                out[a] = 1
                out[b] = 1
                out[c] = 1
    if status:
        raise ValueError("around: a corner index beyond the vertices")
    return out_array
