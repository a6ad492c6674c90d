"""CPU decoder: exact integer scanline rasterisation of the mesh.

Decoding rule (normative, see format_spec/ATM.md "Decoding"). Vertex (x, y) is the
centre of pixel (row y, column x). A pixel p inside triangle (p0, p1, p2) with doubled
area D > 0 has the integer edge-function weights

    w_i = (x_k - x_j)(y - y_j) - (y_k - y_j)(x - x_j),   j = i+1, k = i+2 (mod 3),

with w_0 + w_1 + w_2 = D, and for each channel its value is

    floor((2 * sum_i w_i v_i + D) / (2 D))       (round half up of sum w_i v_i / D),

clipped to the dtype. Because every vertex and pixel centre is an integer point this is
exact, and a pixel on an edge shared by two triangles gets the same value from either.

Ownership rule (which triangle writes a pixel): the top-left rule, with the image's
right and bottom borders included. Pixel p belongs to the one triangle that contains
the point p + (sx*e, sy*e*e) for an infinitesimal e > 0, where sx = +1 except in the
last column (sx = -1) and sy = +1 except in the last row (sy = -1). In scanline terms,
with [xl, xr] the triangle's exact cross-section on row y:

* row y is the triangle's if ymin <= y < ymax, or if y = ymax = H - 1;
* column x of such a row is the triangle's if xl <= x < xr, or if xl < x = xr = W - 1.

For a mesh that tiles the image (what mesh.validate checks, plus no overlaps) every
pixel is thus written exactly once. The decoder checks that the spans tile each band of
rows exactly and raises CorruptError otherwise (a pixel uncovered, or covered twice).

Implementation: the image is processed in bands of rows whose pixel count bounds the
temporary memory. In a band, every (triangle, row) pair gets its span [xs, xe) from
exact ceil divisions; the spans are put into raster order with a counting sort, which
also proves that they tile the band; then every pixel's 2*sum(w_i v_i) + D is evaluated
from the plane of its span as G + a * p (p the pixel's index in the band), all
vectorised; no Python loop runs per triangle or per pixel.
"""

from __future__ import annotations

import numpy as np

from .errors import CorruptError, UnsupportedError
from .mesh import Mesh

#: Pixels per band of rows; bounds the decoder's temporary memory (about 40 bytes each).
BATCH_PIXELS = 1 << 20

# float64 holds every integer below 2**53 exactly; the fast path evaluates the exact
# integer numerators in float64 when they provably stay below this bound, and the
# division is then exact too (see _divide_floor).
_FLOAT_EXACT = float(2**52)


def _round_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Exact round-half-up of num / den for den > 0 (integer arrays)."""
    return (2 * num + den) // (2 * den)


def _finish(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(values, info.min, info.max).astype(dtype)


def _ceil_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """ceil(num / den) for integer arrays with den > 0."""
    return -((-num) // den)


def render_line(mesh: Mesh) -> np.ndarray:
    """Decode a mesh of an image one pixel high or wide (no triangles)."""
    w, h = mesh.width, mesh.height
    along = mesh.vertices[:, 0] if h == 1 else mesh.vertices[:, 1]
    order = np.argsort(along, kind="stable")
    s = along[order].astype(np.int64)
    vals = mesh.values[order].astype(np.int64).reshape(len(s), -1)
    n = max(w, h)
    p = np.arange(n, dtype=np.int64)
    if len(s) == 1:
        out = np.repeat(vals, n, axis=0)
    else:
        k = np.clip(np.searchsorted(s, p, side="right") - 1, 0, len(s) - 2)
        a, b = s[k], s[k + 1]
        num = vals[k] * (b - p)[:, None] + vals[k + 1] * (p - a)[:, None]
        out = _round_div(num, (b - a)[:, None])
    shape = (h, w) if mesh.channels == 1 else (h, w, mesh.channels)
    return _finish(out, mesh.dtype).reshape(shape)


class _Trapezoids:
    """Each triangle cut at its middle vertex's row into two trapezoids (one may be
    empty), each bounded by one left and one right edge, as float64 arrays.

    Every number here is an integer far below 2**53, so float64 holds it exactly and
    the float arithmetic below is exact integer arithmetic (bounds in the comments).
    """

    def __init__(self, mesh: Mesh) -> None:
        w, h, c = mesh.width, mesh.height, mesh.channels
        v = mesh.vertices.astype(np.int64)
        t = np.asarray(mesh.triangles, dtype=np.int64)
        # rotate each corner triple so the top corner A comes first; the orientation
        # (clockwise on screen) then puts P1 on the right chain and P2 on the left
        top = np.argmin(v[t, 1], axis=1)
        t = np.take_along_axis(t, (top[:, None] + np.arange(3)) % 3, axis=1)
        x, y = v[t, 0], v[t, 1]
        ax, ay, p1x, p1y, p2x, p2y = x[:, 0], y[:, 0], x[:, 1], y[:, 1], x[:, 2], y[:, 2]
        ymid = np.minimum(p1y, p2y)
        ybot = np.maximum(p1y, p2y)
        # owned rows: ay <= y < ybot, plus ybot itself on the image's last row
        yend = ybot + (ybot == h - 1)
        flat_bottom = ymid == ybot
        upper_end = np.where(flat_bottom, yend, ymid)
        p1_mid = p1y < p2y
        # edges (P -> Q with Qy >= Py) of the upper and lower trapezoids
        up_l = (ax, ay, p2x, p2y)
        up_r = (ax, ay, p1x, p1y)
        lo_l = tuple(np.where(p1_mid, a, b) for a, b in zip((ax, ay, p2x, p2y), (p2x, p2y, p1x, p1y)))
        lo_r = tuple(np.where(p1_mid, a, b) for a, b in zip((p1x, p1y, p2x, p2y), (ax, ay, p1x, p1y)))
        lo_start = ymid
        lo_end = np.where(flat_bottom, ymid, yend)
        tri = np.arange(len(t))
        first = np.concatenate([ay, lo_start])
        count = np.concatenate([upper_end - ay, lo_end - lo_start])
        keep = count > 0
        self.first = first[keep].astype(np.float64)
        self.count = count[keep].astype(np.int64)
        self.tri = np.concatenate([tri, tri])[keep]

        def edge(left: tuple, right: tuple) -> tuple:
            px, py, qx, qy = (np.concatenate([a, b])[keep] for a, b in zip(left, right))
            den = np.maximum(qy - py, 1)  # a flat edge never bounds a non-empty row range
            dx = qx - px
            # x on row y is (px*den + dx*(y - py)) / den: |numerator| <= W*H
            num0 = px * den + dx * (self.first.astype(np.int64) - py)
            return num0.astype(np.float64), dx.astype(np.float64), den.astype(np.float64)

        self.lnum, self.ldx, self.lden = edge(up_l, lo_l)
        self.rnum, self.rdx, self.rden = edge(up_r, lo_r)
        # the plane of 2*sum(w_i v_i) + D per channel, as T(x, y) = ta + ga*(x - ax) +
        # gb*(y - ay); at corner A the weights are (D, 0, 0), so ta = (2 vA + 1) D
        vals = mesh.values.astype(np.int64).reshape(len(v), c)
        d = (p1x - ax) * (p2y - ay) - (p2x - ax) * (p1y - ay)
        ga = np.zeros((len(t), c), np.int64)
        gb = np.zeros((len(t), c), np.int64)
        for i in range(3):  # the three corners, not a per-triangle loop
            j, k = (i + 1) % 3, (i + 2) % 3
            vi = vals[t[:, i]]
            ga -= (y[:, k] - y[:, j])[:, None] * vi
            gb += (x[:, k] - x[:, j])[:, None] * vi
        # |ga|, |gb| <= 4 * 65535 * max(W, H); |ta| <= 2**17 * 2 W H
        ta = (2 * vals[t[:, 0]] + 1) * d[:, None]
        #: per triangle: ax, ay, 2D, ga (C), gb (C), ta (C), gathered in one go per span
        self.plane = np.concatenate(
            [ax[:, None], ay[:, None], 2 * d[:, None], 2 * ga, 2 * gb, ta], axis=1
        ).astype(np.float64)


def _render_band(tz: _Trapezoids, sel: np.ndarray | None, r0: int, r1: int, width: int,
                 out: np.ndarray) -> None:
    """Write rows r0..r1-1 of `out` (H*W x C) from trapezoids `sel` (None: all of them,
    when the band is the whole image)."""
    npix = (r1 - r0) * width
    if sel is None:
        live, n, skip = np.arange(len(tz.count)), tz.count, 0.0
        base = np.cumsum(n) - n
    else:
        # clip the trapezoids' row ranges to the band
        first = tz.first[sel]
        start = np.maximum(first, r0)
        n = (np.minimum(first + tz.count[sel], r1) - start).astype(np.int64)
        keep = n > 0
        live, n, skip = sel[keep], n[keep], (start - first)[keep]
        base = np.cumsum(n) - n - skip
    rows_total = int(n.sum())
    # one (trapezoid, row) pair per owned row; k is the row's offset in its trapezoid
    seg = np.repeat(np.arange(len(n)), n)
    k = np.arange(rows_total, dtype=np.float64)
    k -= np.take(base.astype(np.float64), seg)
    g = np.take(live, seg)
    # exact span ends: ceil of (integer numerator <= W*H) / (denominator <= H)
    lnum = np.take(tz.ldx, g)
    lnum *= k
    lnum += np.take(tz.lnum, g)
    rnum = np.take(tz.rdx, g)
    rnum *= k
    rnum += np.take(tz.rnum, g)
    rden = np.take(tz.rden, g)
    xs = lnum / np.take(tz.lden, g)
    np.ceil(xs, out=xs)
    xe = rnum / rden
    np.ceil(xe, out=xe)
    # the last column belongs to a span that reaches it with positive length
    cand = np.flatnonzero(xe == width - 1)
    if len(cand):
        rc = cand[rnum[cand] == (width - 1) * rden[cand]]
        rc = rc[lnum[rc] < (width - 1) * np.take(tz.lden, np.take(g, rc))]
        xe[rc] = width
    length = xe - xs
    keep = np.flatnonzero(length > 0)
    # first band pixel of each non-empty span
    key = np.take(tz.first, g)
    key += k
    key -= r0
    key *= width
    key += xs
    key = np.take(key, keep).astype(np.int64)
    length = np.take(length, keep)
    g = np.take(g, keep)
    spans = len(key)
    # counting sort of the spans into raster order; a repeated start means an overlap
    marker = np.zeros(npix, dtype=bool)
    marker[key] = True
    slot = np.empty(npix, dtype=np.int64)
    slot[key] = np.arange(spans)
    where = np.flatnonzero(marker)
    if len(where) != spans:
        _fail(int(np.flatnonzero(np.bincount(key) > 1)[0]), r0, width, "covers it twice")
    order = np.take(slot, where)
    length = np.take(length, order)
    ends = np.cumsum(length)
    # tiling check: each span starts where the previous one ended, the last ends the band
    bad = np.flatnonzero(where[1:] != ends[:-1])
    if len(bad) or spans == 0 or where[0] != 0 or ends[-1] != npix:
        _tiling_error(where, ends, npix, r0, width)
    # per span, in raster order: its triangle and the numerator at its first pixel
    tri = np.take(tz.tri, np.take(g, order))
    keyf = where.astype(np.float64)
    y, xs = np.divmod(keyf, width)
    y += r0
    pl = np.take(tz.plane, tri, axis=0)  # ax, ay, 2D, then ga, gb, ta per channel
    c = out.shape[1]
    ga, gb, ta = pl[:, 3:3 + c], pl[:, 3 + c:3 + 2 * c], pl[:, 3 + 2 * c:]
    t0 = ga * (xs - pl[:, 0])[:, None]
    t0 += gb * (y - pl[:, 1])[:, None]
    t0 += ta
    # numerator at band pixel p: t0 + ga*(p - key) = (t0 - ga*key) + ga*p; the folded
    # form saves a pass but needs |ga|*npix and |t0 - ga*key| below 2**52 to be exact
    g0 = t0 - ga * keyf[:, None]
    fold = float(np.abs(ga).max(initial=0)) * npix + float(np.abs(g0).max(initial=0)) < _FLOAT_EXACT
    # the span of each band pixel
    pseg = np.repeat(np.arange(spans), length.astype(np.int64))
    p = np.arange(npix, dtype=np.float64)
    if not fold:
        p -= np.take(keyf, pseg)
        g0 = t0
    dr = np.take(pl[:, 2], pseg)
    band = out[r0 * width:r1 * width]
    for ch in range(c):  # a loop over channels
        num = np.take(np.ascontiguousarray(ga[:, ch]), pseg)
        num *= p
        num += np.take(np.ascontiguousarray(g0[:, ch]), pseg)
        # num and dr are integers below 2**53 and dr < 2**36: the correctly rounded
        # quotient is exact when integral, and otherwise more than its rounding error
        # (< 2**-36 for quotients below 2**17) away from the next integer, so floor()
        # of it is the exact floor((2 sum w_i v_i + D) / 2D)
        num /= dr
        np.floor(num, out=num)
        np.copyto(band[:, ch], num, casting="unsafe")


def _tiling_error(where: np.ndarray, ends: np.ndarray, npix: int, r0: int, width: int) -> None:
    """Raise CorruptError naming the first pixel the sorted spans miss or repeat."""
    expected = np.concatenate([[0], ends[:-1]]).astype(np.int64)
    bad = np.flatnonzero(where != expected)
    if len(bad):
        i = int(bad[0])
        if where[i] > expected[i]:
            _fail(int(expected[i]), r0, width, "leaves it uncovered")
        _fail(int(where[i]), r0, width, "covers it twice")
    end = int(ends[-1]) if len(ends) else 0
    if end < npix:
        _fail(end, r0, width, "leaves it uncovered")
    _fail(npix - 1, r0, width, "covers it twice")


def _segments(lengths: np.ndarray, total: int) -> np.ndarray:
    """Index of the run each of `total` items falls in, for runs of `lengths` (> 0)."""
    marks = np.zeros(total, dtype=np.int32)
    marks[np.cumsum(lengths[:-1])] = 1
    return np.cumsum(marks, out=marks)


def _fail(pixel: int, r0: int, width: int, what: str) -> None:
    raise CorruptError(
        f"the mesh {what}: pixel (row {r0 + pixel // width}, column {pixel % width})"
    )


def render(mesh: Mesh) -> np.ndarray:
    """Decode a validated mesh to an image of its dtype and channel count."""
    if len(mesh.triangles) == 0:
        return render_line(mesh)
    w, h, c = mesh.width, mesh.height, mesh.channels
    if w * h >= 1 << 34:
        # keeps every intermediate below the float64-exact bounds stated above
        raise UnsupportedError(f"a {w}x{h} image is too large for the CPU decoder")
    tz = _Trapezoids(mesh)
    out = np.empty((h * w, c), dtype=mesh.dtype)
    band_rows = max(1, BATCH_PIXELS // w)
    if band_rows >= h:
        _render_band(tz, None, 0, h, w, out)
    else:
        # bucket trapezoids by band: each joins every band its rows touch
        b0 = tz.first.astype(np.int64) // band_rows
        b1 = (tz.first.astype(np.int64) + tz.count - 1) // band_rows
        per = b1 - b0 + 1
        trap = np.repeat(np.arange(len(b0)), per)
        band = b0[trap] + np.arange(len(trap)) - np.repeat(np.cumsum(per) - per, per)
        nb = (h + band_rows - 1) // band_rows
        # a stable radix sort when the band numbers fit 16 bits
        order = np.argsort(band.astype(np.int16 if nb < 1 << 15 else np.int64), kind="stable")
        trap, band = trap[order], band[order]
        cuts = np.searchsorted(band, np.arange(nb + 1))
        for b in range(nb):  # a loop over memory-bounding bands
            r0, r1 = b * band_rows, min(h, (b + 1) * band_rows)
            _render_band(tz, trap[cuts[b]:cuts[b + 1]], r0, r1, w, out)
    # no clipping needed: in a triangle every value is a convex combination of values of
    # the dtype, and round-half-up of such a mean stays within the dtype
    shape = (h, w) if c == 1 else (h, w, c)
    return out.reshape(shape)
