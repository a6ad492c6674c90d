"""The encoder's view of a mesh: which pixels each triangle owns, as exact row spans.

Every pixel is owned by exactly one *element*, and inside it the mesh value is
sum_i w_i z_i with the decoder's own barycentric weights (format_spec/ATM.md,
"Decoding"): w_i = (alpha_i u + beta_i v + gamma_i) / D in coordinates (u, v) relative to
the element's origin (a triangle's first corner in raster order), with integer alpha,
beta, gamma and D. Elements are

* the triangles, owning the pixel centres of the half-open rectangle
  [0, W-1) x [0, H-1) by the rule "a point belongs to the triangle that contains it
  nudged by (eps, eps^2)" (left and top edges inclusive, right and bottom exclusive),
  which gives every such pixel exactly one owner;
* the pieces of the bottom row and of the right column between consecutive vertices on
  them (the mesh is linear there), which own the pixels that rule leaves out.

So the sums over all pixels that least squares and error estimates need (moments of u,
v and of the image) reduce to closed forms and prefix-sum look-ups per span, with no
per-pixel work. Elements can be rasterised in parts (a subset
of the triangles, the border lines) and their statistics kept per element, so that a
mesh that changes in places only needs its new triangles measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import native


def _segments(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: starts[k] + 0 .. counts[k]-1."""
    total = int(counts.sum())
    first = np.cumsum(counts) - counts
    # the range each output belongs to: the last one starting at or before it (empty
    # ranges start where the next one does); cheaper than np.repeat
    owner = np.cumsum(np.bincount(first, minlength=total + 1)[:total]) - 1
    return np.take(starts - first, owner) + np.arange(total)


@dataclass(eq=False)
class Raster:
    """Elements (corners, local origin, affine weight coefficients) and their row spans,
    grouped by element (span_elem is non-decreasing)."""

    width: int
    height: int
    corners: np.ndarray  # E x 3 vertex indices
    origin: np.ndarray  # E x 2 (x, y) of the element's local origin
    coef: np.ndarray  # E x 3 x 3: [alpha, beta, gamma] of each corner's weight numerator
    den: np.ndarray  # E: D, the common denominator (> 0)
    span_elem: np.ndarray  # S: element owning the span
    span_y: np.ndarray  # S: row
    span_x: np.ndarray  # S: first column
    span_n: np.ndarray  # S: pixel count (>= 0)
    span_bounds: np.ndarray | None = None  # E + 1: element e's spans are [b[e], b[e+1])
    # corner-major float copies of corners, coef and den for affine(), made once
    _weights: tuple | None = field(default=None, init=False, repr=False)

    def __len__(self) -> int:
        return len(self.den)

    @property
    def bounds(self) -> np.ndarray:
        if self.span_bounds is None:
            self.span_bounds = np.searchsorted(self.span_elem, np.arange(len(self.den) + 1))
        return self.span_bounds

    def _spans_of(self, elements) -> np.ndarray:
        b = self.bounds
        elements = np.asarray(elements, dtype=np.int64)
        return _segments(b[elements], b[elements + 1] - b[elements])

    def pixels(self, elements: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(element, x, y) of every pixel owned by `elements` (default: all)."""
        sel = slice(None) if elements is None else self._spans_of(elements)
        e, y, x, n = self.span_elem[sel], self.span_y[sel], self.span_x[sel], self.span_n[sel]
        return np.repeat(e, n), _segments(x, n), np.repeat(y, n)

    def reduce(self, per_span: np.ndarray) -> np.ndarray:
        """Sum the columns of a K x S array over each element's spans (E x K), span
        after span (a compiled pass, codec._elements.span_totals)."""
        return native._elements.span_totals(
            np.ascontiguousarray(per_span, dtype=np.float64), np.ascontiguousarray(self.bounds, dtype=np.int64)
        )

    def span_sums(self, planes: "Planes") -> np.ndarray:
        """K x S sums over each span's pixels of the K planes of `planes`."""
        lo = self.span_y * planes.stride + self.span_x
        hi = lo + self.span_n
        return (np.take(planes.table, hi, axis=0) - np.take(planes.table, lo, axis=0)).T

    def affine(self, vertex_values: np.ndarray, elements: np.ndarray | None = None) -> np.ndarray:
        """E x 3 (a row per element of `elements`, if given): the mesh value in each
        element as (a, b, c) with f = a u + b v + c."""
        if self._weights is None:
            self._weights = (
                np.ascontiguousarray(self.corners.T),
                np.ascontiguousarray(self.coef.transpose(1, 2, 0), dtype=np.float64),
                self.den.astype(np.float64),
            )
        corners, c, den = self._weights
        if elements is not None:
            corners, c, den = np.take(corners, elements, axis=1), np.take(c, elements, axis=2), den[elements]
        z = np.asarray(vertex_values, dtype=np.float64)
        # sum over corners i of coef[i] z_i, in corner order, then / D
        out = c[0] * np.take(z, corners[0])
        out += c[1] * np.take(z, corners[1])
        out += c[2] * np.take(z, corners[2])
        out /= den
        return out.T

    def evaluate(self, affine: np.ndarray, elem: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The mesh value (unrounded) at pixels (x, y) of their elements (a compiled
        pass: no E x 3 gather per pixel)."""
        return native._elements.evaluate(
            np.ascontiguousarray(affine, dtype=np.float64), np.ascontiguousarray(self.origin, dtype=np.int64),
            *(np.ascontiguousarray(a, dtype=np.int64) for a in (elem, x, y)),
        )

    def worst_pixels(self, plane: np.ndarray, vertex_values: np.ndarray, elements: np.ndarray):
        """For each of `elements` (sorted, distinct) that owns pixels: its pixel farthest
        from the mesh through `vertex_values`, the first in raster order of those
        tied. Returns (element, x, y, |error|)."""
        # one compiled pass over their spans (the numbers of the numpy expressions it
        # replaced, which made a dozen arrays of the pixels)
        elements = np.ascontiguousarray(elements, dtype=np.int64)
        if plane.dtype != np.float32:
            plane = plane.astype(np.float64)
        x, y, err = native._elements.element_worst_pixels(
            np.ascontiguousarray(self.corners, dtype=np.int64), np.ascontiguousarray(self.coef, dtype=np.int64),
            np.ascontiguousarray(self.den, dtype=np.int64), np.ascontiguousarray(self.origin, dtype=np.int64),
            np.ascontiguousarray(self.bounds, dtype=np.int64),
            *(np.ascontiguousarray(a, dtype=np.int64) for a in (self.span_y, self.span_x, self.span_n)),
            elements, np.ascontiguousarray(vertex_values, dtype=np.float64), np.ascontiguousarray(plane),
        )
        owns = np.flatnonzero(err >= 0)
        return elements[owns], x[owns], y[owns], err[owns]


class Planes:
    """Prefix sums along the rows of K planes, interleaved, so that the sums of all of
    them over any row span cost two look-ups of K neighbouring numbers: the planes b,
    x b, b b of a structure b and b_c, x b_c of each channel c (H x W each, one
    integer or float type), summed in one compiled pass (codec._elements.prefix_table)."""

    def __init__(self, structure: np.ndarray, channels: list[np.ndarray]):
        h, w = structure.shape
        self.stride = w + 1
        stack = np.stack(channels) if channels else np.zeros((0, h, w), structure.dtype)
        # row y, columns [x, x+n) of plane k: table[y*stride + x + n, k] - table[y*stride + x, k]
        self.table = native._elements.prefix_table(np.ascontiguousarray(structure), np.ascontiguousarray(stack))


class Statistics:
    """Per-element sums over the element's pixels, from one pass over its spans.

    Columns (E x width): the moments of u and v (GEO: 1, u, v, uu, uv, vv) and the sums
    of the structure plane b (IMG: b, ub, vb, bb), for squared errors; for least
    squares, the sums of every channel c of the fitted image (b_c, u b_c, v b_c).

    fit: None (no least squares), "structure" (fit the structure plane itself) or an
    H x W x C image.
    """

    GEO = slice(0, 6)
    IMG = slice(6, 10)

    def __init__(self, structure: np.ndarray, fit=None):
        h, w = structure.shape
        self.own = fit is not None and not isinstance(fit, str)
        channels = [] if not self.own else list(np.moveaxis(fit.reshape(h, w, -1), 2, 0))
        # integer images keep exact integer prefix sums (and are faster to sum); those
        # of 8-bit images fit in int32 (half the memory traffic) up to widths of about
        # 2900: b x and b b summed along a row stay below 2^31
        kind = np.int64 if structure.dtype.kind in "ui" else np.float64
        if kind is np.int64 and all(c.dtype.kind in "ui" for c in channels):
            top = max(np.iinfo(a.dtype).max for a in [structure] + channels)
            if max(top * (w - 1), top * top) * w < 2**31:
                kind = np.int32
        self._planes: Planes | None = None
        self._make_planes = lambda: Planes(structure.astype(kind), [c.astype(kind) for c in channels])
        # one 8- or 16-bit plane: the kernels sum its spans pixel by pixel in int64, the
        # integers its prefix table's differences give, so no table is made (12 bytes a
        # pixel, faulted in and filled for every band)
        self._plane = np.ascontiguousarray(structure) if not channels and structure.dtype in (np.uint8, np.uint16) else None
        self.channels = 0 if fit is None else max(1, len(channels))
        self._fit = [slice(10 + 3 * c, 13 + 3 * c) for c in range(len(channels))] or [slice(6, 9)]
        width = 10 + 3 * len(channels)
        self.width = width
        self.shape = (h, w)
        # the columns of the kernel's sums (codec._elements.triangle_statistics and span_statistics) in the order of
        # __call__'s: the moments, b, xb, y b, bb, then per channel b_c, x b_c, y b_c
        k = 3 + 2 * len(channels)
        self._from_kernel = np.array(
            [0, 1, 2, 3, 4, 5, 6, 7, 6 + k, 8] + [i for c in range(len(channels)) for i in (9 + 2 * c, 10 + 2 * c, 6 + k + 3 + 2 * c)]
        )
        # the first columns (b, ub, vb) of each image's sums, which _to_origin moves
        self._blocks = np.array([6] + [10 + 3 * c for c in range(len(self._fit) if self.own else 0)], np.int64)
        # sums of x^k over columns [0, x): a span's sums of x and xx in two look-ups
        # each (exact integers in float64 for widths up to about 180,000)
        cols = np.arange(w, dtype=np.float64)
        self._powers = [None] + [np.r_[0.0, np.cumsum(cols**k)] for k in (1, 2)]

    @property
    def planes(self) -> Planes:
        """The planes' prefix sums (made on first use: one 8- or 16-bit plane needs none)."""
        if self._planes is None:
            self._planes = self._make_planes()
        return self._planes

    def _source(self) -> np.ndarray:
        """What the kernels sum spans from: the one plane itself, or the prefix table."""
        return self._plane if self._plane is not None else self.planes.table

    def __call__(self, raster: Raster) -> np.ndarray:
        """E x width: the statistics of every element of `raster`."""
        if self._plane is not None:
            # one compiled pass: the numbers of the columns below and their row sums
            return native._elements.span_statistics(
                self._plane, np.ascontiguousarray(raster.bounds, dtype=np.int64),
                *(np.ascontiguousarray(a, dtype=np.int64) for a in (raster.span_y, raster.span_x, raster.span_n)),
                np.ascontiguousarray(raster.origin, dtype=np.int64), self._powers[1], self._powers[2],
                self._from_kernel, self._blocks)
        d = raster.span_sums(self.planes)
        y = raster.span_y.astype(np.float64)
        x0, x1 = raster.span_x, raster.span_x + raster.span_n
        # per span, in image coordinates: 1, x, y, xx, xy, yy, then b, xb, yb (and bb)
        fit = len(self._fit) if self.own else 0
        cols = np.empty((self.width, len(y)))
        cols[0] = raster.span_n
        cols[1] = np.take(self._powers[1], x1) - np.take(self._powers[1], x0)
        np.multiply(y, cols[0], out=cols[2])
        cols[3] = np.take(self._powers[2], x1) - np.take(self._powers[2], x0)
        np.multiply(y, cols[1], out=cols[4])
        np.multiply(y, cols[2], out=cols[5])
        cols[6:8] = d[0:2]
        np.multiply(y, d[0], out=cols[8])
        cols[9] = d[2]
        for c in range(fit):
            cols[10 + 3 * c : 12 + 3 * c] = d[3 + 2 * c : 5 + 2 * c]
            np.multiply(y, d[3 + 2 * c], out=cols[12 + 3 * c])
        return self._to_origin(raster.reduce(cols), raster.origin)

    def of_triangles(self, vertices: np.ndarray, triangles: np.ndarray,
                     vertex_values: np.ndarray | None = None, rows: np.ndarray | None = None,
                     into: np.ndarray | None = None,
                     sse_into: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """(M x width statistics of `triangles`, the numbers __call__ gives for their
        triangle_raster; with vertex_values, also element_sse's squared error of each
        against the mesh through them, else None), from one compiled walk over their
        pixels (codec._elements.triangle_statistics) instead of span arrays. rows: only
        the triangles of those rows, each written to its row of `into` (M x width
        float64) and of `sse_into` (M), which are returned."""
        h, w = self.shape
        z = np.zeros(0) if vertex_values is None else np.ascontiguousarray(vertex_values, dtype=np.float64)
        return native._elements.triangle_statistics(
            np.ascontiguousarray(vertices, dtype=np.int64), np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3),
            w, h, self._source(), self._powers[1], self._powers[2], self._from_kernel, self._blocks, z,
            None if rows is None else np.ascontiguousarray(rows, dtype=np.int64), into, sse_into,
        )

    def _to_origin(self, out: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Sums in image coordinates (E x width) to coordinates relative to each
        element's origin: u = x - ox, v = y - oy (in place)."""
        fit = len(self._fit) if self.own else 0
        ox, oy = (origin[:, k].astype(np.float64) for k in (0, 1))
        sn, sx, sy, sxx, sxy, syy = out[:, :6].T.copy()
        out[:, 1] = sx - ox * sn
        out[:, 2] = sy - oy * sn
        out[:, 3] = sxx - 2 * ox * sx + ox * ox * sn
        out[:, 4] = sxy - ox * sy - oy * sx + ox * oy * sn
        out[:, 5] = syy - 2 * oy * sy + oy * oy * sn
        for first in [6] + [10 + 3 * c for c in range(fit)]:
            sb = out[:, first].copy()
            out[:, first + 1] -= ox * sb
            out[:, first + 2] -= oy * sb
        return out

    def fit_part(self, stats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(E x 6 moments, E x C x 3 image sums b, ub, vb) for least squares."""
        return stats[:, self.GEO], np.stack([stats[:, f] for f in self._fit], axis=1)


def squared_error(affine: np.ndarray, moments: np.ndarray, sums: np.ndarray) -> np.ndarray:
    """E: sum over each element's pixels of (b - f)^2 for the affine f = a u + b v + c
    of each element (E x 3), from its moments (E x 6: 1, u, v, uu, uv, vv) and image
    sums (E x 4: b, ub, vb, bb): sum b^2 - 2 sum b f + sum f^2."""
    m, mb = moments, sums
    a, b, c = affine.T
    ff = a * a * m[:, 3] + 2 * a * b * m[:, 4] + b * b * m[:, 5] + 2 * a * c * m[:, 1] + 2 * b * c * m[:, 2] + c * c * m[:, 0]
    bf = a * mb[:, 1] + b * mb[:, 2] + c * mb[:, 0]
    return np.maximum(mb[:, 3] - 2 * bf + ff, 0.0)


def element_sse(raster: Raster, stats: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
    """E: squared error of the (unrounded) mesh through `vertex_values` against the
    structure plane, summed over each element's pixels (`stats` from Statistics): the
    numbers squared_error(raster.affine(vertex_values), ...) gives, from one compiled
    pass (codec._lsq.plane_errors)."""
    return native._lsq.plane_errors(
        np.ascontiguousarray(raster.corners, dtype=np.int64), np.asarray(raster.coef, dtype=np.int64),
        np.asarray(raster.den, dtype=np.int64), np.ascontiguousarray(vertex_values, dtype=np.float64),
        np.asarray(stats[:, Statistics.GEO], dtype=np.float64), np.asarray(stats[:, Statistics.IMG], dtype=np.float64),
    )


def _sort3(keys, *values):
    """Sort three columns by `keys` (a network of three compare-and-swaps); `values`
    follow. Returns the sorted keys and values as lists of three arrays."""
    cols = [list(keys)] + [list(v) for v in values]
    for i, j in ((0, 1), (1, 2), (0, 1)):
        swap = cols[0][j] < cols[0][i]
        for c in cols:
            c[i], c[j] = np.where(swap, c[j], c[i]), np.where(swap, c[i], c[j])
    return cols


def _triangle_spans(v: np.ndarray, t: np.ndarray):
    """Row spans of the pixels each triangle owns in [0, W-1) x [0, H-1), one per row
    it crosses (possibly empty), and each triangle's first span.

    A row's span lies between the long edge (top to bottom corner) and the upper or
    the lower short edge; each edge crossing is ceil(num / den) of integers below 2**41
    (coordinates below 2**20, limits.MAX_DIMENSION), computed in float64: the quotient
    is correctly rounded and at least 1/den away from any integer it is not, so its
    ceiling is exact.
    """
    tt = t.T
    (ya, yb, yc), (xa, xb, xc) = _sort3(v[:, 1].astype(np.float64)[tt], v[:, 0].astype(np.float64)[tt])
    tall, upper, lower = yc - ya, yb - ya, yc - yb
    rows = tall.astype(np.int64)  # the bottom row is never owned: half-open in y
    up = np.minimum(upper + 1, tall).astype(np.int64)
    # pieces: the rows of each triangle down to its middle corner, then the rest; a
    # short edge is x = (x0 + slope * dy) / den with dy = y - ya (flat top: x = xb)
    flat = upper == 0
    short_x = np.stack([np.where(flat, xb, xa * upper), xb * np.maximum(lower, 1) - (xc - xb) * upper], axis=1).ravel()
    short_slope = np.stack([np.where(flat, 0.0, xb - xa), xc - xb], axis=1).ravel()
    short_den = np.stack([np.where(flat, 1.0, upper), np.maximum(lower, 1.0)], axis=1).ravel()
    counts = np.stack([up, rows - up], axis=1).ravel()
    piece = np.repeat(np.arange(len(counts)), counts)
    dy = _segments(np.stack([np.zeros_like(up), up], axis=1).ravel(), counts)
    tri = piece >> 1
    dyf = dy.astype(np.float64)
    c_long = np.ceil((np.take(xa * tall, tri) + np.take(xc - xa, tri) * dyf) / np.take(tall, tri))
    c_short = np.ceil((np.take(short_x, piece) + np.take(short_slope, piece) * dyf) / np.take(short_den, piece))
    # columns with xl <= x < xr: left edges inclusive, right edges exclusive (rows a
    # triangle crosses between two pixel centres stay, as empty spans)
    left = np.minimum(c_long, c_short)
    n = (np.maximum(c_long, c_short) - left).astype(np.int64)
    y = np.take(ya.astype(np.int64), tri) + dy
    return tri, y, left.astype(np.int64), n, np.r_[0, np.cumsum(rows)]


def triangle_raster(vertices: np.ndarray, triangles: np.ndarray, width: int, height: int,
                    *, spans: bool = True) -> Raster:
    """The triangles' elements alone (no border lines): what they own of the image.
    Each element's origin is its first corner in raster order, so that a triangle has
    the same statistics whichever corner it is listed from and however the vertices
    are numbered. spans=False: the weights only (no spans, for statistics measured
    before)."""
    v = np.ascontiguousarray(vertices, dtype=np.int64)
    t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    # origins and weight coefficients in one compiled pass (integers: the same numbers)
    origin, coef, den = native._elements.triangle_weights(v, t, width, height)
    if spans and len(t):
        return Raster(width, height, t, origin, coef, den, *_triangle_spans(v, t))
    empty = np.zeros(0, np.int64)
    return Raster(width, height, t, origin, coef, den, empty, empty, empty, empty)


def mesh_elements(vertices: np.ndarray, triangles: np.ndarray, lines: Raster) -> Raster:
    """concat([triangle_raster(vertices, triangles, width, height, spans=False), lines]):
    the triangles' weights written by the kernel into arrays with room for the lines'
    rows, with no copy of them (two megabytes of fresh pages for a 512 x 512 mesh)."""
    v = np.ascontiguousarray(vertices, dtype=np.int64)
    t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    m = len(t)
    origin, coef, den = native._elements.triangle_weights(v, t, lines.width, lines.height, m + len(lines))
    origin[m:], coef[m:], den[m:] = lines.origin, lines.coef, lines.den
    return Raster(lines.width, lines.height, np.concatenate([t, lines.corners]), origin, coef, den,
                  lines.span_elem + m, lines.span_y, lines.span_x, lines.span_n)


def worst_pixels(plane: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, vertex_values: np.ndarray,
                 width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each of `triangles` that owns pixels: its pixel farthest from the mesh
    through `vertex_values`, the first in raster order of those tied, as
    Raster.worst_pixels finds it, from one compiled walk over the triangles' pixels.
    Returns (index into `triangles`, x, y, |error|)."""
    v = np.ascontiguousarray(vertices, dtype=np.int64)
    t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    if plane.dtype != np.float32:
        plane = plane.astype(np.float64)
    x, y, err = native._elements.worst_pixels(
        v, t, width, height, np.ascontiguousarray(vertex_values, dtype=np.float64), np.ascontiguousarray(plane),
    )
    owns = np.flatnonzero(err >= 0)
    return owns, x[owns], y[owns], err[owns]


def triangle_pixels(vertices: np.ndarray, triangles: np.ndarray, width: int,
                    height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangle, x, y) of every pixel the triangles own, as triangle_raster(...).pixels()
    lists them, from a compiled walk over their rows (no span arrays)."""
    return native._elements.triangle_pixels(
        np.ascontiguousarray(vertices, dtype=np.int64),
        np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3), width, height,
    )


def line_raster(vertices: np.ndarray, width: int, height: int) -> Raster:
    """The elements of the bottom row and the right column, which need a vertex at
    each of their ends (the image corners)."""
    # one compiled pass (the same integers as the numpy pieces it replaced, in their
    # order: a fifth of a refinement round's orchestration)
    return Raster(width, height, *native._elements.line_elements(np.ascontiguousarray(vertices, dtype=np.int64),
                                                                 width, height))


def concat(rasters: list[Raster]) -> Raster:
    """One raster of the elements of several, in their order."""
    offsets = np.cumsum([0] + [len(r) for r in rasters[:-1]])
    first = rasters[0]
    return Raster(
        first.width,
        first.height,
        *(np.concatenate([getattr(r, f) for r in rasters]) for f in ("corners", "origin", "coef", "den")),
        np.concatenate([r.span_elem + o for r, o in zip(rasters, offsets)]),
        *(np.concatenate([getattr(r, f) for r in rasters]) for f in ("span_y", "span_x", "span_n")),
    )


def rasterize(vertices: np.ndarray, triangles: np.ndarray, width: int, height: int) -> Raster:
    """Ownership spans and weights of a mesh covering the image: the triangles, then the
    bottom row and the right column (which need a vertex at each of their ends)."""
    return concat([triangle_raster(vertices, triangles, width, height), line_raster(vertices, width, height)])
