"""Constrained Delaunay triangulation of sample pixels, the triangulation of ATM.md
§4.2.5, two ways that give the same triangles: delaunay() by the compiled kernel
codec._cdt (codec/cdt.hpp; the decoder's, and through triangulate() the encoder's),
by_triangle() by Shewchuk's Triangle and the canonical flip pass of codec.canonical
(an independent construction, kept to check the kernel against)."""

from __future__ import annotations

import numpy as np

from .errors import ATMError
from .mesh import segments
from .native import _cdt


#: Largest coordinate extent (max - min, either axis) at which Triangle's plain
#: floating-point predicates are exact (see triangulate).
EXACT_EXTENT = 4095

_CROSSING = (
    "constraint segments cross each other, so the triangulation would need vertices "
    "off the pixel grid"
)


def delaunay(vertices: np.ndarray, segments: np.ndarray | None = None, *,
             strict: bool = False) -> np.ndarray:
    """The triangulation of ATM.md §4.2.5 of integer (x, y) vertices with every segment
    (pairs of vertex indices) an edge: M x 3 positively oriented triangles in canonical
    order (§4.2.3), none when all vertices lie on one line (a one-pixel-wide image needs
    no triangles). A segment passing over vertices is cut at them (strict: refused, as
    ATM.md §4.2.3 constraint 6 refuses a polyline step over a vertex).

    The vertex set is used as given: a triangulation that would need an extra vertex
    (crossing segments) is refused, because vertices must stay on pixel centres. The
    GIL is released while the kernel works.
    """
    return delaunay_and_crc(vertices, segments, strict=strict)[0]


def delaunay_and_crc(vertices: np.ndarray, segments: np.ndarray | None = None, *,
                     strict: bool = False) -> tuple[np.ndarray, int]:
    """delaunay's triangles and the CRC-32 of their list as u32 little-endian values
    (ATM.md's triangle_crc, coding.triangle_crc's value), which the kernel computes as
    it writes them: the decoder's check needs no copy of the triangles."""
    return _run(_cdt.triangulate, vertices, segments, strict)


class Delaunay:
    """delaunay_and_crc again and again in buffers this object owns: after its first
    call, the kernel's arrays that grow with the vertices reuse their memory instead of
    faulting in fresh pages (a decoder's, for band after band and file after file). One
    thread at a time."""

    def __init__(self) -> None:
        self._kernel = _cdt.Delaunay()

    def triangles_and_crc(self, vertices: np.ndarray, segments: np.ndarray | None = None, *,
                          strict: bool = False) -> tuple[np.ndarray, int]:
        """delaunay_and_crc(vertices, segments, strict=strict), in this object's buffers."""
        return _run(self._kernel.triangulate, vertices, segments, strict)


def _run(kernel, vertices: np.ndarray, segments: np.ndarray | None, strict: bool) -> tuple[np.ndarray, int]:
    """(triangles, crc) of a kernel entry point (_cdt.triangulate's signature)."""
    v = np.ascontiguousarray(vertices, dtype=np.int64).reshape(-1, 2)
    if segments is None:
        s = np.zeros((0, 2), np.int64)
    else:
        s = np.ascontiguousarray(segments, dtype=np.int64).reshape(-1, 2)
    status, triangles, _, crc = kernel(v, s, strict)
    if status != _cdt.OK:
        _refuse(status, len(v))
    return triangles, crc


def _refuse(status: int, n: int) -> None:
    """Raise the error a kernel status code stands for."""
    if status == _cdt.CROSSING:
        raise ATMError(_CROSSING)
    if status == _cdt.DUPLICATE:
        raise ATMError("two vertices of the triangulation share a position")
    if status == _cdt.EXTENT:
        raise ATMError("the vertices span more than 2^28 - 1 in x or y, beyond the exact predicates")
    if status == _cdt.INDEX:
        raise ATMError(f"a constraint segment names a vertex beyond the {n} vertices")
    if status == _cdt.OVER:
        raise ATMError("a polyline step passes over a vertex, so it is no triangle edge")
    if status == _cdt.OUTSIDE:
        raise ATMError("a point lies outside the triangulated hull (or all points lie on one line)")
    if status == _cdt.MEMORY:
        raise MemoryError(f"no memory to triangulate {n} vertices")
    raise ATMError(f"the triangulation kernel failed (status {status}): please report this input")


class Triangulation:
    """delaunay's triangulation kept up to date while points are inserted and segments
    constrained (for a refinement loop): the same triangles as delaunay() of all the
    points and segments so far. Pixel coordinates 0 .. 2^28 - 1; inserted points lie
    inside the first vertices' hull (an image's corners, say). Owns its buffers.
    track_changes: keep what changes() reports (off, it costs a record per changed
    triangle that nobody reads)."""

    def __init__(self, vertices: np.ndarray, *, track_changes: bool = False) -> None:
        v = np.ascontiguousarray(vertices, dtype=np.int64).reshape(-1, 2)
        self._kernel = _cdt.Triangulation()
        status = self._kernel.start(v, track_changes)
        if status != _cdt.OK:
            _refuse(status, len(v))
        self._count = len(v)

    def insert(self, points: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
        """Insert points (K x 2); returns their vertex indices (the next numbers).
        near: for each point a vertex index near it (-1: none), where its point
        location starts instead of at the last vertex inserted; a hint only, the
        triangles are the same whatever it holds."""
        return self._insert(np.ascontiguousarray(points, dtype=np.int64).reshape(-1, 2), near)

    def insert_free(self, points: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
        """insert(points, near), leaving out each point at a position taken (by a vertex,
        or a point before it) instead of refusing it: merge()'s rule, from the kernel's
        own table of positions. Returns a mask of the points that went in (numbered
        next, in their order)."""
        points = np.ascontiguousarray(points, dtype=np.int64).reshape(-1, 2)
        taken = np.zeros(len(points), np.uint8)
        self._insert(points, near, taken)
        return taken == 0

    def _insert(self, points: np.ndarray, near: np.ndarray | None, taken: np.ndarray | None = None) -> np.ndarray:
        """The kernel's insert of K x 2 int64 points (taken: see insert_free), counted,
        refused as the codec's error when it fails; the new vertices' indices."""
        if near is not None:
            near = np.ascontiguousarray(near, dtype=np.int64).reshape(-1)
        status, indices = self._kernel.insert(points, near, taken)
        self._count += len(indices)
        if status != _cdt.OK:
            _refuse(status, self._count)
        return indices

    def constrain(self, segments: np.ndarray) -> None:
        """Make every segment (S x 2 vertex indices) an edge, cut at vertices on it."""
        status = self._kernel.constrain(np.ascontiguousarray(segments, dtype=np.int64).reshape(-1, 2))
        if status != _cdt.OK:
            _refuse(status, self._count)

    def triangles(self) -> np.ndarray:
        """All triangles (M x 3, positively oriented, canonical order of ATM.md §4.2.3)."""
        return self._kernel.triangles()

    def changes(self) -> tuple[np.ndarray, np.ndarray]:
        """(removed, added) triangles since construction or the last call; only with
        track_changes=True (ValueError otherwise)."""
        return self._kernel.changes()

    def slots(self) -> np.ndarray:
        """Every triangle by the kernel's slot (M x 3, row t the triangle in slot t), each
        rotated to start at its smallest corner as the canonical order lists it: a
        slot keeps its triangle until a change rewrites it, and new slots come last,
        so a caller can keep something per triangle by slot."""
        return self._kernel.slots()

    def dirty(self, into: np.ndarray | None = None):
        """(slots, triangles): the slots rewritten since construction or the last call of
        this or changes() (the two share one record) and the triangle each holds now,
        rotated as slots() rotates them; only with track_changes=True (ValueError
        otherwise). What changes() reports, by slot, with none of the removed corners.
        into (int64, 3 columns, a row per slot at least): each slot's triangle is
        written to its row there, and only the slots are returned."""
        return self._kernel.dirty(into)

    def size(self) -> int:
        """The number of triangles (of slots)."""
        return self._kernel.size()


def triangulate(vertices: np.ndarray, segments: np.ndarray | None = None) -> np.ndarray:
    """The encoder's triangulation: delaunay's triangles (canonical order) of integer
    (x, y) vertices with every segment an edge, cut at the vertices on it; none for
    fewer than three vertices or all on one line. Crossing segments and repeated
    vertices are refused (ATMError). The GIL is released while the kernel works."""
    return delaunay(vertices, segments)


def by_triangle(vertices: np.ndarray, segments: np.ndarray | None = None, *,
                exact: bool = False) -> np.ndarray:
    """delaunay's triangles (not in canonical order) by Shewchuk's Triangle and the
    canonical flip pass: the construction ATM.md §4.2.5 describes, independent of the
    kernel (tests and benchmarks compare the two; the codec itself uses the kernel,
    7-8x faster on a band's vertices). Crossing segments are refused as by delaunay; a
    repeated vertex is dropped by Triangle (delaunay refuses it).

    Triangle's exact arithmetic is skipped where that provably changes nothing
    (exact=True keeps it, for tests: the result is identical).
    """
    # Triangle and the flip pass serve only this check: a decode does not import them
    import triangle

    from .canonical import canonicalise

    vertices = np.asarray(vertices, dtype=np.int64)
    if segments is not None:
        segments = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
        if len(segments) == 0:
            segments = None
    if len(vertices) < 3 or np.ptp(vertices[:, 0]) == 0 or np.ptp(vertices[:, 1]) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    coords, switches = vertices, "Q"
    low = vertices.min(axis=0)
    if not exact and int((vertices.max(axis=0) - low).max()) <= EXACT_EXTENT:
        # Triangle's predicates work on coordinate differences: orient2d forms
        # dx1 dy2 - dy1 dx2 and incircle sum(lift_i (dx_j dy_k - dx_k dy_j)) with
        # lift_i = dx_i^2 + dy_i^2. With integer coordinates at most 4095 apart every
        # difference is an integer below 2^12, every product below 2^24, every lift and
        # 2x2 determinant below 2^25 and the incircle sum below 3 * 2^50 < 2^53: each
        # step is an exact double operation, so the plain predicates return the exact
        # values and switch X (no exact arithmetic) gives the same triangulation. The
        # shift to the minimum keeps the doubles small (it moves nothing relative).
        coords, switches = vertices - low, "QX"
    data = {"vertices": coords.astype(np.float64)}
    if segments is not None:
        data["segments"] = segments.astype(np.int32)
        switches = "pc" + switches
    # B, N: no boundary markers or vertices back; a vertex Triangle had to add is then
    # seen as a triangle corner beyond the input's. The segments come back as the edges
    # they became (cut at the vertices on them; the hull's edges too, never flipped)
    result = triangle.triangulate(data, switches + "BN")
    triangles = np.asarray(result.get("triangles", np.zeros((0, 3))), dtype=np.int64)
    if len(triangles) and int(triangles.max()) >= len(vertices):
        raise ATMError(_CROSSING)
    # Triangle lists every triangle counterclockwise with x right and y up, which is a
    # positive doubled area here; mesh.validate checks it wherever a mesh is written or
    # read, so it is not computed a second time on this hot path
    # ties between cocircular vertices are Triangle's to break as its input order falls:
    # the format's own rule decides them (ATM.md section 4.2.5)
    triangles = canonicalise(vertices, triangles, result.get("segments"))
    return triangles


def split_at_vertices(vertices: np.ndarray, segments: np.ndarray, width: int,
                      *, origin: bool = False):
    """Cut every segment at the vertices lying inside it (as the constrained
    triangulation does), keeping the order along it; `width` numbers the pixels. With
    origin=True, also return the index of the input segment each piece comes from.
    Zero-length segments vanish."""
    segments = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    source = np.flatnonzero(segments[:, 0] != segments[:, 1])
    segments = segments[source]
    if len(segments) == 0:
        return (segments, source) if origin else segments
    # vertices found by pixel key in sorted order: memory grows with the vertices, not
    # with the band
    keys = vertices[:, 1].astype(np.int64) * width + vertices[:, 0]
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    a = vertices[segments[:, 0]]
    seg, pts = _lattice_points(a, vertices[segments[:, 1]] - a, ends=True)
    hit, at = _find(keys, pts, width)
    seg, vid = seg[hit], order[at[hit]]
    same = seg[1:] == seg[:-1]
    pieces = np.stack([vid[:-1][same], vid[1:][same]], axis=1)
    return (pieces, source[seg[:-1][same]]) if origin else pieces


def _lattice_points(a: np.ndarray, d: np.ndarray, ends: bool) -> tuple[np.ndarray, np.ndarray]:
    """(segment, (x, y)) of every pixel centre on the segments from points a by steps d
    (K x 2, no step zero), segment by segment from a; the end points too if `ends`."""
    g = np.gcd(np.abs(d[:, 0]), np.abs(d[:, 1]))  # the segment is g unit steps
    count = g + 1 if ends else g - 1
    seg = np.repeat(np.arange(len(a)), count)
    t = np.arange(len(seg)) - np.repeat(np.cumsum(count) - count, count)
    if not ends:
        t += 1
    return seg, a[seg] + t[:, None] * (d // g[:, None])[seg]


def _find(keys: np.ndarray, pts: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(found, at): whether each point's pixel number is among the sorted `keys`, and
    where in them (meaningful where found)."""
    q = pts[:, 1] * width + pts[:, 0]
    at = np.minimum(np.searchsorted(keys, q), len(keys) - 1)
    return keys[at] == q, at


def through_vertices(vertices: np.ndarray, polylines: list[np.ndarray]) -> list[np.ndarray]:
    """The polylines with every vertex that lies exactly on one of their segments put
    in its place along the segment (split_at_vertices, polyline by polyline): their
    steps are then the edges a constrained triangulation keeps."""
    if not polylines:
        return polylines
    v = np.asarray(vertices, dtype=np.int64)
    pieces, source = split_at_vertices(
        v, segments(polylines), int(v[:, 0].max()) + 1, origin=True
    )
    # each step came from one polyline: regroup the pieces by it
    owner = np.repeat(np.arange(len(polylines)), [len(c) - 1 for c in polylines])[source]
    if not len(pieces):
        return []
    # each run's first vertices, then its last step's end, split all at once (a loop
    # over a 2048² band's thousands of walls took 16 ms)
    ends = np.r_[np.flatnonzero(np.diff(owner)) + 1, len(pieces)]
    flat = np.insert(pieces[:, 0], ends, pieces[ends - 1, 1])
    bounds = np.r_[0, ends + np.arange(1, len(ends) + 1)].tolist()
    return [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
