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

Implementation: each triangle is cut at its middle corner's row into two trapezoids;
the image is processed in bands of rows whose pixel count bounds the temporary memory.
In a band, every (trapezoid, row) pair gets its span [xs, xe) from exact ceil
divisions; the spans are put into raster order with a counting sort, which also proves
that they tile the band; then every pixel's 2*sum(w_i v_i) + D is evaluated from its
span's plane as ga*x + (gb*y + gc) and divided by 2D, all vectorised; no Python loop
runs per triangle or per pixel. The integers are held in float64, which is exact for
them (see _Trapezoids) and much faster than numpy's int64 division.
"""

from __future__ import annotations

import threading

import numpy as np

from .errors import CorruptError, UnsupportedError
from .mesh import Mesh

#: Pixels per band of rows; bounds the decoder's temporary memory (about 60 bytes each,
#: 40 of them kept per thread as reusable scratch).
BATCH_PIXELS = 1 << 16

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
    """Each triangle cut at its middle vertex's row into two trapezoids (empty ones
    dropped), each bounded by one left and one right edge, plus the plane of the
    triangle it comes from.

    Everything is float64 holding integers: for images of at most 2**32 pixels every
    number here and in _render_band stays below 2**53 (bounds in the comments), so the
    float arithmetic is exact integer arithmetic.
    """

    def __init__(self, mesh: Mesh) -> None:
        h, c = mesh.height, mesh.channels
        t0, t1, t2 = np.asarray(mesh.triangles, dtype=np.int64).T
        vx = mesh.vertices[:, 0].astype(np.float64)
        vy = mesh.vertices[:, 1].astype(np.float64)
        y0, y1, y2 = vy[t0], vy[t1], vy[t2]
        # rotate each corner triple so the top corner A comes first; the orientation
        # (clockwise on screen) then puts P1 on the right chain and P2 on the left
        # (1-D arrays throughout: numpy is slow along short axes)
        top0 = (y0 <= y1) & (y0 <= y2)
        top1 = ~top0 & (y1 <= y2)
        a = np.where(top0, t0, np.where(top1, t1, t2))
        p1 = np.where(top0, t1, np.where(top1, t2, t0))
        p2 = np.where(top0, t2, np.where(top1, t0, t1))
        ax, ay, p1x, p1y, p2x, p2y = vx[a], vy[a], vx[p1], vy[p1], vx[p2], vy[p2]
        ymid = np.minimum(p1y, p2y)
        ybot = np.maximum(p1y, p2y)
        # owned rows: ay <= y < ybot, plus ybot itself on the image's last row
        yend = ybot + (ybot == h - 1)
        flat_bottom = ymid == ybot
        m = len(a)
        # trapezoid rows: upper [ay, ymid) (to yend if the bottom is flat), lower [ymid, yend)
        first = np.concatenate([ay, ymid])
        count = np.concatenate([np.where(flat_bottom, yend, ymid) - ay,
                                np.where(flat_bottom, 0, yend - ymid)])
        keep = np.flatnonzero(count > 0)
        tri = np.concatenate([np.arange(m), np.arange(m)])[keep]
        self.first = first[keep]
        self.count = count[keep].astype(np.int64)
        # bounding edges P -> Q: upper A->P2 | A->P1; lower A->P2 | P1->P2 when P1 is
        # the middle corner, else P2->P1 | A->P1
        p1_mid = p1y < p2y

        def pick(upper: np.ndarray, if_p1_mid: np.ndarray, otherwise: np.ndarray) -> np.ndarray:
            return np.concatenate([upper, np.where(p1_mid, if_p1_mid, otherwise)])[keep]

        def edge(px, py, qx, qy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            den = np.maximum(qy - py, 1.0)  # a flat edge never bounds a non-empty row range
            dx = qx - px
            # x on row y is (px*den + dx*(y - py)) / den: |numerator| <= W*H
            return px * den + dx * (self.first - py), dx, den

        self.lnum, self.ldx, self.lden = edge(
            pick(ax, ax, p2x), pick(ay, ay, p2y), pick(p2x, p2x, p1x), pick(p2y, p2y, p1y)
        )
        self.rnum, self.rdx, self.rden = edge(
            pick(ax, p1x, ax), pick(ay, p1y, ay), pick(p1x, p2x, p1x), pick(p1y, p2y, p1y)
        )
        # the plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc per channel; at corner A the
        # weights are (D, 0, 0), which gives gc. |ga|, |gb| < 2**18 max(W, H) and
        # |ga*x|, |gb*y|, |gc| < 2**52 (channel-major so each channel is contiguous)
        vals = mesh.values.astype(np.float64).reshape(len(vx), c).T  # C x N
        va, v1, v2 = vals[:, a], vals[:, p1], vals[:, p2]
        ga = 2 * ((p1y - p2y) * va + (p2y - ay) * v1 + (ay - p1y) * v2)
        gb = 2 * ((p2x - p1x) * va + (ax - p2x) * v1 + (p1x - ax) * v2)
        d = (p1x - ax) * (p2y - ay) - (p2x - ax) * (p1y - ay)
        gc = (2 * va + 1) * d - ga * ax - gb * ay
        self.ga, self.gb, self.gc = ga[:, tri], gb[:, tri], gc[:, tri]
        self.d2 = 2 * d[tri]


def _render_band(tz: _Trapezoids, sel: np.ndarray | None, r0: int, r1: int, width: int,
                 out: np.ndarray) -> None:
    """Write rows r0..r1-1 of `out` (H*W x C) from trapezoids `sel` (None: all of them,
    when the band is the whole image)."""
    npix = (r1 - r0) * width
    if sel is None:
        n = tz.count
        seg = np.repeat(np.arange(len(n)), n)  # trapezoid of each (trapezoid, row) pair
        g = seg
        base = (np.cumsum(n) - n).astype(np.float64)
    else:
        # clip the trapezoids' row ranges to the band
        first = tz.first[sel]
        start = np.maximum(first, r0)
        n = (np.minimum(first + tz.count[sel], r1) - start).astype(np.int64)
        keep = n > 0
        live, n = sel[keep], n[keep]
        base = np.cumsum(n) - n - (start - first)[keep]
        seg = np.repeat(np.arange(len(n)), n)
        g = np.take(live, seg)
    # k: the pair's row offset in its trapezoid
    k = np.arange(len(seg), dtype=np.float64)
    k -= np.take(base, seg)
    # exact span ends: ceil of (integer numerator <= W*H) / (denominator <= H)
    lnum = np.take(tz.ldx, g)
    lnum *= k
    lnum += np.take(tz.lnum, g)
    rnum = np.take(tz.rdx, g)
    rnum *= k
    rnum += np.take(tz.rnum, g)
    xs = lnum / np.take(tz.lden, g)
    np.ceil(xs, out=xs)
    rden = np.take(tz.rden, g)
    xe = rnum / rden
    np.ceil(xe, out=xe)
    # the last column belongs to a span that reaches it with positive length
    cand = np.flatnonzero(xe == width - 1)
    if len(cand):
        cand = cand[rnum[cand] == (width - 1) * rden[cand]]
        cand = cand[lnum[cand] < (width - 1) * np.take(tz.lden, np.take(g, cand))]
        xe[cand] = width
    xe -= xs  # span lengths
    keep = np.flatnonzero(xe > 0)
    # the band row of each pair, and the band pixel where each non-empty span starts
    y = np.take(tz.first, g)
    y += k
    g = np.take(g, keep)
    y = np.take(y, keep)
    xs = np.take(xs, keep)
    length = np.take(xe, keep)
    key = (y - r0) * width
    key += xs
    key = key.astype(np.int64)
    spans = len(key)
    # counting sort of the spans into raster order; a repeated start means an overlap
    marker = _scratch("marker", npix, bool)
    marker.fill(False)
    marker[key] = True
    slot = _scratch("slot", npix, np.int64)
    slot[key] = np.arange(spans)
    where = np.flatnonzero(marker)
    if len(where) != spans:
        _fail(int(np.flatnonzero(np.bincount(key) > 1)[0]), r0, width, "covers it twice")
    order = np.take(slot, where)
    length = np.take(length, order).astype(np.int64)
    ends = np.cumsum(length)
    # tiling check: each span starts where the previous one ended, the last ends the band
    if spans == 0 or where[0] != 0 or ends[-1] != npix or (where[1:] != ends[:-1]).any():
        _tiling_error(where, ends, npix, r0, width)
    # per span in raster order: its trapezoid, row and the plane's row constant
    g = np.take(g, order)
    y = np.take(y, order)
    d2 = np.take(tz.d2, g)
    # per band pixel: its span (the number of span starts up to it, minus one) and its
    # column; the per-pixel arrays are reused scratch, since fresh pages cost more
    # than the arithmetic on them
    pseg = np.cumsum(marker, dtype=np.int64, out=_scratch("pseg", npix, np.int64))
    pseg -= 1
    col = _columns(width, r1 - r0)
    dr = np.take(d2, pseg, out=_scratch("dr", npix, np.float64), mode="clip")
    num = _scratch("num", npix, np.float64)
    tmp = _scratch("tmp", npix, np.float64)
    band = out[r0 * width:r1 * width]
    for ch in range(out.shape[1]):  # a loop over channels
        # numerator ga*x + (gb*y + gc): every term and partial sum below 2**52
        row_const = np.take(tz.gb[ch], g)
        row_const *= y
        row_const += np.take(tz.gc[ch], g)
        np.take(np.take(tz.ga[ch], g), pseg, out=num, mode="clip")  # indices are valid
        num *= col
        num += np.take(row_const, pseg, out=tmp, mode="clip")
        # num and dr are integers below 2**53 and dr < 2**36: the correctly rounded
        # quotient is exact when integral, and otherwise more than its rounding error
        # (< 2**-36 for quotients below 2**17) away from the next integer, so floor()
        # of it is the exact floor((2 sum w_i v_i + D) / 2D); values are >= 0, so the
        # truncating cast below is that floor
        num /= dr
        np.copyto(band[:, ch], num, casting="unsafe")


_local = threading.local()


def _scratch(name: str, n: int, dtype) -> np.ndarray:
    """A reusable per-thread array of n items (contents undefined), at most a band."""
    bufs = _local.__dict__.setdefault("bufs", {})
    buf = bufs.get(name)
    if buf is None or len(buf) < n:
        buf = bufs[name] = np.empty(n, dtype)
    return buf[:n]


def _columns(width: int, rows: int) -> np.ndarray:
    """The column number of every pixel of a band `rows` x `width`, as float64 (a
    prefix of a cached ramp, so the last, shorter band reuses it)."""
    cols = _local.__dict__.get("cols")
    if cols is None or cols[0] != width or len(cols[1]) < rows * width:
        cols = (width, np.tile(np.arange(width, dtype=np.float64), rows))
        _local.cols = cols
    return cols[1][:rows * width]


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
    if w * h > 1 << 32:
        # keeps every intermediate below the float64-exact bounds stated above
        raise UnsupportedError(f"a {w}x{h} image is too large for the CPU decoder")
    tz = _Trapezoids(mesh)
    out = np.empty((h * w, c), dtype=mesh.dtype)
    band_rows = max(1, BATCH_PIXELS // w)
    if band_rows >= h:
        _render_band(tz, None, 0, h, w, out)
    else:
        # bucket trapezoids by band: each joins every band its rows touch
        first = tz.first.astype(np.int64)
        b0 = first // band_rows
        b1 = (first + tz.count - 1) // band_rows
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
