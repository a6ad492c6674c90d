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
from .elements import Statistics, element_sse, line_raster, mesh_elements, worst_pixels

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


def _pixels(pts: np.ndarray, width: int) -> np.ndarray:
    """Each point's pixel index in raster order (int64, contiguous, for the kernels)."""
    return np.ascontiguousarray(pts[:, 1] * width + pts[:, 0], dtype=np.int64)


def _first_of_each(pts: np.ndarray, width: int) -> np.ndarray:
    """A mask of the points that are the first on their pixel."""
    return _elements.first_of_each(_pixels(pts, width))


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


def _gathered(parts: list[np.ndarray], rows: np.ndarray, after: np.ndarray | None, width: int) -> np.ndarray:
    """Rows `rows` of the parts taken as one store (statistics, `width` columns each),
    followed by the rows of `after` if given: gathered into one new array by a compiled
    row copy (np.take's row by row memmove took 2.6x as long), with no store of every
    part joined and no second copy to append `after` (each a megabyte of fresh pages at
    512 x 512)."""
    tail = 0 if after is None else len(after)
    out = np.empty((len(rows) + tail, width))
    _elements.gather_rows(parts, np.ascontiguousarray(rows, dtype=np.int64), out[: len(rows)])
    if tail:
        out[len(rows):] = after
    return out


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
        pixel = _pixels(vertices, width)
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

    def seed(self, vertices: np.ndarray, triangles: np.ndarray, stats: np.ndarray, sse: np.ndarray, width: int,
             height: int) -> None:
        """Take a triangulation measured elsewhere (a _Kept one, when the caller's finish
        changes the mesh) as the last measured: its triangles (any corner order) and
        their statistics and squared errors, row by row."""
        pixel = _pixels(vertices, width)
        none = np.zeros(0, np.int64)
        keys, rows, _, _ = _elements.cached(pixel, np.ascontiguousarray(triangles, dtype=np.int64),
                                            _key_base(width, height), none, none, np.zeros(0), 0)
        # (no keys where the band is too large for them: then nothing is kept, as in
        # measure(), and the next round measures every triangle)
        if len(keys):
            self.keys, self.rows, self.sse = keys, rows, np.array(sse)
        else:
            self.keys, self.rows, self.sse = none, none, np.zeros(0)
        self._parts = [stats]
        self._stored = len(triangles)
        self._last = rows

    def statistics(self, after: np.ndarray | None = None) -> np.ndarray:
        """The statistics of the triangles last measured, in their order, followed by the
        rows of `after` if given."""
        return _gathered(self._parts, self._last, after, self.layout.width)


class _Kept:
    """The triangulation of refinement's vertices and walls kept between rounds
    (codec.triangulate.Triangulation, tracking its changes), with each triangle's
    statistics and squared error (against the mesh through the sampled values) kept
    by the kernel's slot: a round's new vertices, which merge() appends, are inserted,
    and only the slots the insertions rewrote are measured. No round lists or looks up
    every triangle: the canonical order (ATM.md §4.2.3) is needed only to break ties
    among the triangles tied at the batch's cut and to order the candidates, and comes
    from the few triangles concerned. The triangles are triangulate()'s (ATM.md
    §4.2.5's triangulation is unique), each measured with its corners in canonical
    rotation, so every number is the one a canonical list would give. Raises ATMError
    where the kernel refuses the start (all vertices on one line, crossing walls) or
    an insertion."""

    def __init__(self, layout: Statistics, vertices: np.ndarray, segments: np.ndarray, target: int):
        self.layout = layout
        self.tri = Triangulation(vertices, track_changes=True)
        self.tri.constrain(segments)
        self.count = len(vertices)
        self.m = self.tri.size()
        # room for the triangles of `target` vertices (2 n - 5 at most with 4 hull
        # corners), grown by doubling should a mesh need more
        room = max(self.m, 2 * target + 16)
        self.corners = np.empty((room, 3), np.int64)
        self.stats = np.empty((room, layout.width))
        self.sse = np.empty(room)
        self.corners[: self.m] = self.tri.slots()
        self.tri.dirty()  # every slot is in `corners`: the changes so far are read
        self._pending = np.arange(self.m)  # the slots not measured yet

    def insert(self, vertices: np.ndarray, near: np.ndarray | None) -> None:
        """Insert the vertices appended since the last call; near: for each a vertex
        near it, where its point location starts (a hint: ignored unless it has one
        entry per vertex appended)."""
        if len(vertices) == self.count:
            return
        if near is not None and len(near) != len(vertices) - self.count:
            near = None
        self.tri.insert(vertices[self.count:], near)
        self.count = len(vertices)
        self._rewritten()

    def add(self, vertices: np.ndarray, points: np.ndarray, near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """merge_new(width, vertices, points, near), the points inserted as they are
        appended: those at a pixel taken (by a vertex, or a point before them) are left
        out by the kernel's own table of positions, not by a table of every vertex
        made each round."""
        free = self.tri.insert_free(points, near)
        vertices, near = np.concatenate([vertices, points[free]]), near[free]
        self.count = len(vertices)
        self._rewritten()
        return vertices, near

    def _rewritten(self) -> None:
        """Take the slots the last insertion rewrote (room made for new ones)."""
        self.m = self.tri.size()
        if self.m > len(self.sse):
            room = 2 * self.m
            self.corners = _grown(self.corners, room)
            self.stats = _grown(self.stats, room)
            self.sse = _grown(self.sse, room)
        # the rewritten slots' triangles straight into their rows
        self._pending = self.tri.dirty(into=self.corners)

    def measure(self, vertices: np.ndarray, z: np.ndarray | None) -> None:
        """Measure the slots rewritten since the last measure (z: the vertex values for
        their squared errors; None: statistics only, no round follows), each into its
        rows of the kept statistics and squared errors."""
        self.layout.of_triangles(vertices, self.corners[: self.m], z, self._pending, self.stats, self.sse)
        self._pending = self._pending[:0]

    def canonical(self, number: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(triangles, slots): every triangle in canonical order, its vertices numbered
        number[i] (default: as inserted), and the slot of each."""
        if number is None:
            number = np.arange(self.count)
        return _renumber.canonical_renumbered(self.corners[: self.m], np.ascontiguousarray(number, dtype=np.int64),
                                              rows=True)

    def in_canonical_order(self, elements: np.ndarray) -> np.ndarray:
        """Elements (slots below m, then border lines m, m + 1, ...; distinct) in the
        order a canonical list gives them: triangles by their corners, then lines."""
        tri = elements[elements < self.m]
        c = self.corners[tri]
        n = self.count
        if n**3 < 2**62:
            order = np.argsort((c[:, 0] * n + c[:, 1]) * n + c[:, 2])  # (distinct triangles: no ties)
        else:
            order = np.lexsort((c[:, 2], c[:, 1], c[:, 0]))
        return np.concatenate([tri[order], np.sort(elements[elements >= self.m])])


def _grown(a: np.ndarray, rows: int) -> np.ndarray:
    """`a` with room for `rows` rows, its rows kept."""
    out = np.empty((rows,) + a.shape[1:], a.dtype)
    out[: len(a)] = a
    return out


def _raster_order(vertices: np.ndarray, segments: np.ndarray, width: int, sort_walls: bool = False):
    """(vertices in raster order, the segments renumbered and cut at the vertices on
    them, the new position of every old vertex): the vertex order and wall steps a
    band's MESH chunk stores, which codec.meshcode triangulates again to check that a
    decoder rebuilds the same triangles. sort_walls: also put the runs of segments
    (the stored polylines) in the raster order of their first vertices, so that their
    stored starts are small forward gaps (about 30 % fewer bytes for them); only before
    a triangulation, which with cocircular vertices may depend on the segment order."""
    # (the vertices are distinct: their pixel numbers have no ties for a stable sort
    # to keep in order, and numpy's default sort is 4-5x quicker on them)
    order = np.argsort(vertices[:, 1] * width + vertices[:, 0])
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
    area = width * height
    cache = _Cache(layout)  # the triangulations not kept (kernel refused, or after finish)
    kept: _Kept | None = None
    ordered = False
    measured = None
    line_sse = None
    final_rows = None  # kept: the slot of each final triangle, whose statistics it has
    z = None  # the values of the last round's vertices
    near = None  # for each vertex the last round added, a corner of the triangle it fell in
    for r in itertools.count():
        tris = None
        last = r == rounds or target <= len(vertices)
        if last and finish is not None:
            if kept is not None:
                # the mean squared error of the last one measured, summed in canonical order
                _, slots = kept.canonical()
                measured = float(np.concatenate([kept.sse[slots], line_sse]).sum()) / area
                cache.seed(vertices, kept.corners[: kept.m], kept.stats[: kept.m], kept.sse[: kept.m], width, height)
                kept = None  # the caller changes the mesh: it is triangulated anew
            vertices, segments = finish(vertices, segments, measured)
        elif r == 0:
            try:
                kept = _Kept(layout, vertices, segments, target)
            except ATMError:
                kept = None  # triangulate() decides, round after round
        elif kept is not None:
            try:
                kept.insert(vertices, near)
            except ATMError:
                kept = None
        if last:
            if kept is not None:
                kept.measure(vertices, None)
            # the last triangulation: made as the MESH chunk's check will make it
            vertices, segments, renumber = _raster_order(vertices, segments, width, sort_walls=True)
            ordered = True
            if kept is not None:
                # the same triangles numbered as the vertices now are, in canonical order
                tris, final_rows = kept.canonical(renumber)
                break
        if kept is not None and z is not None and len(z) < len(vertices):
            # the vertices kept are those of the last round, in place: only the new
            # ones' values are read
            new = vertices[len(z):]
            z = np.concatenate([z, gray[new[:, 1], new[:, 0]].astype(np.float64)])
        else:
            z = gray[vertices[:, 1], vertices[:, 0]].astype(np.float64)
        if kept is not None:
            kept.measure(vertices, z)
            m = kept.m
            tri_sse = kept.sse[:m]
        else:
            tris = triangulate(vertices, segments)
            tri_sse = cache.measure(vertices, tris, z, width, height, ordered)
            m = len(tris)
        missing = target - len(vertices)
        if ordered:
            break
        lines = line_raster(vertices, width, height)
        line_sse = element_sse(lines, layout(lines), z)
        sse = np.concatenate([tri_sse, line_sse])
        if kept is None:
            measured = float(sse.sum()) / area
        if r == 0:
            # (in canonical order: the sums' rounding depends on it)
            ranked = sse if kept is None else np.concatenate([tri_sse[kept.canonical()[1]], line_sse])
            quarter = min(len(ranked), math.ceil(missing / 4))
            if np.partition(ranked, len(ranked) - quarter)[len(ranked) - quarter :].sum() >= CONCENTRATED * ranked.sum():
                rounds = max(rounds, focused_rounds)
        weights = DECAY ** np.arange(rounds - r)
        batch = math.ceil(missing * weights[0] / weights.sum())
        if batch < len(sse):
            # the batch largest, ties to the first in canonical order (as a stable sort
            # of a canonical list would)
            cut = -np.partition(-sse, batch - 1)[batch - 1]
            above = np.flatnonzero(sse > cut)
            tied = np.flatnonzero(sse == cut)
            if kept is not None and len(above) + len(tied) > batch:
                tied = kept.in_canonical_order(tied)
            cand = np.concatenate([above, tied[: batch - len(above)]])
        else:
            cand = np.arange(len(sse))
        cand = cand[sse[cand] > 0]
        cand = np.sort(cand) if kept is None else kept.in_canonical_order(cand)
        on_tri = cand[cand < m]
        corners = tris[on_tri] if kept is None else kept.corners[on_tri]
        # each candidate triangle's worst pixel (in canonical order)
        owns, x, y, err = worst_pixels(gray, vertices, corners, z, width, height)
        # a corner of the triangle each worst pixel lies in: where its insertion's point
        # location starts (the border lines' have none)
        near = corners[owns, 0]
        _, lx, ly, lerr = lines.worst_pixels(gray, z, cand[cand >= m] - m)
        # (np.concatenate: np.r_ parses its index each call, 10 us a time)
        x, y, err = np.concatenate([x, lx]), np.concatenate([y, ly]), np.concatenate([err, lerr])
        near = np.concatenate([near, np.full(len(lx), -1, np.int64)])
        big = err > 0.5
        if not big.any() and finish is not None:
            rounds = r + 1  # nothing worth a vertex, but the caller's still go in
            continue
        if not big.any():
            # nothing worth a vertex: keep this triangulation, in raster order
            if kept is not None:
                tris, final_rows = kept.canonical()
            vertices, segments, renumber = _raster_order(vertices, segments, width)
            tris = renumber[tris]
            break
        points = np.stack([x[big], y[big]], axis=1)
        if kept is not None and finish is None:
            # inserted now (a finish would change the mesh first: those wait for it)
            try:
                vertices, near = kept.add(vertices, points, near[big])
                continue
            except ATMError:
                kept = None  # triangulate() decides, round after round
        vertices, near = merge_new(width, vertices, points, near[big])
    lines = line_raster(vertices, width, height)
    elements = mesh_elements(vertices, tris, lines)
    if final_rows is None:
        return vertices, segments, tris, elements, cache.statistics(layout(lines)), ordered
    # the kept statistics of the final triangles, the border lines' after them
    return vertices, segments, tris, elements, _gathered([kept.stats], final_rows, layout(lines), layout.width), ordered
