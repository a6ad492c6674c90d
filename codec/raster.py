"""The encoder's view of a mesh: which pixels each triangle owns, as exact row spans.

Every pixel is owned by exactly one *element*, and inside it the mesh value is
sum_i w_i z_i with the decoder's own barycentric weights (format_spec/ATM.md,
"Decoding"): w_i = (alpha_i u + beta_i v + gamma_i) / D in coordinates (u, v) relative to
the element's first corner, with integer alpha, beta, gamma and D. Elements are

* the triangles, owning the pixel centres of the half-open rectangle
  [0, W-1) x [0, H-1) by the rule "a point belongs to the triangle that contains it
  nudged by (eps, eps^2)" (left and top edges inclusive, right and bottom exclusive),
  which gives every such pixel exactly one owner;
* the pieces of the bottom row and of the right column between consecutive vertices on
  them (the mesh is linear there), which own the pixels that rule leaves out.

So the sums over all pixels that least squares and error estimates need (moments of u,
v and of the image) reduce to closed forms per span, with no per-pixel work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _ceil_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    return -((-num) // den)


def _segments(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: starts[k] + 0 .. counts[k]-1."""
    offs = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    return np.repeat(starts, counts) + offs


@dataclass(eq=False)
class Raster:
    """Elements (corners, local origin, affine weight coefficients) and their row spans."""

    width: int
    height: int
    corners: np.ndarray  # E x 3 vertex indices
    origin: np.ndarray  # E x 2 (x, y) of the element's local origin
    coef: np.ndarray  # E x 3 x 3: [alpha, beta, gamma] of each corner's weight numerator
    den: np.ndarray  # E: D, the common denominator (> 0)
    span_elem: np.ndarray  # S: element owning the span
    span_y: np.ndarray  # S: row
    span_x: np.ndarray  # S: first column
    span_n: np.ndarray  # S: pixel count (> 0)

    def pixels(self, elements: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(element, x, y) of every pixel owned by `elements` (default: all)."""
        sel = slice(None) if elements is None else np.isin(self.span_elem, elements)
        e, y, x, n = self.span_elem[sel], self.span_y[sel], self.span_x[sel], self.span_n[sel]
        return np.repeat(e, n), _segments(x, n), np.repeat(y, n)

    def moments(self) -> np.ndarray:
        """E x 6 sums over each element's pixels of 1, u, v, uu, uv, vv."""
        e, n = self.span_elem, self.span_n.astype(np.float64)
        u0 = (self.span_x - self.origin[e, 0]).astype(np.float64)
        v = (self.span_y - self.origin[e, 1]).astype(np.float64)
        u1 = u0 + n - 1
        su = (u0 + u1) * n / 2
        suu = (u1 * (u1 + 1) * (2 * u1 + 1) - (u0 - 1) * u0 * (2 * u0 - 1)) / 6
        parts = [n, su, v * n, suu, v * su, v * v * n]
        m = len(self.den)
        return np.stack([np.bincount(e, weights=p, minlength=m) for p in parts], axis=1)

    def image_moments(self, prefix: "RowPrefix") -> np.ndarray:
        """E x 4 sums over each element's pixels of b, u b, v b and b^2 for the plane b
        of `prefix`."""
        e, y, x, n = self.span_elem, self.span_y, self.span_x, self.span_n
        lo = y * prefix.stride + x
        hi = lo + n
        sb = prefix.sum[hi] - prefix.sum[lo]
        sxb = prefix.sum_x[hi] - prefix.sum_x[lo]
        sbb = prefix.sum_sq[hi] - prefix.sum_sq[lo]
        sub = sxb - self.origin[e, 0] * sb
        svb = (y - self.origin[e, 1]) * sb
        m = len(self.den)
        return np.stack([np.bincount(e, weights=p, minlength=m) for p in (sb, sub, svb, sbb)], axis=1)

    def affine(self, vertex_values: np.ndarray) -> np.ndarray:
        """E x 3: the mesh value in each element as (a, b, c) with f = a u + b v + c."""
        z = np.asarray(vertex_values, dtype=np.float64)[self.corners]
        return np.einsum("eik,ei->ek", self.coef.astype(np.float64), z) / self.den[:, None]

    def evaluate(self, affine: np.ndarray, elem: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The mesh value (unrounded) at pixels (x, y) of their elements."""
        f = affine[elem]
        return f[:, 0] * (x - self.origin[elem, 0]) + f[:, 1] * (y - self.origin[elem, 1]) + f[:, 2]


class RowPrefix:
    """Prefix sums along the rows of a plane b (of b, x b and b^2), so that the sums
    over any row span cost two look-ups."""

    def __init__(self, plane: np.ndarray):
        h, w = plane.shape
        b = plane.astype(np.float64)
        self.stride = w + 1
        sums = []
        for term in (b, b * np.arange(w, dtype=np.float64), b * b):
            out = np.zeros((h, w + 1))
            np.cumsum(term, axis=1, out=out[:, 1:])
            sums.append(out.ravel())  # flat: row y, columns [x, x+n) is y*stride + x .. + n
        self.sum, self.sum_x, self.sum_sq = sums


def _triangle_spans(v: np.ndarray, t: np.ndarray):
    """Row spans of the pixels each triangle owns in [0, W-1) x [0, H-1)."""
    xs, ys = v[t, 0], v[t, 1]
    order = np.argsort(ys, axis=1, kind="stable")
    xs = np.take_along_axis(xs, order, axis=1)
    ys = np.take_along_axis(ys, order, axis=1)
    xa, xb, xc = xs.T
    ya, yb, yc = ys.T
    rows = yc - ya  # the bottom row is never owned: half-open in y
    tri = np.repeat(np.arange(len(t)), rows)
    y = _segments(ya, rows)
    xa, xb, xc, ya, yb, yc = (a[tri] for a in (xa, xb, xc, ya, yb, yc))
    dy = y - ya
    long_den = yc - ya
    long_num = xa * long_den + (xc - xa) * dy
    upper = y <= yb
    flat = upper & (yb == ya)
    short_den = np.where(flat, 1, np.where(upper, yb - ya, yc - yb))
    short_num = np.where(
        upper, xa * (yb - ya) + (xb - xa) * dy, xb * (yc - yb) + (xc - xb) * (y - yb)
    )
    short_num = np.where(flat, xb, short_num)
    # columns with xl <= x < xr: left edges inclusive, right edges exclusive
    c_long = _ceil_div(long_num, long_den)
    c_short = _ceil_div(short_num, short_den)
    left = np.minimum(c_long, c_short)
    n = np.maximum(c_long, c_short) - left
    keep = n > 0
    return tri[keep], y[keep], left[keep], n[keep]


def _line_elements(v: np.ndarray, on_line: np.ndarray, axis: int, fixed: int, length: int):
    """Elements for the pixels 0 .. length-1 of a border line (axis 0: a row, 1: a
    column) between consecutive vertices on it; the last pixel is owned by its vertex."""
    idx = np.flatnonzero(on_line)
    idx = idx[np.argsort(v[idx, axis], kind="stable")]
    pos = v[idx, axis]
    a, b = idx[:-1], idx[1:]
    la = pos[1:] - pos[:-1]
    k = len(a)
    corners = np.stack([a, b, b], axis=1)
    coef = np.zeros((k + 1, 3, 3), dtype=np.int64)
    # along the line the coordinate is u (a row) or v (a column)
    coef[:k, 0, axis] = -1
    coef[:k, 0, 2] = la
    coef[:k, 1, axis] = 1
    coef[k, 0, 2] = 1
    corners = np.concatenate([corners, [[idx[-1]] * 3]]).astype(np.int64)
    origin = v[np.concatenate([a, idx[-1:]])]
    den = np.concatenate([la, [1]]).astype(np.int64)
    starts = np.concatenate([pos[:-1], pos[-1:]])
    counts = np.concatenate([la, [1]])
    keep = starts < length
    counts = np.minimum(counts, length - starts)
    if axis == 0:
        span_y, span_x, span_n = np.full(k + 1, fixed), starts, counts
    else:
        span_n = np.ones(int(counts[keep].sum()), dtype=np.int64)
        elem = np.repeat(np.arange(k + 1)[keep], counts[keep])
        return corners, origin, coef, den, elem, _segments(starts[keep], counts[keep]), np.full(len(elem), fixed), span_n
    elem = np.arange(k + 1)
    return corners, origin, coef, den, elem[keep], span_y[keep], span_x[keep], span_n[keep]


def rasterize(vertices: np.ndarray, triangles: np.ndarray, width: int, height: int) -> Raster:
    """Ownership spans and weights of a mesh covering the image. The bottom row and the
    right column need a vertex at each of their ends (the image corners)."""
    v = np.asarray(vertices, dtype=np.int64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    parts = []
    if len(t):
        p = v[t]  # M x 3 x 2
        origin = p[:, 0]
        coef = np.zeros((len(t), 3, 3), dtype=np.int64)
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            # w_i = (xk - xj)(y - yj) - (yk - yj)(x - xj), with x = u + x0, y = v + y0
            ex = p[:, k, 0] - p[:, j, 0]
            ey = p[:, k, 1] - p[:, j, 1]
            coef[:, i, 0] = -ey
            coef[:, i, 1] = ex
            coef[:, i, 2] = ex * (origin[:, 1] - p[:, j, 1]) - ey * (origin[:, 0] - p[:, j, 0])
        den = coef[:, :, 2].sum(axis=1)
        tri, y, x, n = _triangle_spans(v, t)
        parts.append((t, origin, coef, den, tri, y, x, n))
    parts.append(_line_elements(v, v[:, 1] == height - 1, 0, height - 1, width))
    if height > 1:
        right = _line_elements(v, v[:, 0] == width - 1, 1, width - 1, height - 1)
        parts.append(right)
    offset = 0
    cols = [[] for _ in range(8)]
    for part in parts:
        for i, a in enumerate(part):
            cols[i].append(a + offset if i == 4 else a)
        offset += len(part[3])
    corners, origin, coef, den, elem, y, x, n = (np.concatenate(c) for c in cols)
    return Raster(width, height, corners, origin, coef, den, elem, y, x, n)


def element_sse(raster: Raster, prefix: RowPrefix, vertex_values: np.ndarray, moments=None) -> np.ndarray:
    """E: squared error of the (unrounded) mesh against the plane of `prefix`, summed
    over each element's pixels: sum b^2 - 2 sum b f + sum f^2 with f affine per element."""
    m = raster.moments() if moments is None else moments  # 1, u, v, uu, uv, vv
    mb = raster.image_moments(prefix)  # b, ub, vb, bb
    a, b, c = raster.affine(vertex_values).T
    ff = a * a * m[:, 3] + 2 * a * b * m[:, 4] + b * b * m[:, 5] + 2 * a * c * m[:, 1] + 2 * b * c * m[:, 2] + c * c * m[:, 0]
    bf = a * mb[:, 1] + b * mb[:, 2] + c * mb[:, 0]
    return np.maximum(mb[:, 3] - 2 * bf + ff, 0.0)
