"""Encoder kernel: the sequential parts of the edge polyline stage
(codec.mesher.polylines), walked one pixel after another instead of in vectorised
rounds: ordering the pixels of the simple chains, and the segment rule of section
3.3.2.1 of "Approximation of Digital Images with Discontinuity-Preserving Adaptive
Triangular Meshes" that picks each chain's control points. The results are those of
the numpy code they replace. The GIL is released while they work.
"""

from libc.stdint cimport int64_t, uint8_t, uint64_t
from libc.math cimport rint
from libc.string cimport memcpy

from codec.offsets cimport OFFSETS_OK, offsets_fault

import numpy as np


# per 8-bit neighbourhood code: how many neighbours, the first and the last one's bit
cdef uint8_t _COUNT[256]
cdef uint8_t _FIRST[256]
cdef uint8_t _LAST[256]


cdef void _code_tables() noexcept:
    cdef int code, k
    for code in range(256):
        _COUNT[code] = 0
        _FIRST[code] = 0
        _LAST[code] = 0
        for k in range(8):
            if code >> k & 1:
                if _COUNT[code] == 0:
                    _FIRST[code] = k
                _LAST[code] = k
                _COUNT[code] += 1


_code_tables()


def order_chains(const uint8_t[::1] simple, const int64_t[::1] offsets):
    """The pixels of the simple chains (every pixel with at most two 8-neighbours) of a
    flat mask padded by one pixel (offsets: the 8 neighbours' index offsets), chain by
    chain, each from its start: its first end in scan-line order, or for a loop its
    first pixel, the loop then opened between the start and its later neighbour (so the
    walk leaves the start towards its earlier one); chains in the scan-line order of
    their starts. Returns (flat indices in chain order, chain of each, closed per
    chain). ValueError if a neighbour offset leaves the mask or a pixel has more than
    two neighbours."""
    cdef int64_t size = simple.shape[0], n = 0, i, j, k, p, q, a, b, top, count, chains = 0
    if offsets.shape[0] != 8:
        raise ValueError("order_chains: 8 neighbour offsets")
    for k in range(8):
        if abs(offsets[k]) >= size:
            raise ValueError("order_chains: a neighbour offset beyond the mask")
    # the set pixels in index order, eight bytes tested at a time (np.flatnonzero of a
    # uint8 mask takes numpy's slow generic path: 0.39 ms for a 512² image's mask)
    cdef const uint8_t* s = &simple[0] if size else NULL
    cdef uint64_t word
    with nogil:
        for i in range(0, size - 7, 8):
            memcpy(&word, s + i, 8)
            if word:
                for k in range(i, i + 8):
                    n += s[k] != 0
        for i in range(size - size % 8, size):
            n += s[i] != 0
    if n == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty.copy(), np.zeros(0, bool)
    # one spare slot: each byte of a word is written and kept only if set (no branch)
    flat_a = np.empty(n + 1, dtype=np.int64)
    cdef int64_t[::1] flat_w = flat_a
    with nogil:
        j = 0
        for i in range(0, size - 7, 8):
            memcpy(&word, s + i, 8)
            if word:
                for k in range(i, i + 8):
                    flat_w[j] = k
                    j += s[k] != 0
        for i in range(size - size % 8, size):
            flat_w[j] = i
            j += s[i] != 0
    # each set pixel's place in `flat`, in a ring of slots by position modulo a power of
    # two above twice the farthest offset, filled just ahead of the pixel read: every
    # neighbour read is set, so filled and not yet overwritten (an image-sized table,
    # 3 MB at 741 x 500, made its random reads miss the cache and faulted in its pages)
    cdef int64_t span = max(abs(int(v)) for v in offsets)
    cdef int64_t ring_mask = (1 << (2 * span + 1).bit_length()) - 1
    ring_a = np.empty(ring_mask + 1, dtype=np.int64)
    nb_a = np.full((n, 2), -1, dtype=np.int64)
    comp_start_a = np.full(n, -1, dtype=np.int64)
    is_start_a = np.zeros(n, dtype=np.uint8)
    closed_start_a = np.zeros(n, dtype=np.uint8)
    stack_a = np.empty(n, dtype=np.int64)
    order_a = np.empty(n, dtype=np.int64)
    chain_a = np.empty(n, dtype=np.int64)
    closed_a = np.zeros(n, dtype=bool)
    cdef const int64_t[::1] flat = flat_a
    cdef int64_t[::1] ring = ring_a, comp_start = comp_start_a, stack = stack_a
    cdef int64_t ahead = 0
    cdef int64_t[::1] order = order_a, chain = chain_a
    cdef int64_t[:, ::1] nb = nb_a
    cdef uint8_t[::1] is_start = is_start_a, closed_start = closed_start_a
    cdef uint8_t[::1] closed = closed_a.view(np.uint8)
    cdef bint bad = False, border = False
    cdef int64_t[8] off
    cdef int64_t low = 0, high = 0
    cdef int code
    with nogil:
        for k in range(8):
            off[k] = offsets[k]
            low = min(low, off[k])
            high = max(high, off[k])
        # each pixel's neighbours in offset order: its first and its last, from its
        # 8-bit neighbourhood code by table (the branch a neighbour was mispredicted)
        for i in range(n):
            p = flat[i]
            if p + low < 0 or p + high >= size:
                border = True
                break
            while ahead < n and flat[ahead] <= p + span:
                ring[flat[ahead] & ring_mask] = ahead
                ahead += 1
            code = ((s[p + off[0]] != 0) | (s[p + off[1]] != 0) << 1 | (s[p + off[2]] != 0) << 2
                    | (s[p + off[3]] != 0) << 3 | (s[p + off[4]] != 0) << 4 | (s[p + off[5]] != 0) << 5
                    | (s[p + off[6]] != 0) << 6 | (s[p + off[7]] != 0) << 7)
            if _COUNT[code] > 2:
                bad = True
                break
            if code:
                nb[i, 0] = ring[(p + off[_FIRST[code]]) & ring_mask]
                if _COUNT[code] == 2:
                    nb[i, 1] = ring[(p + off[_LAST[code]]) & ring_mask]
        if not bad and not border:
            # components, found from their first pixel in scan-line order (the loop's
            # start), each pixel labelled with its component's first pixel
            for i in range(n):
                if comp_start[i] >= 0:
                    continue
                comp_start[i] = i
                stack[0] = i
                top = 1
                a = -1  # the first end (at most one neighbour) in scan-line order
                while top:
                    top -= 1
                    p = stack[top]
                    if nb[p, 1] < 0 and (a < 0 or p < a):
                        a = p
                    for k in range(2):
                        q = nb[p, k]
                        if q >= 0 and comp_start[q] < 0:
                            comp_start[q] = i
                            stack[top] = q
                            top += 1
                if a >= 0:
                    is_start[a] = 1
                else:
                    is_start[i] = 1
                    closed_start[i] = 1
                    # open the loop between its start and the start's later neighbour
                    b = nb[i, 0] if nb[i, 0] > nb[i, 1] else nb[i, 1]
                    if nb[i, 0] == b:
                        nb[i, 0] = nb[i, 1]
                    nb[i, 1] = -1
                    if nb[b, 0] == i:
                        nb[b, 0] = nb[b, 1]
                    nb[b, 1] = -1
            # chains in the scan-line order of their starts, each walked from its start
            j = 0
            for i in range(n):
                if not is_start[i]:
                    continue
                closed[chains] = closed_start[i]
                a = -1
                p = i
                while p >= 0:
                    order[j] = flat[p]
                    chain[j] = chains
                    j += 1
                    q = nb[p, 0] if nb[p, 0] != a else nb[p, 1]
                    a = p
                    p = q
                chains += 1
    if border:
        raise ValueError("order_chains: a pixel's neighbour lies beyond the mask (it needs a border)")
    if bad:
        raise ValueError("order_chains: a pixel has more than two neighbours")
    return order_a, chain_a, closed_a[:chains].copy()


def control_points(const double[:, ::1] xy, const int64_t[::1] first, const int64_t[::1] last,
                   int64_t k, double d):
    """The paper's segment rule on every chain (pixels xy[first[c]] .. xy[last[c]]):
    from the start A a reference point C k pixels ahead; while every pixel strictly
    between A and C lies within d of segment AC, C advances by k (to the chain's end at
    most); otherwise the first offending pixel becomes the next start. Returns the
    indices into xy of the control points (each chain's first, every start, its last),
    in order. ValueError on a chain outside xy or k < 1."""
    cdef int64_t chains = first.shape[0], p = xy.shape[0], c, a, ref, end, i, bad, count = 0
    cdef double d2 = d * d, ax, ay, sx, sy, rx, ry, t, ox, oy, den
    if last.shape[0] != chains or k < 1 or xy.shape[1] != 2:
        raise ValueError("control_points: a last per first, k >= 1 and N x 2 points")
    for c in range(chains):
        if first[c] < 0 or last[c] >= p or (c and first[c] <= last[c - 1]) or last[c] < first[c]:
            raise ValueError("control_points: chains must be ordered ranges of the points")
    out_a = np.empty(p, dtype=np.int64)
    cdef int64_t[::1] out = out_a
    with nogil:
        for c in range(chains):
            a = first[c]
            end = last[c]
            out[count] = a
            count += 1
            if end == a:
                continue
            ref = a + k if a + k < end else end
            while True:
                ax = xy[a, 0]
                ay = xy[a, 1]
                sx = xy[ref, 0] - ax
                sy = xy[ref, 1] - ay
                den = sx * sx + sy * sy
                if den < 1e-12:
                    den = 1e-12
                bad = -1
                for i in range(a + 1, ref):
                    rx = xy[i, 0] - ax
                    ry = xy[i, 1] - ay
                    t = (rx * sx + ry * sy) / den
                    if t < 0.0:
                        t = 0.0
                    elif t > 1.0:
                        t = 1.0
                    ox = rx - t * sx
                    oy = ry - t * sy
                    if ox * ox + oy * oy > d2:
                        bad = i
                        break
                if bad >= 0:
                    out[count] = bad
                    count += 1
                    a = bad
                    ref = a + k if a + k < end else end
                elif ref == end:
                    out[count] = end
                    count += 1
                    break
                else:
                    ref = ref + k if ref + k < end else end
    return out_a[:count].copy()


cdef inline int64_t _abs(int64_t v) noexcept nogil:
    return -v if v < 0 else v


cdef inline int _orient(int64_t ax, int64_t ay, int64_t bx, int64_t by, int64_t cx, int64_t cy) noexcept nogil:
    cdef int64_t d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    return (d > 0) - (d < 0)


cdef bint _conflict(const int64_t[:, ::1] p, const int64_t[:, ::1] s, int64_t i, int64_t j) noexcept nogil:
    """Do segments i and j meet anywhere but at a shared end point (unfold.conflicts)?"""
    cdef int64_t a = s[i, 0], b = s[i, 1], c = s[j, 0], d = s[j, 1], k, lo1, hi1, lo2, hi2, overlap
    cdef int o1 = _orient(p[a, 0], p[a, 1], p[b, 0], p[b, 1], p[c, 0], p[c, 1])
    cdef int o2 = _orient(p[a, 0], p[a, 1], p[b, 0], p[b, 1], p[d, 0], p[d, 1])
    cdef int o3 = _orient(p[c, 0], p[c, 1], p[d, 0], p[d, 1], p[a, 0], p[a, 1])
    cdef int o4 = _orient(p[c, 0], p[c, 1], p[d, 0], p[d, 1], p[b, 0], p[b, 1])
    cdef bint collinear = o1 == 0 and o2 == 0
    # collinear: compare the extents along the axis a-b runs along most
    k = 1 if _abs(p[b, 0] - p[a, 0]) < _abs(p[b, 1] - p[a, 1]) else 0
    lo1 = min(p[a, k], p[b, k]); hi1 = max(p[a, k], p[b, k])
    lo2 = min(p[c, k], p[d, k]); hi2 = max(p[c, k], p[d, k])
    overlap = min(hi1, hi2) - max(lo1, lo2)
    if a == c or a == d or b == c or b == d:
        # sharing an end point, two segments conflict only by running along each other
        return collinear and overlap > 0
    return (not collinear and o1 * o2 <= 0 and o3 * o4 <= 0) or (collinear and overlap >= 0)


def later_conflicts(const int64_t[:, ::1] points, const int64_t[:, ::1] segments, int64_t cell):
    """Mask over segments: True where an earlier segment meets it anywhere but at a
    shared end point (unfold.drop_conflicts drops those). Pairs are tested where their
    bounding boxes share a cell of a `cell`-pixel grid (two segments that meet always
    do), exactly. ValueError on an index out of range or coordinates below 0."""
    cdef int64_t n = segments.shape[0], m = points.shape[0], i, j, a, b, x, y, gx = 0, gy = 0, c, u, v
    if cell < 1 or (n and segments.shape[1] != 2) or (m and points.shape[1] != 2):
        raise ValueError("later_conflicts: N x 2 points, S x 2 segments, a cell of 1 or more")
    for i in range(n):
        for j in range(2):
            if segments[i, j] < 0 or segments[i, j] >= m:
                raise ValueError("later_conflicts: a segment names a point out of range")
    for i in range(m):
        if points[i, 0] < 0 or points[i, 1] < 0:
            raise ValueError("later_conflicts: a point has a negative coordinate")
        gx = max(gx, points[i, 0] // cell + 1)
        gy = max(gy, points[i, 1] // cell + 1)
    lo_a = np.zeros((n, 2), np.int64)
    hi_a = np.zeros((n, 2), np.int64)
    start_a = np.zeros(gx * gy + 1, np.int64)
    bad_a = np.zeros(n, bool)
    cdef int64_t[:, ::1] lo = lo_a, hi = hi_a
    cdef int64_t[::1] start = start_a
    cdef uint8_t[::1] bad = bad_a.view(np.uint8)
    cdef int64_t total = 0
    with nogil:
        # each segment in every cell its box covers: counted, then listed cell by cell
        for i in range(n):
            a = segments[i, 0]
            b = segments[i, 1]
            for j in range(2):
                lo[i, j] = min(points[a, j], points[b, j]) // cell
                hi[i, j] = max(points[a, j], points[b, j]) // cell
            for y in range(lo[i, 1], hi[i, 1] + 1):
                for x in range(lo[i, 0], hi[i, 0] + 1):
                    start[y * gx + x + 1] += 1
        for c in range(gx * gy):
            start[c + 1] += start[c]
        total = start[gx * gy]
    members_a = np.empty(total, np.int64)
    fill_a = start_a[:-1].copy()
    cdef int64_t[::1] members = members_a, fill = fill_a
    with nogil:
        for i in range(n):  # in order: each cell lists its segments in increasing order
            for y in range(lo[i, 1], hi[i, 1] + 1):
                for x in range(lo[i, 0], hi[i, 0] + 1):
                    members[fill[y * gx + x]] = i
                    fill[y * gx + x] += 1
        for c in range(gx * gy):
            for u in range(start[c], start[c + 1]):
                for v in range(u + 1, start[c + 1]):
                    j = members[v]
                    if not bad[j] and _conflict(points, segments, members[u], j):
                        bad[j] = 1
    return bad_a


def thin_split(uint8_t[::1] on, Py_ssize_t stride, const uint8_t[::1] redundant):
    """Thin a flat edge mask padded by one empty pixel all round (rows of `stride`) in
    place, as polylines.thin did with image filters: two passes, over the pixels with
    (x + y) % 2 == 0 and then 1 (padded coordinates), each removing at once every
    pixel of its colour whose 8-neighbourhood code (bit k: neighbour k of
    polylines._OFFSETS on, as the pass found them) is `redundant`. Returns (junction,
    simple) masks over the same pixels: the pixels left with three or more neighbours,
    and the others. Works over the mask's pixels only (an edge map is sparse).
    ValueError if the border is not empty or the table has not 256 entries."""
    cdef Py_ssize_t size = on.shape[0], rows, i, j, p, x, y, k, n = 0, removed
    cdef int code, count
    if stride < 3 or size % stride or size // stride < 3:
        raise ValueError("thin_split: a padded mask of at least 3 x 3")
    if redundant.shape[0] != 256:
        raise ValueError("thin_split: a table of 256 neighbourhood codes")
    rows = size // stride
    for x in range(stride):
        if on[x] or on[size - stride + x]:
            raise ValueError("thin_split: the mask's border must be empty")
    for y in range(rows):
        if on[y * stride] or on[y * stride + stride - 1]:
            raise ValueError("thin_split: the mask's border must be empty")
    # the neighbours in polylines._OFFSETS' order: (dy, dx) = (-1, -1), (-1, 0), (-1, 1),
    # (0, 1), (1, 1), (1, 0), (1, -1), (0, -1)
    cdef Py_ssize_t off[8]
    off[0] = -stride - 1; off[1] = -stride; off[2] = -stride + 1; off[3] = 1
    off[4] = stride + 1; off[5] = stride; off[6] = stride - 1; off[7] = -1
    # the edge pixels, row by row (an edge map is mostly empty: eight bytes tested at a
    # time), each with its colour (x + y) % 2
    cdef const uint8_t* o = &on[0]
    cdef uint64_t word
    with nogil:
        for y in range(1, rows - 1):
            for x in range(y * stride, y * stride + stride - 7, 8):
                memcpy(&word, o + x, 8)
                if word:
                    for k in range(x, x + 8):
                        n += o[k] != 0
            for x in range(y * stride + stride - stride % 8, y * stride + stride):
                n += o[x] != 0
    # one spare slot: each byte of a word is written and kept only if set (no branch)
    pixels_a = np.empty(n + 1, np.intp)
    colour_a = np.empty(n + 1, np.uint8)
    gone_a = np.empty(n, np.intp)
    junction_a = np.zeros(size, np.uint8)
    simple_a = np.zeros(size, np.uint8)
    cdef Py_ssize_t[::1] pixels = pixels_a, gone = gone_a
    cdef uint8_t[::1] junction = junction_a, simple = simple_a, colour = colour_a
    cdef int parity
    with nogil:
        j = 0
        for y in range(1, rows - 1):
            for x in range(y * stride, y * stride + stride - 7, 8):
                memcpy(&word, o + x, 8)
                if word:
                    for k in range(x, x + 8):
                        pixels[j] = k
                        colour[j] = (k - y * stride + y) & 1
                        j += o[k] != 0
            for x in range(y * stride + stride - stride % 8, y * stride + stride):
                pixels[j] = x
                colour[j] = (x - y * stride + y) & 1
                j += o[x] != 0
        for parity in range(2):
            # every code of the pass from the mask as the pass found it, then the removals
            # (kept or not without a branch: which pixels go is unpredictable)
            removed = 0
            for j in range(n):
                p = pixels[j]
                code = ((o[p + off[0]] != 0) | (o[p + off[1]] != 0) << 1 | (o[p + off[2]] != 0) << 2
                        | (o[p + off[3]] != 0) << 3 | (o[p + off[4]] != 0) << 4 | (o[p + off[5]] != 0) << 5
                        | (o[p + off[6]] != 0) << 6 | (o[p + off[7]] != 0) << 7)
                gone[removed] = p
                removed += (redundant[code] != 0) & (o[p] != 0) & (colour[j] == parity)
            for j in range(removed):
                on[gone[j]] = 0
        for j in range(n):
            p = pixels[j]
            count = ((o[p + off[0]] != 0) + (o[p + off[1]] != 0) + (o[p + off[2]] != 0) + (o[p + off[3]] != 0)
                     + (o[p + off[4]] != 0) + (o[p + off[5]] != 0) + (o[p + off[6]] != 0) + (o[p + off[7]] != 0))
            # both written for every listed pixel (0 where it is not so), without a branch
            junction[p] = (o[p] != 0) & (count >= 3)
            simple[p] = (o[p] != 0) & (count < 3)
    return junction_a.view(bool), simple_a.view(bool)


ctypedef fused gray_t:
    float
    double


def opposite_feet(const int64_t[:, ::1] points, const double[:, ::1] normal, const gray_t[:, ::1] gray,
                  int64_t reach, double min_step):
    """unfold.opposite_points for every control point P (N x 2 (x, y)) with its unit
    normal (N x 2), in one pass: on each side (+normal, then -normal) the pixels
    rint(P + s * k * normal), k = 1 .. reach, clipped to the image; the change |gray -
    gray[P]| of each (-1 where the pixel is P itself); the first at least max(half the
    side's largest change, min_step); the side whose hit comes first wins (ties: the
    larger change there; no hit on either side: the larger change at k = 1). Returns
    (left, right): P and its opposite point O, each on its side of the normal. The
    numpy code's arithmetic in gray's own precision, so the same pixels. ValueError
    on shapes that disagree or reach < 1."""
    cdef Py_ssize_t n = points.shape[0], h = gray.shape[0], w = gray.shape[1], i, k, s
    if normal.shape[0] != n or (n and (points.shape[1] != 2 or normal.shape[1] != 2)) or reach < 1 or h < 1 or w < 1:
        raise ValueError("opposite_feet: N x 2 points and normals, reach >= 1, a non-empty image")
    for i in range(n):
        if not (0 <= points[i, 0] < w and 0 <= points[i, 1] < h):
            raise ValueError("opposite_feet: a point outside the image")
    left_a = np.empty((n, 2), np.int64)
    right_a = np.empty((n, 2), np.int64)
    qs_a = np.empty((2, reach, 2), np.int64)
    cdef int64_t[:, ::1] left = left_a, right = right_a
    cdef int64_t[:, :, ::1] qs = qs_a
    cdef int64_t px, py, qx, qy, first[2], ia, ib, ox, oy
    cdef gray_t centre, change, biggest, limit, half = 0.5, floor_step = <gray_t>min_step
    cdef gray_t ch[2][64]
    cdef double sign, step, nx, ny
    cdef bint take_a, none
    if reach > 64:
        raise ValueError("opposite_feet: reach up to 64")
    with nogil:
        for i in range(n):
            px = points[i, 0]
            py = points[i, 1]
            nx = normal[i, 0]
            ny = normal[i, 1]
            centre = gray[py, px]
            for s in range(2):
                sign = 1.0 if s == 0 else -1.0
                biggest = 0
                for k in range(reach):
                    step = sign * <double>(k + 1)
                    qx = <int64_t>rint(<double>px + step * nx)
                    qy = <int64_t>rint(<double>py + step * ny)
                    qx = 0 if qx < 0 else (w - 1 if qx > w - 1 else qx)
                    qy = 0 if qy < 0 else (h - 1 if qy > h - 1 else qy)
                    qs[s, k, 0] = qx
                    qs[s, k, 1] = qy
                    change = gray[qy, qx] - centre
                    change = -change if change < 0 else change
                    if qx == px and qy == py:
                        change = -1
                    ch[s][k] = change
                    if k == 0 or change > biggest:
                        biggest = change
                limit = half * biggest
                if not limit >= floor_step:
                    limit = floor_step
                first[s] = reach
                for k in range(reach):
                    if ch[s][k] >= limit:
                        first[s] = k
                        break
            ia = first[0] if first[0] < reach - 1 else reach - 1
            ib = first[1] if first[1] < reach - 1 else reach - 1
            take_a = first[0] < first[1] or (first[0] == first[1] and ch[0][ia] >= ch[1][ib])
            none = first[0] == reach and first[1] == reach
            if none:
                take_a = ch[0][0] >= ch[1][0]
                ia = 0
                ib = 0
            if take_a:
                ox = qs[0, ia, 0]
                oy = qs[0, ia, 1]
            else:
                ox = qs[1, ib, 0]
                oy = qs[1, ib, 1]
            # the paper's swap (section 3.3.2.1): each polyline keeps the points on its side
            if <double>(ox - px) * nx + <double>(oy - py) * ny > 0:
                left[i, 0] = ox; left[i, 1] = oy; right[i, 0] = px; right[i, 1] = py
            else:
                left[i, 0] = px; left[i, 1] = py; right[i, 0] = ox; right[i, 1] = oy
    return left_a, right_a


def chain_walks(const int64_t[::1] flat, const int64_t[::1] chain, const uint8_t[::1] closed,
                const uint8_t[::1] junction, const int64_t[::1] offsets, const float[:, ::1] magnitude,
                int64_t stride):
    """Each chain's ends attached to the junction pixels beside them (as the paper
    does) and the chains' sums of squared gradient in one pass over order_chains' output (flat padded indices in chain order, the chain of each, closed
    per chain): each chain's pixels with, unless it is closed, the first junction pixel
    (in offset order) next to its first pixel before them and the one next to its last
    after them; a closed chain ends at its first pixel again. Returns (pixels, starts:
    chain c is pixels[starts[c]:starts[c + 1]], sums: per chain, the squares of
    `magnitude` (H x W, the unpadded image; as float64) added in pixel order, as
    np.bincount adds its weights). ValueError on inconsistent input."""
    cdef Py_ssize_t n = flat.shape[0], size = junction.shape[0], chains = closed.shape[0]
    cdef Py_ssize_t h = magnitude.shape[0], w = magnitude.shape[1]
    cdef Py_ssize_t i, j, c, k, a, b, q, p, out = 0
    cdef double m, total
    if chain.shape[0] != n or offsets.shape[0] != 8 or stride != w + 2 or size != (h + 2) * stride:
        raise ValueError("chain_walks: the arrays do not fit together")
    for k in range(8):
        if abs(offsets[k]) > stride + 1:
            raise ValueError("chain_walks: a neighbour offset beyond the 3 x 3 square")
    pixels_a = np.empty(n + 2 * chains, dtype=np.int64)
    starts_a = np.empty(chains + 1, dtype=np.int64)
    sums_a = np.zeros(chains, dtype=np.float64)
    cdef int64_t[::1] pixels = pixels_a, starts = starts_a
    cdef double[::1] sums = sums_a
    cdef const float* mag = &magnitude[0, 0] if h and w else NULL
    cdef bint bad = False
    with nogil:
        # every index is checked before it is read: the pixels lie inside the border
        for i in range(n):
            p = flat[i]
            # (inside the border: not in its rows, nor in its columns, which the row
            # bounds alone let through and whose magnitude would be another pixel's)
            if p < stride + 1 or p >= size - stride - 1 or p % stride == 0 or p % stride == stride - 1 \
                    or chain[i] < 0 or chain[i] >= chains \
                    or (i and chain[i] != chain[i - 1] and chain[i] != chain[i - 1] + 1) or (i == 0 and chain[0] != 0):
                bad = True
                break
        if not bad and n and chain[n - 1] != chains - 1:
            bad = True
        if not bad:
            a = 0
            for c in range(chains):
                b = a
                while b < n and chain[b] == c:
                    b += 1
                starts[c] = out
                if b > a and not closed[c]:
                    for k in range(8):
                        q = flat[a] + offsets[k]
                        if junction[q]:
                            pixels[out] = q
                            out += 1
                            break
                for j in range(a, b):
                    pixels[out] = flat[j]
                    out += 1
                if b > a:
                    if closed[c]:
                        pixels[out] = flat[a]
                        out += 1
                    else:
                        for k in range(8):
                            q = flat[b - 1] + offsets[k]
                            if junction[q]:
                                pixels[out] = q
                                out += 1
                                break
                total = 0.0
                for j in range(starts[c], out):
                    p = pixels[j]
                    m = <double>mag[(p // stride - 1) * w + (p % stride - 1)]
                    total += m * m
                sums[c] = total
                a = b
            starts[chains] = out
    if bad:
        raise ValueError("chain_walks: pixels outside the mask or chains out of order")
    return pixels_a[:out], starts_a, sums_a


cdef inline Py_ssize_t _slot(const int64_t* keys, Py_ssize_t mask, int64_t key) noexcept nogil:
    """The slot of `key` in an open-addressing table (linear probing; -1 marks a free
    slot): where it is, or the free slot where it goes."""
    cdef Py_ssize_t i = <Py_ssize_t>((<uint64_t>key * 0x9E3779B97F4A7C15ULL) >> 32) & mask
    while keys[i] != -1 and keys[i] != key:
        i = (i + 1) & mask
    return i


def wall_segments(const int64_t[:, ::1] left, const int64_t[:, ::1] right, const int64_t[::1] starts,
                  int64_t width, int64_t height):
    """unfold's walls before their conflicts are dropped, in one pass: the feet (left
    then right, N x 2 (x, y) each, N control points; polyline k is starts[k] ..
    starts[k + 1] - 1) merged one vertex a pixel, numbered in order of first
    appearance; each polyline's left wall's segments, then its right wall's, between
    its consecutive control points; a segment whose ends merged dropped, and a segment
    met before (either direction) kept only the first time. Returns (points M x 2,
    segments S x 2, wall of each: 2k left of polyline k, 2k + 1 its right).
    ValueError on feet outside the width x height image or starts that do not cover
    the N points in order."""
    cdef Py_ssize_t n = left.shape[0], lines = starts.shape[0] - 1, i, j, k, a, b, size, mask, slot
    cdef Py_ssize_t count = 0, nseg = 0
    cdef int64_t key, lo, hi, x, y
    if right.shape[0] != n or (n and (left.shape[1] != 2 or right.shape[1] != 2)) or lines < 0:
        raise ValueError("wall_segments: the feet and the polylines do not fit together")
    if offsets_fault(starts, lines, n) != OFFSETS_OK:
        raise ValueError("wall_segments: the polylines do not cover the control points")
    size = 16
    while size < 4 * n:  # at most 2n keys in each table: at most half full
        size *= 2
    mask = size - 1
    # one table for the pixels' keys (>= 0), one for the segments' keys; -1 is free
    keys_a = np.full(size, -1, dtype=np.int64)
    ids_a = np.empty(size, dtype=np.int64)
    pair_a = np.full(size, -1, dtype=np.int64)
    id_of_a = np.empty(2 * n, dtype=np.int64)
    points_a = np.empty((2 * n, 2), dtype=np.int64)
    segs_a = np.empty((2 * n, 2), dtype=np.int64)
    wall_a = np.empty(2 * n, dtype=np.int64)
    cdef int64_t[::1] keys = keys_a, ids = ids_a, pair = pair_a, id_of = id_of_a, wall = wall_a
    cdef int64_t[:, ::1] points = points_a, segs = segs_a
    cdef bint bad = False
    with nogil:
        for i in range(2 * n):
            x = left[i, 0] if i < n else right[i - n, 0]
            y = left[i, 1] if i < n else right[i - n, 1]
            if x < 0 or x >= width or y < 0 or y >= height:
                bad = True
                break
            key = y * width + x
            slot = _slot(&keys[0], mask, key)
            if keys[slot] == -1:
                keys[slot] = key
                ids[slot] = count
                points[count, 0] = x
                points[count, 1] = y
                count += 1
            id_of[i] = ids[slot]
        if not bad:
            for k in range(lines):
                for j in range(2):  # the left wall, then the right one
                    for i in range(starts[k], starts[k + 1] - 1):
                        a = id_of[j * n + i]
                        b = id_of[j * n + i + 1]
                        if a == b:
                            continue
                        lo = a if a < b else b
                        hi = b if a < b else a
                        slot = _slot(&pair[0], mask, lo * count + hi)
                        if pair[slot] != -1:
                            continue
                        pair[slot] = lo * count + hi
                        segs[nseg, 0] = a
                        segs[nseg, 1] = b
                        wall[nseg] = 2 * k + j
                        nseg += 1
    if bad:
        raise ValueError("wall_segments: a foot lies outside the image")
    return points_a[:count].copy(), segs_a[:nseg].copy(), wall_a[:nseg].copy()
