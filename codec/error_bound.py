"""Error-bounded refinement: insert vertices where the decoded error is largest until a
bound holds (coarse to fine, as the refinement of section 3.3.1 that section 3.3.2.3
of "Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes" names for bounding
its mesh's error).

The error is measured on the image the decoder will produce (the exact CPU rule), so
a bound reached here holds for every decode. Refinement always ends: at worst every
pixel becomes a vertex holding its own value, which decodes exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import decoder_cpu
from .mesher import values as vertex_values
from .errors import ATMError, OptionError
from . import meshcode
from .mesh import Mesh, segments
from .native import _bound, _renumber
from .triangulate import Triangulation


@dataclass(frozen=True)
class Bound:
    """What refinement must reach: per channel, RMS <= max_rms and/or every
    |error| <= max_error, over the pixels the band is responsible for."""

    max_rms: float | None = None
    max_error: float | None = None

    def __post_init__(self):
        for name in ("max_rms", "max_error"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0):
                raise OptionError(f"{name} must be a number >= 0, not {v!r}")

    @property
    def active(self) -> bool:
        return self.max_rms is not None or self.max_error is not None


#: (quality, RMS): JPEG's error at that quality, the median over the test corpus
#: (tests/corpus.py: camera, coins, moon, text, astronaut, motorcycle disparity; OpenCV's
#: libjpeg; all gray, so no chroma subsampling), so that `quality` gives about JPEG's error at the
#: same quality, not its size (camera at 50: 57.6 KB at RMS 5.1, JPEG 22 KB at 6.0).
#: 100 is lossless, which JPEG never is. Between the points: linear.
JPEG_RMS = (
    (1, 17.37), (5, 12.61), (10, 9.41), (20, 7.35), (30, 6.41), (40, 5.81), (50, 5.34),
    (60, 4.89), (70, 4.31), (75, 3.98), (80, 3.13), (85, 2.72), (90, 2.19), (95, 1.29),
    (98, 0.64), (99, 0.40), (100, 0.0),
)


#: New vertices per round (one per cell of a grid of about that many cells), as a
#: share of the mesh's: the rounds a bound takes grow as log(final / start) / log(1 + GROWTH).
#: Faster growth places vertices worse: adding also 0.1 vertex per pixel over a max_error
#: bound (at most half the mesh) took 25 rounds instead of 32 on the SRTM DEM at
#: max_error=2 but saved no time (the rounds got bigger) and gave 1.5-5 % more bytes
#: (SRTM at 10, the motorcycle disparity at 4); 0.3-1.0 of the RMS excess, 10-15 %.
GROWTH = 0.25

#: The walls are given up when the bad pixels off them number fewer than the bad
#: pixels on them divided by this: what is left is the walls' own error.
WALL_TAIL = 4

#: Under a max_error below one level (every level must come back exact: float data
#: whose quantisation step max_error chose with no slack, codec.slack), new vertices per
#: round are also at least this share of the pixels over it (one per cell, as above).
#: Most pixels are over such a bound until most are vertices, so rounds of GROWTH alone
#: are many and small, each paying for a whole render and measurement: float DEMs
#: (synthetic 1024² at 0.5/5/50, SRTM at 0.5/2/10) took 28-35 rounds, with this 12-24,
#: for +0.20/+0.49/+1.42 and -0.01/+0.76/+0.15 % bytes (0.1 gave up to 7.7 %).
#: Under wider bounds (integer data) it cost bytes: motorcycle disparity at
#: max_error=4 +12.8 %, camera at 6 +2.5 %, uint16 SRTM at 3 +1.1 %.
FAR = 0.05


def quality_rms(quality: int, dtype: np.dtype) -> float:
    """The RMS bound that `quality` (1..100, JPEG's scale: about JPEG's error at the same
    quality) stands for, for 8-bit samples; scaled by the sample range for 16-bit."""
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise OptionError(f"quality must be a whole number from 1 to 100, not {quality!r}")
    scale = np.iinfo(dtype).max / 255.0
    q, rms = zip(*JPEG_RMS)
    return scale * float(np.interp(quality, q, rms))


def _segments_mask(mesh: Mesh) -> np.ndarray:
    """Pixels on or next to a constraint segment: new vertices there would split a wall."""
    import cv2

    mask = np.zeros((mesh.height, mesh.width), np.uint8)
    if mesh.constraints:
        lines = [mesh.vertices[c].astype(np.int32).reshape(-1, 1, 2) for c in mesh.constraints]
        cv2.polylines(mask, lines, False, 1)
    return mask.astype(bool)


class _Growing:
    """A mesh's triangulation kept by codec.triangulate.Triangulation while refinement
    adds vertices: a round inserts its new vertices instead of triangulating all of
    them again. The triangles are those meshcode.in_stored_order makes (ATM.md
    §4.2.5's triangulation is unique), in the mesh's own vertex numbering: refinement
    keeps its vertices in the order they came (the last round's, then the new ones)
    and puts them in stored order once, at the end (sorting them and the triangles
    every round cost as much as triangulating)."""

    def __init__(self, mesh: Mesh) -> None:
        """mesh: its triangles the triangulation of its vertices and walls; later
        vertices must lie inside its vertices' hull (a band's corners)."""
        self._tri = Triangulation(mesh.vertices)
        self._tri.constrain(segments(mesh.constraints))
        self._kernel = np.arange(len(mesh.vertices))  # each vertex's number in _tri

    def grow(self, grown: Mesh, old: int) -> Mesh:
        """`grown` (the last mesh's vertices, the first `old`, then the new ones, with
        the last mesh's walls) with the triangulation of its vertices and walls as
        triangles, numbered as its vertices are."""
        added = self._tri.insert(grown.vertices[old:])
        self._kernel = np.concatenate([self._kernel, added])
        triangles = self._tri.triangles()
        if not np.array_equal(self._kernel, np.arange(len(self._kernel))):
            number = np.empty(len(self._kernel), np.int64)  # the mesh's number of each of _tri's
            number[self._kernel] = np.arange(len(self._kernel))
            triangles = number[triangles]
        return Mesh(grown.vertices, grown.values, triangles, grown.width, grown.height,
                    grown.constraints, grown.holes)


def _pixels(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The samples of `image` (H x W or H x W x C) at the points `xy` (K x 2: x, y), as
    image[y, x]: one np.take of whole rows of the image seen as H*W x C (indexing two
    axes of an RGB photo took three times as long)."""
    h, w = image.shape[:2]
    return np.take(image.reshape(h * w, *image.shape[2:]), xy[:, 1] * w + xy[:, 0], axis=0)


class _Errors:
    """The decoded mesh's squared error per pixel (the decoder's exact rule), kept
    between refinement rounds: a round measures again only the triangles that have a
    vertex it added or whose value it changed (inserting vertices into the unique
    triangulation replaces only triangles that come to have one of them as a corner, so
    every other pixel decodes as before). Owns its buffers."""

    def __init__(self, image: np.ndarray, valid: np.ndarray | None, height: int, width: int) -> None:
        self.height, self.width = height, width
        # in the stored samples' own type where the kernel takes it (a quarter or an
        # eighth of float64's size: fewer cache lines to wait for)
        keep = image.dtype in (np.uint8, np.uint16)
        self.reference = np.ascontiguousarray(image, dtype=None if keep else np.float64).reshape(height * width, -1)
        channels = self.reference.shape[1]
        self.valid = None if valid is None else np.ascontiguousarray(valid, dtype=np.uint8).reshape(-1)
        self.worst = np.zeros(height * width)
        # each row's sum per channel, kept by the kernel where the errors are whole
        # numbers (integer samples): exact, as a float64 sum of them is below 2**53
        self.rows = np.zeros((height, channels), np.int64) if keep else None
        # the errors per channel only where the largest is not all of it: with integer
        # samples as the decoded image (the kernel's old errors for the row sums, at an
        # eighth of the memory for 8-bit samples; an error of 0 until measured), else
        # as they are
        self.decoded = self.reference.copy() if keep and channels > 1 else None
        self.squared = np.zeros((height * width, channels)) if channels > 1 and not keep else None

    def measure(self, mesh: Mesh, changed: np.ndarray | None = None) -> None:
        """Measure the triangles of `mesh` that have a corner marked in `changed` (per
        vertex; None: all of them)."""
        h, w = self.height, self.width
        if len(mesh.triangles) == 0 or h * w > 1 << 32:
            # a one-pixel-wide image (no triangles), or one the decoder refuses
            decoded = decoder_cpu.render(mesh).reshape(h * w, -1)
            if self.decoded is not None:
                self.decoded[:] = decoded
            sq = self._squared(decoded)
            self.worst[:] = sq.max(axis=1)
            if self.squared is not None:
                self.squared[:] = sq
            if self.rows is not None:
                self.rows[:] = sq.reshape(h, w, -1).astype(np.int64).sum(axis=1)
            return
        _bound.measure(
            np.ascontiguousarray(mesh.vertices, dtype=np.int64),
            np.ascontiguousarray(mesh.values, dtype=np.int64).reshape(len(mesh.vertices), -1),
            np.ascontiguousarray(mesh.triangles, dtype=np.int64),
            None if changed is None else np.ascontiguousarray(changed, dtype=np.uint8),
            self.reference, self.valid, self.worst, self.squared, w, h, self.rows, self.decoded,
        )

    def _squared(self, decoded: np.ndarray) -> np.ndarray:
        """H*W x C squared errors of the `decoded` image (H*W x C), holes 0."""
        diff = decoded.astype(np.float64) - self.reference
        sq = diff * diff
        if self.valid is not None:
            sq[self.valid == 0] = 0.0
        return sq

    def per_channel(self) -> np.ndarray:
        """H x W x C squared errors (holes 0)."""
        if self.decoded is not None:
            sq = self._squared(self.decoded)
        else:
            sq = self.worst if self.squared is None else self.squared
        return sq.reshape(self.height, self.width, -1)

    def total(self, rows: np.ndarray) -> np.ndarray:
        """Per channel, the sum of the squared errors of the `rows` (a mask, H): the
        kept row sums where they are exact in float64 (the value the float64 sum of the
        errors has, in any order), else that sum."""
        if self.rows is not None:
            total = self.rows[rows].sum(axis=0)
            if total.max(initial=0) < 1 << 53:
                return total
        return self.per_channel()[rows].sum(axis=(0, 1))


def refine_to_bound(
    mesh: Mesh,
    image: np.ndarray,
    bound: Bound,
    *,
    values: str = "sample",
    pinned_rows: int = 0,
    last_band: bool = True,
    valid: np.ndarray | None = None,
    delaunay: bool = False,
    progress: Callable[[float], None] | None = None,
) -> tuple[Mesh, bool]:
    """Insert vertices into `mesh` (of `image`) until `bound` holds. Returns the mesh
    (the same object if nothing changed) and whether its triangles are the ones a
    decoder rebuilds: each round triangulates the vertices in stored order
    (meshcode.in_stored_order), so this is `delaunay` (said of the given mesh) until
    a round adds vertices, and True after.

    pinned_rows: the first rows are fixed (shared with the band above): no vertex is
        added there and their vertices keep their values.
    last_band: if False, the band's last row is shared with the band below, which
        counts it: the RMS bound is then met by the rows above it and, separately, by
        the last row alone, so that the bound holds over the whole image.
    values: how new vertex values are chosen ("sample" or "lsq", as the mesher did).
    valid: pixels that count (holes do not); `image` then holds filled values in holes.
    progress: called after each round with the share of the work done, 0..1 (how far
        the pixels over the bound have shrunk from the first round's), never falling.
    """
    if not bound.active:
        return mesh, delaunay
    h, w = mesh.height, mesh.width
    sq_limit = None if bound.max_error is None else bound.max_error**2
    rms_sq = None if bound.max_rms is None else bound.max_rms**2
    counted = np.ones(h, bool)
    if not last_band and h > 1:
        counted[-1] = False
    fixed = mesh.vertices[:, 1] < pinned_rows
    walls = _segments_mask(mesh).view(np.uint8) if mesh.constraints else None
    sampled = np.zeros(len(mesh.vertices), bool)
    first_bad, done = None, 0.0
    layout = None
    # the triangulation kept between rounds (None: not made, or its walls changed;
    # False: the kernel refused the mesh, so each round triangulates in full)
    growing: _Growing | None | bool = None
    errors = _Errors(image, valid, h, w)
    changed = None  # per vertex: its triangles are measured again (None: all are)
    is_vertex = np.zeros((h, w), np.uint8)
    is_vertex[mesh.vertices[:, 1], mesh.vertices[:, 0]] = 1
    over_limit = np.inf if sq_limit is None else sq_limit + 1e-9
    while True:
        errors.measure(mesh, changed)
        worst = errors.worst.reshape(h, w)
        # a pixel is bad over its row's limit: the max_error bound's, and the RMS
        # bound's where the RMS of the rows it belongs to is over it
        row_limit = np.full(h, over_limit)
        if rms_sq is not None:
            for rows in ([counted], [~counted]) if not last_band else ([counted],):
                sel = rows[0]
                count = sel.sum() * w if valid is None else valid[sel].sum()
                if count and (errors.total(sel) / count > rms_sq + 1e-9).any():
                    row_limit[sel] = np.minimum(row_limit[sel], rms_sq)
        row_limit[:pinned_rows] = np.inf
        over, bad_count, candidates, on_walls = _bound.count(worst, row_limit, over_limit, is_vertex, walls)
        if not bad_count:
            return mesh, delaunay
        if progress is not None:
            first_bad = first_bad or bad_count
            done = max(done, 1.0 - bad_count / first_bad)
            progress(done)
        # a bad pixel that is already a vertex (fitted, not sampled) gets its own value
        vy = mesh.vertices[:, 1]
        at_vertex = (errors.worst[vy * w + mesh.vertices[:, 0]] > row_limit[vy]) & ~fixed
        count = max(8, int(len(mesh.vertices) * GROWTH))
        if sq_limit is not None and bound.max_error < 1:
            count = max(count, int(FAR * over))
        cell = max(1, int(math.sqrt(h * w / max(count, 1))))
        # the triangles before this round are the unique triangulation of ATM.md §4.2.5
        # of their vertices and of the walls the new one keeps (so inserting vertices
        # changes only triangles that come to touch one: see below)
        unique_before = delaunay
        if on_walls and (candidates == 0 and not at_vertex.any() or WALL_TAIL * candidates < on_walls):
            # (almost) only wall pixels are left: take them, splitting walls is better
            # than failing; once the walls are gone their pixels are like any other
            # (waiting for the last few others first took a round each: 15 of 41
            # rounds on the SRTM DEM at max_error=2)
            new = _bound.spread(worst, row_limit, is_vertex, None, cell)
            mesh = Mesh(mesh.vertices, mesh.values, mesh.triangles, w, h, [], mesh.holes)
            walls = None
            unique_before = False
            if growing:
                growing = None
        else:
            new = _bound.spread(worst, row_limit, is_vertex, walls, cell)
        # the pixels that decode differently after this round: those of triangles with
        # a new vertex or a vertex whose value changes, if the triangles before the
        # round were the unique triangulation and the kernel kept it (else all)
        incremental = len(new) == 0
        # per vertex: sampled (its own pixel value from now on; so far, or now), its
        # value so far (new ones: their pixel's), fixed
        old_sampled, old_triangles = sampled, mesh.triangles
        was_sampled = np.concatenate([sampled | at_vertex, np.zeros(len(new), bool)])
        sampled = np.concatenate([sampled | at_vertex, np.ones(len(new), bool)])
        fixed = np.concatenate([fixed, np.zeros(len(new), bool)])
        grown = Mesh(
            np.concatenate([mesh.vertices, new]) if len(new) else mesh.vertices,
            np.concatenate([mesh.values, _pixels(image, new)]) if len(new) else mesh.values,
            mesh.triangles, w, h, mesh.constraints, mesh.holes,
        )
        order = np.arange(len(grown.vertices))
        if len(new):
            # the triangulation a decoder rebuilds: the writer then need not
            # triangulate again to check
            if growing is None and unique_before:
                try:
                    growing = _Growing(mesh)
                except ATMError:
                    growing = False
            if growing:
                try:
                    grown = growing.grow(grown, len(mesh.vertices))
                    incremental = unique_before
                except ATMError:  # a vertex outside the first ones' hull
                    growing = False
            if not growing:
                order = meshcode.stored_permutation(grown)
                grown = meshcode.in_stored_order(grown)
                sampled, fixed, was_sampled = sampled[order], fixed[order], was_sampled[order]
            delaunay = True
        vertices, triangles = grown.vertices, grown.triangles
        if values == "sample":
            vals = grown.values.copy()
            at = np.flatnonzero(sampled)  # (masks on N x C arrays: three times as long)
            vals[at] = _pixels(image, vertices[at])
        else:
            # vertices whose own pixel was off keep their pixel value from now on
            previous = grown.values.copy()
            at = np.flatnonzero(was_sampled)
            previous[at] = _pixels(image, vertices[at])
            # only what the round changed is fitted again: the corners of the new
            # triangles and the neighbours of vertices that took their pixel value;
            # the rest of the mesh keeps its values (refitting it all each round cost
            # most of the time: 16 s of 30 on the SRTM DEM at max_error=2)
            renumber = np.empty(len(order), np.int64)
            renumber[order] = np.arange(len(order))
            became = (was_sampled & ~np.concatenate([old_sampled, np.zeros(len(new), bool)]))[order]
            if unique_before:
                # inserting a vertex into that triangulation replaces only triangles
                # whose circumcircle holds it, by triangles that have it as a corner
                # (the triangulation is unique, so however it is built): the new
                # triangles are those with a new corner (matching all old triangles
                # against the new cost 1.8 s of 16 on a 512² DEM at max_error=2)
                marked = became.copy()
                marked[renumber[len(old_sampled):]] = True
                free = _bound.around(np.ascontiguousarray(triangles, dtype=np.int64), marked.view(np.uint8))
            else:
                touched = _new_triangles(renumber[old_triangles], triangles, len(vertices))
                touched |= became[triangles].any(axis=1)
                free = np.zeros(len(vertices), bool)
                free[triangles[touched]] = True
            free &= ~was_sampled & ~fixed
            if layout is None:
                layout = vertex_values.layout_for(image)
            vals = vertex_values.refit(image, vertices, triangles, previous, free, layout)
        vals[fixed] = grown.values[fixed]
        if incremental:
            old = len(mesh.vertices)
            changed = np.ones(len(vertices), bool)
            changed[:old] = (vals[:old] != mesh.values).reshape(old, -1).any(axis=1)
        else:
            changed = None
        is_vertex[new[:, 1], new[:, 0]] = 1
        mesh = Mesh(vertices, vals, triangles, w, h, grown.constraints, mesh.holes)


def _new_triangles(old_triangles: np.ndarray, triangles: np.ndarray, n: int) -> np.ndarray:
    """Mask of `triangles` that are not among `old_triangles` (both in the same vertex
    numbering, of n vertices), whichever corner a triangle is listed from."""
    if len(old_triangles) == 0:
        return np.ones(len(triangles), bool)

    def keys(t: np.ndarray):
        t = np.sort(t, axis=1).astype(np.int64)
        if n**3 < 2**63:
            return (t[:, 0] * n + t[:, 1]) * n + t[:, 2]
        return np.ascontiguousarray(t).view(np.dtype((np.void, 24))).ravel()

    # a sorted table and binary search: np.isin hashed these keys at about 1 s a call
    # for 300k triangles
    old = np.sort(keys(old_triangles))
    new = keys(triangles)
    at = np.minimum(np.searchsorted(old, new), len(old) - 1)
    return old[at] != new
