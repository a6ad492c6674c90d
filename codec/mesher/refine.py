"""Error-driven refinement of the adaptive mesher to its vertex budget (the coarse-to-
fine refinement of section 3.3.1 of "Approximation of Digital Images with
Discontinuity-Preserving Adaptive Triangular Meshes", in batches): each round puts
vertices at the worst pixels of the elements with the largest squared error, and
the last triangulation is made in stored order, as a decoder rebuilds it.

Not to be confused with codec.error_bound, which refines a band's finished mesh
until an error bound holds on the decoded image.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from ..errors import ATMError
from ..native import _elements, _renumber
from ..triangulate import Triangulation, triangulate
from .elements import Statistics, concat, element_sse, line_raster, triangle_raster, worst_pixels

#: Refinement rounds; each inserts part of what is left, the parts shrinking by DECAY
#: from round to round (later rounds see the effect of the earlier ones).
ROUNDS = 3
DECAY = 0.7
#: When the elements that would get a quarter of the refinement budget hold at least
#: this share of the squared error (steps in a piecewise-smooth image rather than
#: texture), insertions crowd each other and the budget goes in FOCUSED_ROUNDS rounds.
CONCENTRATED = 0.7
FOCUSED_ROUNDS = 6

def merge(width: int, *groups: np.ndarray) -> np.ndarray:
    """Concatenate point groups keeping the first of any points on the same pixel and
    the order of the groups (the first group's indices stay valid)."""
    pts = np.concatenate(groups)
    return pts[_first_of_each(pts, width)]


def _first_of_each(pts: np.ndarray, width: int) -> np.ndarray:
    """A mask of the points that are the first on their pixel."""
    return _elements.first_of_each(np.ascontiguousarray(pts[:, 1] * width + pts[:, 0], dtype=np.int64))


def merge_new(width: int, vertices: np.ndarray, points: np.ndarray, near: np.ndarray):
    """merge(width, vertices, points), and `near` (a vertex index per point) for the
    points it kept, in their order."""
    pts = np.concatenate([vertices, points])
    keep = _first_of_each(pts, width)
    return pts[keep], near[keep[len(vertices):]]


def run_breaks(segments: np.ndarray) -> np.ndarray:
    """Where a run of segments that continue each other ends and the next begins."""
    return np.flatnonzero(segments[1:, 0] != segments[:-1, 1]) + 1


def _key_base(width: int, height: int) -> int:
    """The base of the triangles' keys (_elements.cached): the pixel count, or 0 (no
    keys, nothing kept between rounds) where three pixel numbers would overflow int64."""
    base = width * height
    return base if base**3 < 2**62 else 0


class _Cache:
    """Statistics and squared errors (against the mesh through the sampled values) of
    the triangles of the last triangulation, kept in its order with a key per triangle
    from its corners' pixels (codec._elements.cached), so that a triangle that
    survives a round is not measured again. The statistics of every triangle measured
    are kept where they were put (rows of a growing store) and gathered once, for the
    triangles of the last round: a round needs only the squared errors."""

    def __init__(self, layout: Statistics):
        self.layout = layout
        self.keys = np.zeros(0, np.int64)
        self.rows = np.zeros(0, np.int64)
        self.sse = np.zeros(0)
        self._parts: list[np.ndarray] = []
        self._stored = 0
        # the last measured triangulation's rows in the store, in its order
        self._last = self.rows

    def measure(self, vertices: np.ndarray, triangles: np.ndarray, z: np.ndarray, width: int, height: int,
                last: bool = False) -> np.ndarray | None:
        """The squared error of every triangle (statistics() gives their statistics).
        last: no round follows, so the squared errors are not needed (None) and the
        cache is not updated."""
        pixel = np.ascontiguousarray(vertices[:, 1] * width + vertices[:, 0], dtype=np.int64)
        keys, rows, sse, fresh = _elements.cached(
            pixel, np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3), _key_base(width, height),
            self.keys, self.rows, self.sse, self._stored,
        )
        # the new triangles' statistics and squared errors in one walk over their pixels
        measured, fresh_sse = self.layout.of_triangles(vertices, triangles[fresh], None if last else z)
        self._parts.append(measured)
        self._stored += len(fresh)
        self._last = rows
        if last:
            return None
        sse[fresh] = fresh_sse
        if len(keys):
            self.keys, self.rows, self.sse = keys, rows, sse
        return sse

    def statistics(self, after: np.ndarray | None = None) -> np.ndarray:
        """The statistics of the triangles last measured, in their order, followed by the
        rows of `after` if given. Gathered part by part into one array: no store of
        every part joined, no second copy to append `after` (each a megabyte of
        fresh pages at 512 x 512)."""
        rows = self._last
        tail = 0 if after is None else len(after)
        out = np.empty((len(rows) + tail, self.layout.width))
        head = out[: len(rows)]
        if len(self._parts) == 1:
            np.take(self._parts[0], rows, axis=0, out=head)  # a row gather: 3x quicker than store[rows]
        else:
            _elements.gather_rows(self._parts, np.ascontiguousarray(rows, dtype=np.int64), head)
        if tail:
            out[len(rows):] = after
        return out


class _Growing:
    """The triangulation of refinement's vertices and walls, kept between rounds
    (codec.triangulate.Triangulation): a round's new vertices, which merge() appends,
    are inserted instead of triangulating all the vertices again. The triangles are
    triangulate()'s, in the same canonical order (ATM.md §4.2.5's triangulation is
    unique). Where the kernel refuses the start (all vertices on one line, crossing
    walls), it gives None and triangulate() decides."""

    def __init__(self) -> None:
        self._tri: Triangulation | None = None
        self._count = 0
        self._failed = False

    def __call__(self, vertices: np.ndarray, segments: np.ndarray,
                 near: np.ndarray | None = None) -> np.ndarray | None:
        """The triangles of `vertices` (those since the last call appended) and the
        walls; near: for each appended vertex one near it, where its point location
        starts (a hint: ignored unless it has one entry per vertex appended)."""
        if self._failed:
            return None
        try:
            if self._tri is None:
                self._tri = Triangulation(vertices)
                self._tri.constrain(segments)
            elif len(vertices) > self._count:
                if near is not None and len(near) != len(vertices) - self._count:
                    near = None
                self._tri.insert(vertices[self._count:], near)
        except ATMError:
            self._failed = True
            return None
        self._count = len(vertices)
        return self._tri.triangles()


def _raster_order(vertices: np.ndarray, segments: np.ndarray, width: int, sort_walls: bool = False):
    """(vertices in raster order, the segments renumbered and cut at the vertices on
    them, the new position of every old vertex): the vertex order and wall steps a
    band's MESH chunk stores, which codec.meshcode triangulates again to check that a
    decoder rebuilds the same triangles. sort_walls: also put the runs of segments
    (the stored polylines) in the raster order of their first vertices, so that their
    stored starts are small forward gaps (about 30 % fewer bytes for them); only before
    a triangulation, which with cocircular vertices may depend on the segment order."""
    order = np.argsort(vertices[:, 1] * width + vertices[:, 0], kind="stable")
    renumber = np.empty(len(order), np.int64)
    renumber[order] = np.arange(len(order))
    vertices = np.ascontiguousarray(vertices[order], dtype=np.int64)
    # split_at_vertices' pieces, found by a table of the vertices' pixels in one pass
    segments = _renumber.split_in_raster_order(vertices, np.ascontiguousarray(renumber[segments].reshape(-1, 2)), width)
    if sort_walls and len(segments):
        firsts = np.r_[0, run_breaks(segments)]
        first_vertex = np.repeat(segments[firsts, 0], np.diff(np.r_[firsts, len(segments)]))
        segments = segments[np.argsort(first_vertex, kind="stable")]
    return vertices, segments, renumber


def refine_to_budget(
    gray: np.ndarray,
    vertices: np.ndarray,
    segments: np.ndarray,
    target: int,
    layout: Statistics,
    rounds: int = ROUNDS,
    focused_rounds: int = FOCUSED_ROUNDS,
    finish=None,
):
    """Add vertices until there are `target`: in each round, the elements with the
    largest squared error (against the mesh through the sampled pixel values) each get
    a vertex at their worst pixel. Pixels beside walls may get one: where a wall's
    straight segments cut a corner of the true edge, that is where the error is.
    Rounds: `rounds`, or `focused_rounds` where the error is CONCENTRATED.

    Returns (vertices, segments, triangles, raster, stats, delaunay): the final
    vertices in raster order, the wall segments cut at the vertices on them, their
    triangulation, a raster of its elements (triangles then border lines; the
    triangles' spans are not kept), every element's statistics (`layout`, which must
    have `gray` as its structure plane) and whether the triangulation is the one a
    decoder rebuilds from the vertices and segments in that order (Meshed.delaunay).

    finish: called once as finish(vertices, segments, mse) before the last
    triangulation, `mse` the mean squared error of the last one measured (None if
    none was), it returns the vertices and segments to triangulate instead (a band's
    shared rows and holes go in there, so that the band is triangulated once a round).
    """
    height, width = gray.shape
    cache = _Cache(layout)
    growing = _Growing()
    ordered = False
    measured = None
    near = None  # for each vertex the last round added, a corner of the triangle it fell in
    for r in itertools.count():
        tris = None
        if r == rounds or target <= len(vertices):
            if finish is not None:
                vertices, segments = finish(vertices, segments, measured)
                growing = None  # the caller changed the mesh: it is triangulated anew
            else:
                tris = growing(vertices, segments, near)
            # the last triangulation: made as the MESH chunk's check will make it
            vertices, segments, renumber = _raster_order(vertices, segments, width, sort_walls=True)
            ordered = True
            if tris is not None:
                # the same triangles numbered as the vertices now are, in canonical order
                tris = _renumber.canonical_renumbered(tris, renumber)
        elif growing is not None:
            tris = growing(vertices, segments, near)
        z = gray[vertices[:, 1], vertices[:, 0]].astype(np.float64)
        if tris is None:
            tris = triangulate(vertices, segments)
        tri_sse = cache.measure(vertices, tris, z, width, height, ordered)
        missing = target - len(vertices)
        if ordered:
            break
        lines = line_raster(vertices, width, height)
        sse = np.concatenate([tri_sse, element_sse(lines, layout(lines), z)])
        measured = float(sse.sum()) / (width * height)
        if r == 0:
            quarter = min(len(sse), math.ceil(missing / 4))
            if np.partition(sse, len(sse) - quarter)[len(sse) - quarter :].sum() >= CONCENTRATED * sse.sum():
                rounds = max(rounds, focused_rounds)
        weights = DECAY ** np.arange(rounds - r)
        batch = math.ceil(missing * weights[0] / weights.sum())
        if batch < len(sse):
            # the batch largest, ties to the lower index (as a stable sort would)
            cut = -np.partition(-sse, batch - 1)[batch - 1]
            above = np.flatnonzero(sse > cut)
            cand = np.concatenate([above, np.flatnonzero(sse == cut)[: batch - len(above)]])
        else:
            cand = np.arange(len(sse))
        cand = np.sort(cand[sse[cand] > 0])
        on_tri = cand[cand < len(tris)]
        # each candidate triangle's worst pixel (candidates sorted: in triangle order)
        owns, x, y, err = worst_pixels(gray, vertices, tris[on_tri], z, width, height)
        # a corner of the triangle each worst pixel lies in: where its insertion's point
        # location starts (the border lines' have none)
        near = tris[on_tri[owns], 0]
        _, lx, ly, lerr = lines.worst_pixels(gray, z, cand[cand >= len(tris)] - len(tris))
        # (np.concatenate: np.r_ parses its index each call, 10 us a time)
        x, y, err = np.concatenate([x, lx]), np.concatenate([y, ly]), np.concatenate([err, lerr])
        near = np.concatenate([near, np.full(len(lx), -1, np.int64)])
        big = err > 0.5
        if not big.any() and finish is not None:
            rounds = r + 1  # nothing worth a vertex, but the caller's still go in
            continue
        if not big.any():
            # nothing worth a vertex: keep this triangulation, in raster order
            vertices, segments, renumber = _raster_order(vertices, segments, width)
            tris = renumber[tris]
            break
        vertices, near = merge_new(width, vertices, np.stack([x[big], y[big]], axis=1), near[big])
    lines = line_raster(vertices, width, height)
    elements = concat([triangle_raster(vertices, tris, width, height, spans=False), lines])
    return vertices, segments, tris, elements, cache.statistics(layout(lines)), ordered
