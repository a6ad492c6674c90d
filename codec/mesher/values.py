"""Vertex values: what each mesh vertex stores, given the image and the triangulation."""

from __future__ import annotations

import numpy as np

from ..errors import OptionError
from ..native import _elements, _lsq

METHODS = ("sample", "lsq")

#: Pull of every vertex towards its own pixel's value in least squares, in units of one
#: pixel's squared weight: negligible next to a vertex's pixels, it keeps the system
#: positive definite when a refit drops all of a vertex's pixels.
RIDGE = 1e-3
#: Conjugate gradients stop when the residual is this small relative to the right-hand
#: side (values are rounded to integers afterwards; about 0.1 % of a vertex's value),
#: or after MAX_ITER steps.
RTOL = 1e-4
MAX_ITER = 300
#: The same for a refit meant to reproduce planes exactly.
EXACT_RTOL = 1e-6
#: Distance from the mesh beyond which a pixel counts as one it cannot follow.
OUTLIER = 2.0
#: Mean squared error per pixel (gray levels squared) under which pixels count as
#: reproduced exactly: rounding the image to integers alone gives about 1/12.
PLANAR = 0.25
#: Pixels a vertex needs around it to be judged exact.
EVIDENCE = 4
#: Share of exactly reproduced pixels from which an image counts as piecewise planar.
PLANAR_SHARE = 0.5
#: Pull towards its own pixel's value per unit of pixel weight a vertex loses.
LOST = 1.0


def sample(image: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """The pixel value under each vertex (the paper's choice, section 3.3.2.2)."""
    return image[vertices[:, 1], vertices[:, 0]].copy()


def _to_dtype(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(np.round(values), info.min, info.max).astype(dtype)


def normal_equations(coef: np.ndarray, den: np.ndarray, moments: np.ndarray, image_sums: np.ndarray):
    """Per element, its part of A^T W A (E x 3 x 3, corner by corner) and of A^T W b
    (E x C x 3), from its weighted moments (E x 6: 1, u, v, uu, uv, vv) and image sums
    (E x C x 3: b, ub, vb), where a pixel's row of A holds its corners' weights
    w_i = (alpha_i u + beta_i v + gamma_i) / D."""
    # one compiled pass (the same float64 operations in the same order as the numpy
    # expressions it replaced: about fifty passes over the elements)
    return _lsq.element_normals(np.asarray(coef, dtype=np.int64), np.asarray(den, dtype=np.int64),
                                np.asarray(moments, dtype=np.float64), np.asarray(image_sums, dtype=np.float64))


def _diagonal(corners: np.ndarray, gram: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(corners.ravel(), weights=np.diagonal(gram, axis1=1, axis2=2).ravel(), minlength=n)


def solve(corners: np.ndarray, gram: np.ndarray, rhs: np.ndarray, start: np.ndarray,
          ridge: float | np.ndarray = RIDGE, anchor: np.ndarray | None = None, rtol: float = RTOL) -> np.ndarray:
    """Minimise sum over elements of the squared error plus ridge * |z - anchor|^2 for
    every channel: (A^T W A + ridge I) z = A^T W b + ridge * anchor, by conjugate
    gradients with a diagonal preconditioner, matrix-free (element by element), from
    `start` (n x C; also the default anchor). Returns n x C float64.

    Compiled (codec._lsq): in numpy each step's gathers and scatter-adds over the
    elements took a fifth of a refit's time after refinement's rounds."""
    anchor = start if anchor is None else anchor
    n = len(start)
    ridge = np.ascontiguousarray(np.broadcast_to(np.asarray(ridge, dtype=np.float64), (n,)))
    return _lsq.conjugate_gradients(
        np.ascontiguousarray(corners, dtype=np.int64), np.ascontiguousarray(gram, dtype=np.float64),
        np.ascontiguousarray(rhs, dtype=np.float64), np.ascontiguousarray(start, dtype=np.float64),
        ridge, np.ascontiguousarray(anchor, dtype=np.float64), rtol, MAX_ITER,
    )


def _planar_refit(image: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, raster, moments: np.ndarray,
                  sums: np.ndarray, values: np.ndarray, samples: np.ndarray, bb: np.ndarray) -> np.ndarray:
    """Least squares without the pixels the mesh cannot follow, kept where that makes
    the image exact.

    A pixel on a step belongs to neither side: a wall cannot follow it to the pixel,
    and left in the fit it pulls the values of the wall vertices on both sides, so
    that even a piecewise-planar image is not reproduced away from its steps. So the
    pixels that the mesh misses by more than OUTLIER (`raster`: the `triangles`, then
    the border lines) are dropped and the fit solved again, then once more with the pixels the new fit
    misses; what a vertex loses in dropped pixels it keeps as a pull (LOST) to its own
    pixel's value (`samples`), so that a vertex left with few pixels stays put. The
    new values are taken at the vertices around which the remaining pixels fit to
    within rounding (mean squared error at most PLANAR over at least EVIDENCE pixels):
    the planar parts of the image. Elsewhere the first fit, the smaller squared error
    overall, stays.
    """
    from .elements import squared_error

    m, n, t = len(raster), len(values), len(triangles)
    height, width = image.shape
    # the border lines' pixels (a row and a column: few) as arrays; the triangles' are
    # walked by a compiled pass that sums the outliers' terms itself (every pixel's
    # element, x and y took three image-sized int64 arrays)
    e0, x0, y0 = raster.pixels(np.arange(t, m))
    b0 = image[y0, x0].astype(np.float64)
    plane = np.ascontiguousarray(image if image.dtype in (np.uint8, np.uint16, np.float32, np.float64)
                                 else image.astype(np.float64))
    verts = np.ascontiguousarray(vertices, dtype=np.int64)
    tris = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    origin = np.ascontiguousarray(raster.origin, dtype=np.int64)
    full = _diagonal(raster.corners, normal_equations(raster.coef, raster.den, moments, sums)[0], n)
    refit = values
    for _ in range(2):
        affine = np.ascontiguousarray(raster.affine(refit[:, 0]))
        missed, drop_tris = _elements.outlier_sums(verts, tris, width, height, affine, origin, plane, OUTLIER)
        out = np.abs(b0 - raster.evaluate(affine, e0, x0, y0)) > OUTLIER
        if not missed and not out.any():
            return values
        e, b = e0[out] - t, b0[out]
        u = (x0[out] - raster.origin[e + t, 0]).astype(np.float64)
        v = (y0[out] - raster.origin[e + t, 1]).astype(np.float64)
        # np.bincount's sums per element, the lines' elements apart from the triangles'
        drop_lines = np.stack([np.bincount(e, w, m - t) for w in (np.ones_like(u), u, v, u * u, u * v, v * v, b, u * b, v * b, b * b)], 1)
        drop = np.concatenate([drop_tris, drop_lines])
        kept_moments = moments - drop[:, :6]
        kept = sums - drop[:, None, 6:9]
        gram, rhs = normal_equations(raster.coef, raster.den, kept_moments, kept)
        # what a vertex loses in dropped pixels it keeps as a pull to its own pixel
        lost = np.maximum(full - _diagonal(raster.corners, gram, n), 0.0) * LOST
        refit = solve(raster.corners, gram, rhs, refit, RIDGE + lost, samples, EXACT_RTOL)
    count = kept_moments[:, 0]
    sse = squared_error(raster.affine(refit[:, 0]), kept_moments, np.concatenate([kept[:, 0], (bb - drop[:, 9])[:, None]], 1))
    flat = raster.corners.ravel()
    error = np.bincount(flat, weights=np.repeat(sse, 3), minlength=n)
    evidence = np.bincount(flat, weights=np.repeat(count, 3), minlength=n)
    planar = (error <= PLANAR * evidence) & (evidence >= EVIDENCE)
    return np.where(planar[:, None], refit, values)


def _planar_share(stats: np.ndarray, layout, moments: np.ndarray, values: np.ndarray, raster) -> float:
    """Share of the pixels that the mesh through `values` reproduces to within rounding
    (elements with a mean squared error of at most PLANAR): most of a piecewise-planar
    image, hardly any of a photograph."""
    from .elements import element_sse

    count = moments[:, 0]
    exact = element_sse(raster, stats, values[:, 0]) <= PLANAR * count
    return float(count[exact].sum() / max(count.sum(), 1.0))


def from_statistics(image: np.ndarray, vertices: np.ndarray, raster, stats: np.ndarray, layout,
                    triangles: np.ndarray | None = None) -> np.ndarray:
    """Least-squares vertex values in the image's dtype from the elements of `raster`
    and their statistics (`layout`: the codec.mesher.elements.Statistics that measured them).

    triangles: for single-channel images, the triangles (the raster's first elements,
    the border lines after them); on an image that is mostly planar (PLANAR_SHARE) the values are fitted again
    without the pixels the mesh cannot follow (_planar_refit)."""
    n = len(vertices)
    moments, sums = layout.fit_part(stats)
    gram, rhs = normal_equations(raster.coef, raster.den, moments, sums)
    start = sample(image, vertices).reshape(n, -1).astype(np.float64)
    out = solve(raster.corners, gram, rhs, start)
    if triangles is not None and image.ndim == 2 and _planar_share(stats, layout, moments, out, raster) >= PLANAR_SHARE:
        out = _planar_refit(image, vertices, triangles, raster, moments, sums, out, start, stats[:, layout.IMG][:, 3])
    out = _to_dtype(out, image.dtype)
    return out[:, 0] if image.ndim == 2 else out


def least_squares(image: np.ndarray, vertices: np.ndarray, raster) -> np.ndarray:
    """Vertex values minimising the squared error over all pixels, for the decoder's
    pixel weights (`raster`: a codec.mesher.elements.Raster of the mesh), in the image's dtype.

    The normal equations are assembled per element from closed-form and prefix sums
    over its row spans and solved by conjugate gradients from the sampled values.
    """
    from ..image import structure
    from .elements import Statistics

    layout = Statistics(image, "structure") if image.ndim == 2 else Statistics(structure(image), image)
    return from_statistics(image, vertices, raster, layout(raster), layout)


def fit(image: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, method: str) -> np.ndarray:
    """Vertex values by `method`, in the image's dtype."""
    if method == "sample":
        return sample(image, vertices)
    if method == "lsq":
        from .elements import rasterize

        height, width = image.shape[:2]
        return least_squares(image, vertices, rasterize(vertices, triangles, width, height))
    raise OptionError(f"unknown values method {method!r}; choose one of {', '.join(METHODS)}")


def layout_for(image: np.ndarray):
    """The codec.mesher.elements.Statistics that least squares measures `image` with;
    made once per image and passed to refit() round after round (it holds the image's
    prefix sums, the costly part to build)."""
    from ..image import structure
    from .elements import Statistics

    return Statistics(image, "structure") if image.ndim == 2 else Statistics(structure(image), image)


def refit(image: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, previous: np.ndarray,
          free: np.ndarray, layout=None) -> np.ndarray:
    """Least-squares values of the `free` vertices (a mask) with every other vertex held
    at its `previous` value, in the image's dtype: after a local change of the mesh
    (refinement inserting a few vertices) only the vertices near it move, which costs
    the triangles around them instead of the whole image. The free vertices' values
    minimise the squared error over the pixels of the triangles that touch them (plus
    the bottom row and right column elements), the held ones entering as known terms;
    conjugate gradients start from `previous`."""
    from .elements import line_raster

    height, width = image.shape[:2]
    n = len(vertices)
    prev = previous.reshape(n, -1).astype(np.float64)
    free = np.asarray(free, bool)
    if not free.any():
        return previous.copy()
    layout = layout_for(image) if layout is None else layout
    vertices = np.ascontiguousarray(vertices, dtype=np.int64)
    # the equations of the triangles that touch a free vertex, summed pixel by pixel in
    # one compiled pass (small triangles own a few pixels each); the border lines' from
    # their spans
    plane = image.reshape(height, width, -1)
    if plane.dtype not in (np.uint8, np.uint16):
        plane = plane.astype(np.float64)
    # unknowns: the free vertices, numbered 0..F-1; a held corner moves its part of the
    # element's equations to the right-hand side and points at a sink F, whose row is
    # left empty (its ridge pins it to 0)
    unknowns = int(free.sum())
    number = np.full(n, -1, np.int64)
    number[free] = np.arange(unknowns)
    prev = np.ascontiguousarray(prev)
    lines = line_raster(vertices, width, height)
    gram, rhs, corners = _lsq.triangle_normals(vertices, np.ascontiguousarray(triangles, dtype=np.int64),
                                               np.ascontiguousarray(plane), number, prev, len(lines))
    line_gram, line_rhs = normal_equations(lines.coef, lines.den, *layout.fit_part(layout(lines)))
    held = ~free[lines.corners]  # E x 3
    known = np.where(held[:, :, None], prev[lines.corners], 0.0)  # E x 3 x C
    end = len(gram) - len(lines)  # the lines go in the rows the kernel left for them
    rhs[end:] = line_rhs - np.einsum("eij,ejc->eci", line_gram, known)
    gram[end:] = line_gram * (~held)[:, :, None] * (~held)[:, None, :]
    corners[end:] = np.where(held, unknowns, number[lines.corners])
    start = np.vstack([prev[free], np.zeros((1, prev.shape[1]))])
    # the free vertices' own pixels (work in proportion to them, not to the mesh)
    at = vertices[free]
    anchor = np.vstack([image[at[:, 1], at[:, 0]].reshape(len(at), -1), np.zeros((1, prev.shape[1]))])
    solved = solve(corners, gram, rhs, start, anchor=anchor)
    out = np.array(previous, dtype=np.result_type(previous, image)).reshape(n, -1)
    out[free] = _to_dtype(solved[:-1], image.dtype)
    return out[:, 0] if image.ndim == 2 else out
