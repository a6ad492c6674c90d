"""The 2.5-D triangular mesh that an .atm file stores, and its invariants."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from . import limits
from .errors import CorruptError, LimitError
from .native import _fields


class Polylines(Sequence):
    """Polylines stored one after another, as a decoder reads them: `flat` vertex
    indices and each polyline's length. It reads as a list of index arrays (each a
    view of `flat`, made when asked), so that a band of hundreds of walls does not
    make hundreds of arrays it may never use."""

    __slots__ = ("flat", "lengths", "_starts")

    def __init__(self, flat: np.ndarray, lengths: np.ndarray):
        self.flat = flat
        self.lengths = lengths
        self._starts: list[int] | None = None

    def __len__(self) -> int:
        return len(self.lengths)

    def _bounds(self) -> list[int]:
        if self._starts is None:
            self._starts = np.r_[0, np.cumsum(self.lengths)].tolist()
        return self._starts

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        k = range(len(self))[i]  # IndexError, negative indices as a list's
        bounds = self._bounds()
        return self.flat[bounds[k] : bounds[k + 1]]

    def __iter__(self) -> Iterator[np.ndarray]:
        bounds, flat = self._bounds(), self.flat
        for a, b in zip(bounds[:-1], bounds[1:]):
            yield flat[a:b]


@dataclass(eq=False)
class Mesh:
    """A triangulated image.

    vertices:    N x 2 int64, (x, y) = (column, row) of a pixel centre.
    holes:       optional H x W mask of pixels without data.
    values:      N (gray) or N x C (colour) samples, the image's dtype.
    triangles:   M x 3 int64 vertex indices, each with positive doubled area
                 (x1-x0)(y2-y0) - (x2-x0)(y1-y0) > 0 (clockwise on screen, y down).
    constraints: polylines (arrays of vertex indices) the triangulation keeps as edges:
                 the walls along image discontinuities.
    """

    vertices: np.ndarray
    values: np.ndarray
    triangles: np.ndarray
    width: int
    height: int
    constraints: Sequence[np.ndarray] = field(default_factory=list)
    #: height x width booleans, True where the image has no data (None: no holes).
    #: Decoders give hole pixels the file's nodata value; no vertex value comes from them.
    holes: np.ndarray | None = None

    @property
    def dtype(self) -> np.dtype:
        return self.values.dtype

    @property
    def channels(self) -> int:
        return 1 if self.values.ndim == 1 else self.values.shape[1]

    def __repr__(self) -> str:
        return (
            f"Mesh({self.width}x{self.height}, {len(self.vertices)} vertices, "
            f"{len(self.triangles)} triangles, {len(self.constraints)} constraint polylines, "
            f"{self.dtype}, {self.channels} channel(s))"
        )


def doubled_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed doubled areas (x1-x0)(y2-y0) - (x2-x0)(y1-y0), exact in int64."""
    x = vertices[:, 0].astype(np.int64)
    y = vertices[:, 1].astype(np.int64)
    # corner by corner, so that the arithmetic runs on contiguous arrays
    a, b, c = np.asarray(triangles).T
    xa, ya = x[a], y[a]
    return (x[b] - xa) * (y[c] - ya) - (x[c] - xa) * (y[b] - ya)


def orient(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Return the triangles reordered so that every doubled area is positive."""
    triangles = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    flip = doubled_areas(vertices, triangles) < 0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return triangles


def validate(mesh: Mesh, *, walls_are_edges: bool = False, tiles: bool = False,
             areas: np.ndarray | None = None, checked: tuple | None = None, lines_checked: bool = False) -> None:
    """Raise CorruptError (or LimitError) unless the mesh is one the decoders can render.

    Checked: shapes, index ranges, vertices inside the image and distinct, triangle
    orientation, that the triangles tile the image (ATM.md §4.2.3, constraint 4: total
    area, and edges shared as a tiling shares them, unless the caller knows it: tiles),
    constraint indices, and that every constraint step is a triangle edge (unless the
    caller knows it: walls_are_edges). areas: the triangles' doubled_areas, when the
    caller has them already; checked: what _fields.mesh_checks gives for these vertices,
    triangles and areas, when the caller has it (a decoder's band_values makes it in
    its own pass over the triangles); lines_checked: the caller made the polylines with
    every length at least 2 and every index a vertex (a decoder's _fields.chains and
    band_vertices), which with walls_are_edges leaves nothing of them to check.
    """
    w, h = mesh.width, mesh.height
    limits.check_image_size(w, h)
    v, t = mesh.vertices, mesh.triangles
    if v.ndim != 2 or v.shape[1] != 2 or len(v) == 0:
        raise CorruptError(f"vertices must be a non-empty N x 2 array, got shape {v.shape}")
    if len(v) > limits.max_vertices(w, h):
        raise LimitError(f"{len(v):,} vertices is too many for a {w}x{h} image")
    if t.ndim != 2 or t.shape[1] != 3:
        raise CorruptError(f"triangles must be an M x 3 array, got shape {t.shape}")
    if len(t) > limits.max_triangles(w, h):
        raise LimitError(f"{len(t):,} triangles is too many for a {w}x{h} image")
    vals = mesh.values
    if vals.shape[0] != len(v) or vals.ndim not in (1, 2):
        raise CorruptError(f"{len(vals)} values for {len(v)} vertices")
    known = None  # the triangles' edges as sorted keys, once _check_edges has them
    x, y = v[:, 0], v[:, 1]
    # the element checks in one compiled pass (their numpy passes cost more than the
    # work on a small band): vertices inside, corners in range, areas positive
    v64, t64 = np.ascontiguousarray(v, dtype=np.int64), np.ascontiguousarray(t, dtype=np.int64)
    status, increasing, area, extent = checked if checked is not None else _fields.mesh_checks(
        v64, t64, None if areas is None else np.ascontiguousarray(areas, dtype=np.int64), w, h
    )
    if status == _fields.MeshCheck.MESH_OUTSIDE:
        raise CorruptError(f"a vertex lies outside the {w}x{h} image")
    # decoded meshes come in raster order, where distinctness is a linear-time check
    if not increasing and len(np.unique(y.astype(np.int64) * w + x)) != len(v):
        raise CorruptError("two vertices share a pixel")
    if status == _fields.MeshCheck.MESH_INDEX:
        raise CorruptError(f"a triangle refers to a vertex beyond the {len(v)} stored")
    if status == _fields.MeshCheck.MESH_DEGENERATE:
        raise CorruptError("a triangle is degenerate or wrongly oriented")
    if len(t):
        if w > 1 and h > 1 and area != 2 * (w - 1) * (h - 1):
            raise CorruptError("the triangles do not cover the image exactly once")
        if not tiles:
            known = _check_edges(v64, t64, w, h)
        # rows crossed by all triangles, plus their count
        if extent > limits.max_triangle_rows(w, h):
            raise LimitError(
                f"the triangles cross {extent:,} rows in all, too many to render a {w}x{h} "
                "image in bounded time (raise codec.limits.MAX_TRIANGLE_ROWS_PER_PIXEL to accept it)"
            )
    if (w > 1 and h > 1) != (len(t) > 0):
        raise CorruptError(
            "a mesh needs triangles exactly when the image is at least 2 pixels each way"
        )
    if len(t) == 0 and (w > 1 or h > 1):
        along = x if h == 1 else y
        if along.min() != 0 or along.max() != max(w, h) - 1:
            raise CorruptError("a one-pixel-wide mesh needs a vertex at each end of the line")
    if not mesh.constraints or (lines_checked and walls_are_edges):
        return
    lines = mesh.constraints
    if isinstance(lines, Polylines):  # a decoder's: already one array
        lengths, flat = lines.lengths, lines.flat
    else:
        lengths = np.fromiter(map(len, lines), np.int64, len(lines))
        flat = np.concatenate(lines)
    # with every polyline 2 long or more, its steps name each of its indices
    if lengths.min() < 2 or flat.min() < 0 or flat.max() >= len(v):
        raise CorruptError("a constraint polyline refers to a missing vertex")
    if len(t) and not walls_are_edges:
        walls = chain_steps(flat.astype(np.int64), lengths)
        if known is None:
            known = np.sort(_edge_keys(*edges(t).T, len(v)))
        keys = _edge_keys(walls[:, 0], walls[:, 1], len(v))
        at = np.clip(np.searchsorted(known, keys), 0, len(known) - 1)
        if not (known[at] == keys).all():
            raise CorruptError("a constraint polyline runs along no triangle edge")


#: Most vertices for which _check_edges sorts (edge, side) as single int64 keys.
_KEYED_EDGES = 1 << 31


def _check_edges(v: np.ndarray, t: np.ndarray, w: int, h: int) -> np.ndarray | None:
    """CorruptError unless every edge of the (positively oriented) triangles is shared
    as in a tiling of the image: no two triangles on the same side of an edge, and an
    edge with a triangle on one side only lies on the image's border. With the total
    area equal to the image's, that makes the triangles tile it (ATM.md §4.2.3), which
    is what lets both decoders give every pixel to exactly one triangle, and the same
    one. Returns the edges' _edge_keys, sorted (None for meshes of over _KEYED_EDGES
    vertices)."""
    a = t.ravel()
    b = np.ascontiguousarray(t[:, [1, 2, 0]]).ravel()  # directed edges a -> b
    n = len(v)
    forward = a < b  # which side of the undirected edge its triangle lies on
    if n <= _KEYED_EDGES:
        # one sort of (edge, side) keys, below 2**63
        key = _edge_keys(a, b, n)
        key <<= 1
        key |= forward
        key.sort()
        side = (key & 1).astype(bool)
        key >>= 1
    else:
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        order = np.lexsort((forward, hi, lo))
        lo, hi, side = lo[order], hi[order], forward[order]
        key = None
    same = key[1:] == key[:-1] if key is not None else (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    # sorted by side within an edge: two triangles on one side (or three on an edge)
    # show up as neighbours with equal sides
    if (same & (side[1:] == side[:-1])).any():
        raise CorruptError("two triangles overlap: they lie on the same side of a shared edge")
    alone = np.ones(len(side), bool)
    alone[1:] &= ~same
    alone[:-1] &= ~same
    if key is not None:
        lo, hi = np.divmod(key[alone], n)
    else:
        lo, hi = lo[alone], hi[alone]
    p, q = v[lo], v[hi]
    border = (((p[:, 0] == 0) & (q[:, 0] == 0)) | ((p[:, 0] == w - 1) & (q[:, 0] == w - 1))
              | ((p[:, 1] == 0) & (q[:, 1] == 0)) | ((p[:, 1] == h - 1) & (q[:, 1] == h - 1)))
    if not border.all():
        x, y = p[np.argmin(border)]
        raise CorruptError(
            "the triangles do not tile the image: an edge from vertex "
            f"({x}, {y}) has a triangle on one side only but lies inside the image"
        )
    return key


def segments(polylines: list[np.ndarray]) -> np.ndarray:
    """The (i, j) vertex pairs of every step of every polyline, as one K x 2 array."""
    if not polylines:
        return np.zeros((0, 2), np.int64)
    lengths = np.fromiter(map(len, polylines), np.int64, len(polylines))
    return chain_steps(np.concatenate(polylines).astype(np.int64), lengths)


def chain_steps(flat: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The consecutive pairs of `flat` (polylines one after another, of `lengths`)
    that lie within one polyline: a step does not join one polyline's last entry to
    the next one's first. Works on vertex indices and on K x 2 points alike."""
    inner = np.ones(max(len(flat) - 1, 0), bool)
    inner[np.cumsum(lengths)[:-1] - 1] = False
    return np.stack([flat[:-1][inner], flat[1:][inner]], axis=1)


def edges(triangles: np.ndarray) -> np.ndarray:
    """The 3M directed edges (i, j) of the triangles."""
    t = np.asarray(triangles, dtype=np.int64)
    return np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])


def _edge_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """The key min * n + max of each undirected edge a - b (int64; exact for n <= 2**31)."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    return np.minimum(a, b) * n + np.maximum(a, b)


def without_vertices(mesh: Mesh, keep: np.ndarray) -> Mesh:
    """The mesh's kept vertices, their values, and its walls split where a vertex went
    (pieces shorter than two vertices vanish). Triangles are left empty: the caller
    triangulates again."""
    remap = np.full(len(mesh.vertices), -1, dtype=np.int64)
    remap[keep] = np.arange(int(np.count_nonzero(keep)))
    constraints = []
    lines = [line for line in mesh.constraints if len(line)]  # an empty one keeps nothing
    if lines:
        # the runs of kept vertices within each polyline, found for all at once (a loop
        # over a 2048² band's thousands of walls took 20 ms)
        lengths = np.array([len(line) for line in lines], dtype=np.int64)
        mapped = remap[np.concatenate(lines).astype(np.int64, copy=False)]
        kept = mapped >= 0
        first = np.zeros(len(mapped), bool)
        first[np.cumsum(lengths)[:-1]] = True
        first[0] = True
        starts = kept & (first | ~np.r_[False, kept[:-1]])
        run = np.cumsum(starts) - 1
        sizes = np.bincount(run[kept], minlength=int(starts.sum()))
        take = np.zeros(len(mapped), bool)
        take[kept] = sizes[run[kept]] >= 2
        if take.any():
            bounds = np.r_[0, np.cumsum(sizes[sizes >= 2])].tolist()
            pieces = mapped[take]
            constraints = [pieces[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    return Mesh(
        mesh.vertices[keep], mesh.values[keep], np.zeros((0, 3), np.int64),
        mesh.width, mesh.height, constraints, mesh.holes,
    )
