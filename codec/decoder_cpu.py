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

For a mesh that tiles the image (what mesh.validate checks) every pixel is thus written
exactly once. The decoder still checks that the spans tile each band of rows exactly,
for meshes handed to it unvalidated, and raises CorruptError otherwise (a pixel
uncovered, or covered twice).

Implementation, all vectorised (no Python loop runs per triangle, span or pixel):

* the vertices are numbered in raster order (decoded meshes come that way) and each
  triangle's corners sorted into top T, middle M and bottom B (_Corners);
* the image is processed in bands of rows whose pixel count bounds the temporary
  memory (one band for images up to BATCH_PIXELS), each with the triangles that have
  rows in it. Per triangle of a band (_Triangles): the rows it owns, its three edges
  as lines and the plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc of each channel;
* every (triangle, row) pair gets its span [xs, xe) from its left and right edge:
  each edge is a float64 line in the band's pixel numbering whose ceiling is provably
  the exact one, so it gives the pixel where the span starts or ends directly, with
  no division;
* a counting sort puts the spans into raster order: a marker at each span's first
  pixel, and OpenCV's integral (an exact prefix count) of the markers gives every
  pixel the rank of its span. The same markers prove that the spans tile the band;
* each pixel's value is its span's a*x + b, truncated, where a = ga/2D and
  b = (gb*y + gc)/2D + 1/(4|D|), which float64 evaluates with an error too small to
  change the floor (see _Triangles; images too large for that bound use the integer
  numerator ga*x + gb*y + gc and an exact float64 division per pixel instead).

The arrays the size of a band (its pixels, pairs, spans and triangles) and, for meshes
of up to _KEEP_TRIANGLES triangles, those the size of the mesh are per-thread scratch
reused from call to call, since fresh pages cost more than the arithmetic on them.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from .errors import CorruptError, UnsupportedError
from .mesh import Mesh

#: Pixels per band of rows; bounds the decoder's temporary memory, which is kept per
#: thread as reusable scratch (about 80 bytes per band pixel for typical meshes, some
#: 20 MB).
BATCH_PIXELS = 1 << 18
#: Pixels per chunk of the last, per-pixel stage (its arrays then stay in cache).
_CHUNK = 1 << 15
#: The divided plane is exact while W*H*(69*(vmax + 1) + 2**19) stays below this (see
#: _Triangles): for every 8-bit image, and 16-bit ones up to about 890 megapixels.
_DIVIDED_PLANE_LIMIT = 1 << 52
#: Largest mesh whose mesh-wide arrays (about 80 bytes per triangle) are kept as
#: per-thread scratch between calls; larger meshes allocate them afresh.
_KEEP_TRIANGLES = 1 << 17


def _round_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Exact round-half-up of num / den for den > 0 (integer arrays)."""
    return (2 * num + den) // (2 * den)


def _finish(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(values, info.min, info.max).astype(dtype)


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


class _Corners:
    """The mesh's vertices numbered in raster order (as decoded meshes come), and each
    triangle's corners T, M, B in raster order: its smallest, middle and largest vertex
    number `it`, `im`, `ib`. Per-thread scratch for meshes of up to _KEEP_TRIANGLES
    triangles."""

    def __init__(self, mesh: Mesh) -> None:
        w = mesh.width
        nv, m = len(mesh.vertices), len(mesh.triangles)
        keep = m <= _KEEP_TRIANGLES

        def buf(name: str, dtype, n: int = m) -> np.ndarray:
            return _scratch("c_" + name, n, dtype) if keep else np.empty(n, dtype)

        self.vx = buf("vx", np.float64, nv)
        self.vy = buf("vy", np.float64, nv)
        np.copyto(self.vx, mesh.vertices[:, 0], casting="unsafe")
        np.copyto(self.vy, mesh.vertices[:, 1], casting="unsafe")
        vals = mesh.values.reshape(nv, mesh.channels)
        t = mesh.triangles
        key = np.multiply(self.vy, w, out=buf("key", np.float64, nv))
        key += self.vx
        if not np.less(key[:-1], key[1:], out=buf("sorted", np.bool_, nv)[:nv - 1]).all():
            order = np.argsort(key, kind="stable")
            rank = np.empty_like(order)
            rank[order] = np.arange(nv)
            t = rank[t]
            self.vx, self.vy, vals = self.vx[order], self.vy[order], vals[order]
        # the samples as float64, channel-major (each channel contiguous)
        self.vals = buf("vals", np.float64, vals.size).reshape(vals.shape[::-1])
        np.copyto(self.vals, vals.T, casting="unsafe")
        t0, t1, t2 = t[:, 0], t[:, 1], t[:, 2]
        self.it = np.minimum(t0, t1, out=buf("it", np.int64))
        np.minimum(self.it, t2, out=self.it)
        self.ib = np.maximum(t0, t1, out=buf("ib", np.int64))
        np.maximum(self.ib, t2, out=self.ib)
        self.im = np.add(t0, t1, out=buf("im", np.int64))
        self.im += t2
        self.im -= self.it
        self.im -= self.ib


def _owned_rows(ty: np.ndarray, my: np.ndarray, by: np.ndarray, h: int, buf) -> tuple:
    """(first, count, none, flat_bottom): the rows of each triangle, from the rows of T,
    M and B. Owned rows: ty <= y < by, plus by on the image's last row. A pointed top's
    first row is empty (just T), and so is a pointed bottom's last: rows ty+1 (ty if
    the top is flat) to by-1 (by on the last row if the bottom is flat). A triangle
    left without rows (height 1, flat bottom) gets one (`none`), kept empty."""
    b1 = np.bool_
    flat_bottom = np.equal(by, my, out=buf("flat_bottom", b1))
    first = np.add(ty, 1, out=buf("first", np.float64))
    first -= np.equal(my, ty, out=buf("flat_top", b1))
    count = np.subtract(by, first, out=buf("rows", np.float64))
    if by.max() == h - 1:
        count += flat_bottom & np.equal(by, h - 1, out=buf("last", b1))
    none = np.equal(count, 0, out=buf("none", b1))
    count = np.maximum(count, 1, out=count)
    return first, count, none, flat_bottom


class _Triangles:
    """Per triangle (of `sel`, or all), with its corners T, M and B: the rows it owns
    (`first`, `count`), its edges T -> B, T -> M and M -> B as lines and its plane, in
    per-thread scratch. float64 throughout: integers below 2**53 are exact, and the
    rounding of the rest is bounded where it is used.
    """

    def __init__(self, mesh: Mesh, corners: _Corners, sel: np.ndarray | None) -> None:
        w, h, c = mesh.width, mesh.height, mesh.channels
        f8, i8, b1 = np.float64, np.int64, np.bool_

        def buf(name: str, dtype=f8, n: int | None = None) -> np.ndarray:
            return _scratch("t_" + name, m if n is None else n, dtype)

        if sel is None:
            it, im, ib = corners.it, corners.im, corners.ib
        else:
            it, im, ib = (
                np.take(i, sel, out=_scratch("t_" + name, len(sel), i8), mode="clip")
                for i, name in ((corners.it, "it"), (corners.im, "im"), (corners.ib, "ib")))
        m = len(it)
        vx, vy = corners.vx, corners.vy
        tx, ty, mx, my, bx, by = (
            np.take(v, i, out=buf(name), mode="clip")
            for v, i, name in ((vx, it, "tx"), (vy, it, "ty"), (vx, im, "mx"),
                               (vy, im, "my"), (vx, ib, "bx"), (vy, ib, "by")))
        dxm, dym, dxb, dyb, dxl, dyl = (
            np.subtract(p, q, out=buf(name))
            for p, q, name in ((mx, tx, "dxm"), (my, ty, "dym"), (bx, tx, "dxb"),
                               (by, ty, "dyb"), (bx, mx, "dxl"), (by, my, "dyl")))
        tmp = buf("tmp")
        # The plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc of each channel, with the
        # weights and D of the corner order (T, M, B): of either orientation, since
        # negating all of them leaves (2*sum(w_i v_i) + D) / 2D unchanged. At T the
        # weights are (D, 0, 0), which gives gc. |ga| <= 4 H vmax, |gb| <= 4 W vmax,
        # |gc| < 14 W H (vmax + 1): below 2**52 (as W*H <= 2**32), like every partial
        # sum here, so all of it is exact integer arithmetic.
        d = np.multiply(dxm, dyb, out=buf("d"))
        d -= np.multiply(dxb, dym, out=tmp)
        self.d2 = np.multiply(d, 2, out=buf("d2"))
        self.ga = buf("ga", f8, c * m).reshape(c, m)  # channel-major: each contiguous
        self.gb = buf("gb", f8, c * m).reshape(c, m)
        self.gc = buf("gc", f8, c * m).reshape(c, m)
        vt, vm, vb = buf("vt"), buf("vm"), buf("vb")
        for ch in range(c):  # a loop over channels
            v = corners.vals[ch]
            np.take(v, it, out=vt, mode="clip")
            np.take(v, im, out=vm, mode="clip")
            np.take(v, ib, out=vb, mode="clip")
            ga, gb, gc = self.ga[ch], self.gb[ch], self.gc[ch]
            np.multiply(dyb, vm, out=ga)
            ga -= np.multiply(dyl, vt, out=tmp)
            ga -= np.multiply(dym, vb, out=tmp)
            ga *= 2
            np.multiply(dxl, vt, out=gb)
            gb -= np.multiply(dxb, vm, out=tmp)
            gb += np.multiply(dxm, vb, out=tmp)
            gb *= 2
            np.multiply(vt, 2, out=gc)
            gc += 1
            gc *= d
            gc -= np.multiply(ga, tx, out=tmp)
            gc -= np.multiply(gb, ty, out=tmp)
        # Unless the image is huge, divide the plane by 2D now: a pixel's value is then
        # the truncation of the float64 sum a*x + b of a = ga/2D and b = (gb/2D)*y +
        # (gc/2D + 1/4|D|). That sum is (2 sum w_i v_i + D)/2D + 1/4|D| with an error
        # below 3u G/|2D| + 2**17 u (u = 2**-53, a few roundings), where G = |ga| W +
        # |gb| H + |gc| < 22 W H (vmax + 1). If W H (69 (vmax + 1) + 2**19) < 2**52 (and
        # |2D| < 4 W H), the error is below 1/4|D|: the sum lies strictly between the
        # exact quotient q, a multiple of 1/|2D|, and q + 1/|2D|, so has q's floor.
        vmax = int(np.iinfo(mesh.dtype).max)
        self.exact = w * h * (69 * (vmax + 1) + (1 << 19)) >= _DIVIDED_PLANE_LIMIT
        if not self.exact:
            with np.errstate(divide="ignore", invalid="ignore"):  # degenerate: no pixels
                self.ga /= self.d2
                self.gb /= self.d2
                self.gc /= self.d2
                self.gc += np.divide(0.5, np.abs(self.d2, out=d), out=d)
        # the rows (see _owned_rows); the edges bounding a row are T -> B and T -> M
        # before row `switch`, M -> B from it on
        self.first, count, none, flat_bottom = _owned_rows(ty, my, by, h, buf)
        self.count = _copy("t_count", count, i8)
        self.switch = np.add(my, flat_bottom, out=buf("switch"))
        # Each edge P -> Q as the line x(y) - delta = c + s*(y - py) (s = (qx - px) /
        # (qy - py), c = px - delta). The exact x(y) is a fraction with denominator
        # qy - py < H, so at least 1/H from any integer unless it is one; with delta
        # = 2**-(bits of H + 2), in (1/8H, 1/4H], and an evaluation error below
        # 1/16H (see _render_band), the ceiling of the computed line is exactly that
        # of x(y).
        delta = 2.0 ** -(int(h).bit_length() + 2)
        self.border = (w - 1) - 2 * delta  # x(y) is W - 1 iff the line is above this
        self.touch = np.equal(np.maximum(bx, mx, out=tmp), w - 1, out=buf("touch", b1))
        self.touch |= np.equal(tx, w - 1, out=buf("touch_t", b1))
        self.ty, self.my = ty, my
        self.s_long = np.divide(dxb, np.maximum(dyb, 1, out=tmp), out=dxb)
        self.s_up = np.divide(dxm, np.maximum(dym, 1, out=tmp), out=dxm)  # (flat: unused)
        np.copyto(self.s_up, self.s_long, where=none)
        self.s_low = np.divide(dxl, np.maximum(dyl, 1, out=tmp), out=dxl)
        self.c_top = np.subtract(tx, delta, out=tx)
        self.c_mid = np.subtract(mx, delta, out=mx)


def _render_band(tri: _Triangles, r0: int, r1: int, width: int, out: np.ndarray) -> None:
    """Write rows r0..r1-1 of `out` (H*W x C) from the triangles `tri` (each with rows
    in the band)."""
    npix = (r1 - r0) * width
    f8, i8 = np.float64, np.int64
    first, n, switch, ty, my = tri.first, tri.count, tri.switch, tri.ty, tri.my
    s_long, s_up, s_low, c_top, c_mid = tri.s_long, tri.s_up, tri.s_low, tri.c_top, tri.c_mid
    touch, d2, ga, gb, gc = tri.touch, tri.d2, tri.ga, tri.gb, tri.gc
    start = first
    if r0 > first.min() or r1 < (first + n).max():
        # clip the rows to the band
        nt = len(n)
        start = np.maximum(first, r0, out=_scratch("b_start", nt, f8))
        end = np.add(first, n, out=_scratch("b_end", nt, f8))
        np.minimum(end, r1, out=end)
        end -= start
        n = _copy("b_n", end, i8)
    nt = len(n)
    # Each edge as the line t = c + s*p in the band's pixel numbering p = W*(row - r0)
    # + x: c its value on row r0, s = slope/W + 1, so that ceil(t) = ceil(x(row)) +
    # W*(row - r0) is the band pixel where a span starts or ends. The line is used on
    # rows where |c|, |s*p| <= 2 npix (npix = the band's pixel count), so the few
    # roundings here and in _line err by less than 2**5 u npix <= 2**-48 npix <= 1/16H
    # as render keeps npix*H <= 2**44. The short edges are interleaved: T -> M at
    # 2j, M -> B at 2j + 1.
    back = np.subtract(r0, ty, out=_scratch("back", nt, f8))
    ca = np.multiply(s_long, back, out=_scratch("ca", nt, f8))
    ca += c_top
    sa = np.divide(s_long, width, out=_scratch("sa", nt, f8))
    sa += 1
    cb = _scratch("cb", 2 * nt, f8)
    sb = _scratch("sb", 2 * nt, f8)
    np.multiply(s_up, back, out=cb[0::2])
    cb[0::2] += c_top
    np.subtract(r0, my, out=back)
    np.multiply(s_low, back, out=cb[1::2])
    cb[1::2] += c_mid
    np.divide(s_up, width, out=sb[0::2])
    np.divide(s_low, width, out=sb[1::2])
    sb += 1
    # one (triangle, row) pair per row of each triangle: `seg` its triangle (a prefix
    # count of the triangles' first pairs), yw = W*(row - r0), and `half` its short
    # edge: 2*seg, plus 1 from row `switch` on
    base = np.cumsum(n, out=_scratch("base", nt, i8))
    base -= n
    pairs = int(base[-1] + n[-1]) if nt else 0
    if pairs == 0:
        _fail(0, r0, width, "leaves it uncovered")
    seg = _prefix_count(base[1:], pairs)
    rowpix = np.subtract(start, r0, out=_scratch("rowpix", nt, f8))
    rowpix -= base
    rowpix *= width
    tmp = _scratch("tmp_p", pairs, f8)
    yw = np.add(_wramp(pairs, width), np.take(rowpix, seg, out=tmp, mode="clip"),
                out=_scratch("yw", pairs, f8))
    np.subtract(switch, r0, out=back)
    back *= width
    half = np.multiply(seg, 2, out=_scratch("half", pairs, i8))
    half += np.greater_equal(yw, np.take(back, seg, out=tmp, mode="clip"),
                             out=_scratch("flag", pairs, np.bool_))
    ta = _line(sa, ca, seg, yw, _scratch("ta", pairs, f8), tmp)
    tb = _line(sb, cb, half, yw, _scratch("tb", pairs, f8), tmp)
    # the left end is the one further left: ceil is monotonic, and exact on both
    lo = np.minimum(ta, tb, out=tmp)
    hi = np.maximum(ta, tb, out=ta)
    touch = np.flatnonzero(touch)
    if len(touch):
        # the last column belongs to a span that reaches it with positive length: where
        # its right end is exactly W - 1 and its left end is not
        tc = n[touch]
        cand = np.repeat(base[touch] - (np.cumsum(tc) - tc), tc)
        cand += np.arange(len(cand))
        row = yw[cand]
        cand = cand[(hi[cand] - row > tri.border) & (lo[cand] - row <= tri.border)]
    key = np.ceil(lo, out=_scratch("key", pairs, i8), casting="unsafe")
    end = np.ceil(hi, out=_scratch("end", pairs, i8), casting="unsafe")
    if len(touch):
        end[cand] += 1
    total = int(end.sum()) - int(key.sum())
    # the empty spans' starts move to npix and beyond, out of the markers' way
    empty = np.equal(key, end, out=_scratch("flag", pairs, np.bool_))
    key += np.multiply(empty, npix, out=half)
    spans = pairs - int(np.count_nonzero(empty))
    # The spans tile the band iff their starts are distinct, the first is pixel 0,
    # every end is a start (or the band's end) and their lengths sum to the band:
    # sorted, each start is then at least the previous end, with equality throughout.
    marker = _scratch("marker", 2 * npix + 1, np.uint8)
    marker.fill(0)
    marker[key] = 1
    marker[npix] = 1
    # sums[1, p + 1]: the number of span starts at or before band pixel p (OpenCV's
    # exact integer prefix sum): for a span start its rank in raster order (from 1),
    # and spans + 1 for the moved empty spans
    sums = _scratch("sums", 2 * (npix + 2), np.int32).reshape(2, npix + 2)
    cv2.integral(marker[:npix + 1].reshape(1, npix + 1), sums)
    at_end = np.take(marker, end, out=_scratch("at_end", pairs, np.uint8), mode="clip")
    at_end |= empty
    if (spans == 0 or marker[0] != 1 or sums[1, npix] != spans or total != npix
            or not at_end.all()):
        live = np.flatnonzero(~empty)
        _tiling_error(key[live], end[live], npix, r0, width)
    # per span in raster order (rank r, from 1): its pair, triangle and row
    rank = np.take(sums[1, 1:], key, out=_scratch("rank", pairs, np.int32), mode="clip")
    np.copyto(end, rank)
    inv = _scratch("inv", spans + 2, i8)
    inv[end] = _iramp(pairs)
    inv = inv[:spans + 1]
    inv[0] = 0
    seg_r = np.take(seg, inv, out=_scratch("seg_r", spans + 1, i8), mode="clip")
    y_r = np.take(yw, inv, out=_scratch("y_r", spans + 1, f8), mode="clip")
    y_r /= width  # exact: a multiple of W over W
    if r0:
        y_r += r0
    channels = out.shape[1]
    a_r = _scratch("a_r", channels * (spans + 1), f8).reshape(channels, spans + 1)
    b_r = _scratch("b_r", channels * (spans + 1), f8).reshape(channels, spans + 1)
    tmp = _scratch("tmp_r", spans + 1, f8)
    for ch in range(channels):  # a loop over channels
        # a = ga and b = gb*y + gc, or their divided forms (see _Triangles); undivided,
        # integers below 2**53 whose partial sums are too
        np.take(ga[ch], seg_r, out=a_r[ch], mode="clip")
        np.take(gb[ch], seg_r, out=b_r[ch], mode="clip")
        b_r[ch] *= y_r
        b_r[ch] += np.take(gc[ch], seg_r, out=tmp, mode="clip")
    if tri.exact:
        d2_r = np.take(d2, seg_r, out=_scratch("d2_r", spans + 1, f8), mode="clip")
    # per band pixel, in chunks that stay in cache: its span's rank and its column
    cols = _columns(width, r1 - r0)
    band = out[r0 * width:r1 * width]
    for p0 in range(0, npix, _CHUNK):  # a loop over chunks of pixels
        p1 = min(npix, p0 + _CHUNK)
        pseg = _scratch("pseg", p1 - p0, i8)
        np.copyto(pseg, sums[1, p0 + 1:p1 + 1])
        num = _scratch("num", p1 - p0, f8)
        tmp = _scratch("tmp", p1 - p0, f8)
        if tri.exact:
            den = np.take(d2_r, pseg, out=_scratch("den", p1 - p0, f8), mode="clip")
        for ch in range(channels):  # a loop over channels
            np.take(a_r[ch], pseg, out=num, mode="clip")
            num *= cols[p0:p1]
            np.take(b_r[ch], pseg, out=tmp, mode="clip")
            if tri.exact:
                # num and den are integers below 2**53 and |den| < 2**35: the correctly
                # rounded quotient is exact when integral, and otherwise more than its
                # rounding error (< 2**-36 for quotients below 2**17) away from the next
                # integer, so its floor is the exact one; and the quotient is >= 0, so
                # the truncating cast is that floor
                num += tmp
                np.divide(num, den, out=band[p0:p1, ch], casting="unsafe")
            else:
                # the divided plane: the truncating cast of the positive sum
                np.add(num, tmp, out=band[p0:p1, ch], casting="unsafe")


def _copy(name: str, a: np.ndarray, dtype) -> np.ndarray:
    """`a` converted to dtype, in scratch."""
    out = _scratch(name, len(a), dtype)
    np.copyto(out, a, casting="unsafe")
    return out


def _line(s: np.ndarray, c: np.ndarray, seg: np.ndarray, p: np.ndarray, out: np.ndarray,
          tmp: np.ndarray) -> np.ndarray:
    """c + s*p per pair, from the lines c[seg], s[seg]."""
    np.take(s, seg, out=out, mode="clip")
    out *= p
    out += np.take(c, seg, out=tmp, mode="clip")
    return out


def _prefix_count(marks: np.ndarray, n: int) -> np.ndarray:
    """For each i < n, how many of the distinct positions `marks` are <= i (int64)."""
    marker = _scratch("seg_marker", n, np.uint8)
    marker.fill(0)
    marker[marks] = 1
    sums = _scratch("seg_sums", 2 * (n + 1), np.int32).reshape(2, n + 1)
    cv2.integral(marker.reshape(1, n), sums)
    return _copy("seg", sums[1, 1:], np.int64)


_local = threading.local()


def _scratch(name: str, n: int, dtype) -> np.ndarray:
    """A reusable per-thread array of n items (contents undefined)."""
    bufs = _local.__dict__.setdefault("bufs", {})
    buf = bufs.get(name)
    if buf is None or len(buf) < n or buf.dtype != dtype:
        buf = bufs[name] = np.empty(n, dtype)
    return buf[:n]


def _iramp(n: int) -> np.ndarray:
    """0, 1, ..., n - 1 as int64 (a prefix of a cached ramp)."""
    ramp = _local.__dict__.get("iramp")
    if ramp is None or len(ramp) < n:
        ramp = _local.iramp = np.arange(max(n, 1 << 16), dtype=np.int64)
    return ramp[:n]


def _wramp(n: int, width: int) -> np.ndarray:
    """0, W, 2W, ..., (n - 1) W as float64 (a prefix of a cached ramp)."""
    ramp = _local.__dict__.get("wramp")
    if ramp is None or ramp[0] != width or len(ramp[1]) < n:
        ramp = _local.wramp = (width, np.arange(max(n, 1 << 16), dtype=np.float64) * width)
    return ramp[1][:n]


def _columns(width: int, rows: int) -> np.ndarray:
    """The column number of every pixel of a band `rows` x `width`, as float64 (a
    prefix of a cached ramp, so the last, shorter band reuses it)."""
    cols = _local.__dict__.get("cols")
    if cols is None or cols[0] != width or len(cols[1]) < rows * width:
        cols = (width, np.tile(np.arange(width, dtype=np.float64), rows))
        _local.cols = cols
    return cols[1][:rows * width]


def _tiling_error(key: np.ndarray, end: np.ndarray, npix: int, r0: int, width: int) -> None:
    """Raise CorruptError naming the first pixel the spans [key, end) repeat or miss."""
    if len(key) and len(np.unique(key)) < len(key):
        _fail(int(np.flatnonzero(np.bincount(key) > 1)[0]), r0, width, "covers it twice")
    order = np.argsort(key)
    where, ends = key[order], end[order]
    expected = np.concatenate([[0], ends[:-1]]).astype(np.int64)
    bad = np.flatnonzero(where != expected)
    if len(bad):
        i = int(bad[0])
        if where[i] > expected[i]:
            _fail(int(expected[i]), r0, width, "leaves it uncovered")
        _fail(int(where[i]), r0, width, "covers it twice")
    last = int(ends[-1]) if len(ends) else 0
    if last < npix:
        _fail(last, r0, width, "leaves it uncovered")
    _fail(npix - 1, r0, width, "covers it twice")


def _fail(pixel: int, r0: int, width: int, what: str) -> None:
    raise CorruptError(
        f"the mesh {what}: pixel (row {r0 + pixel // width}, column {pixel % width})"
    )


def _bands(corners: _Corners, h: int, band_rows: int):
    """(first row, triangles) of each band of `band_rows` rows: every triangle joins
    each band its rows touch."""
    m = len(corners.it)
    keep = m <= _KEEP_TRIANGLES

    def buf(name: str, dtype=np.float64, n: int = m) -> np.ndarray:
        return _scratch("r_" + name, n, dtype) if keep else np.empty(n, dtype)

    ty, my, by = (np.take(corners.vy, i, out=buf(name), mode="clip")
                  for i, name in ((corners.it, "ty"), (corners.im, "my"), (corners.ib, "by")))
    first, count, _, _ = _owned_rows(ty, my, by, h, buf)
    # bands of the first and last row (exact: integers over an integer, then floor)
    b0 = np.floor(np.divide(first, band_rows, out=ty), out=ty)
    last = np.add(first, count, out=my)
    last -= 1
    extra = np.floor(np.divide(last, band_rows, out=by), out=by)
    extra -= b0
    # each triangle in its first band, and those that straddle bands in the others
    over = np.flatnonzero(extra)
    more = extra[over].astype(np.int64)
    tris = np.concatenate([np.arange(m), np.repeat(over, more)])
    step = np.arange(len(tris) - m) - np.repeat(np.cumsum(more) - more, more) + 1
    nb = (h + band_rows - 1) // band_rows
    band = np.concatenate([b0, np.repeat(b0[over], more) + step]).astype(
        np.int16 if nb < 1 << 15 else np.int64)  # a stable radix sort for 16 bits
    order = np.argsort(band, kind="stable")
    tris = tris[order]
    cuts = np.concatenate([[0], np.cumsum(np.bincount(band, minlength=nb))])
    for b in range(nb):
        yield b * band_rows, tris[cuts[b]:cuts[b + 1]]


def render(mesh: Mesh) -> np.ndarray:
    """Decode a validated mesh to an image of its dtype and channel count."""
    if len(mesh.triangles) == 0:
        return render_line(mesh)
    w, h, c = mesh.width, mesh.height, mesh.channels
    if w * h > 1 << 32:
        # keeps every intermediate below the float64-exact bounds stated above
        raise UnsupportedError(f"a {w}x{h} image is too large for the CPU decoder")
    corners = _Corners(mesh)
    out = np.empty((h * w, c), dtype=mesh.dtype)
    # bands of at most BATCH_PIXELS pixels (or one row), with pixels * H <= 2**44
    band_rows = max(1, min(BATCH_PIXELS // w, (1 << 44) // (w * h)))
    if band_rows >= h:
        _render_band(_Triangles(mesh, corners, None), 0, h, w, out)
    else:
        for r0, sel in _bands(corners, h, band_rows):  # a loop over memory-bounding bands
            if len(sel) == 0:
                _fail(0, r0, w, "leaves it uncovered")
            _render_band(_Triangles(mesh, corners, sel), r0, min(h, r0 + band_rows), w, out)
    # no clipping needed: in a triangle every value is a convex combination of values of
    # the dtype, and round-half-up of such a mean stays within the dtype
    shape = (h, w) if c == 1 else (h, w, c)
    return out.reshape(shape)
