"""One band's mesh <-> the fields of its MESH payload (format_spec/ATM.md §4.2).

Polylines are stored as chains: a start pixel and the steps to each next vertex, each
step turned by the quadrant of the one before it. The vertices on no polyline are
stored as gaps between their keys, in raster order or along the band's Hilbert curve,
whichever is smaller. Triangles are either listed (canonical order, differences) or
not stored at all and rebuilt by constrained Delaunay triangulation, with a CRC of the
canonical list either way so that a decoder can prove it has the encoder's triangles.
Samples come last: along the polylines, then along the Hilbert curve through the other
vertices, each predicted from an earlier neighbour and stored in units of its vertex's
step (finer where the triangles are larger).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from .format_spec import schema

from . import frames, limits
from .coding import (
    MAX_VARINT_BYTES,
    canonical_triangles,
    hilbert_inverse_tables,
    hilbert_keys,
    hilbert_levels,
    hilbert_points,
    hilbert_tables,
    triangle_crc,
    unvarints,
    unzigzag,
    varints,
    zigzag,
)
from .errors import ATMError, CorruptError, LimitError
from .mesh import Mesh, Polylines, chain_steps, doubled_areas
from .native import _fields, _renumber, _samples
from .triangulate import Delaunay, delaunay_and_crc, triangulate


#: The MESH payload's variable-length fields, in payload order: all after sample_step.
_NAMES = tuple(sub.name for sub in schema.MeshPayload.subcons)
FIELDS = tuple(_NAMES[_NAMES.index("sample_step") + 1 :])


def payload_parts(raw: bytes, fields: dict) -> list[bytes]:
    """A built MESH payload cut before each variable-length field: its fixed fields,
    then each number stream (with its length prefix), for compress_parts."""
    sizes = [len(fields[k]) + 4 for k in FIELDS]
    ends = np.cumsum([len(raw) - sum(sizes)] + sizes).tolist()
    return [raw[a:b] for a, b in zip([0] + ends[:-1], ends)]


def own_parameters_pay(fields: dict) -> bool:
    """Whether a MESH payload's frame is worth trying with level 19's own zstd
    parameters too (frames.compress_parts' `own`): only for a mesh without walls,
    whose values dominate it and whose 3-byte matches those parameters find (RGB
    meshes at a quality: up to 19 % smaller); with walls they lost on 27 of 28 meshes
    and cost half the frame's time."""
    return len(fields["polyline_lengths"]) == 0


#: Largest number of low bits of a position gap stored apart (§4.2.2).
MAX_POSITION_BITS = 24


def _histogram_entropy(counts: np.ndarray) -> float:
    """Order-0 entropy in bytes of data with these byte counts (what zstd's entropy
    stage can reach)."""
    size = int(counts.sum())
    p = counts[counts > 0] / size
    return float(-(p * np.log2(p)).sum() * size / 8)


def position_fields(gaps: np.ndarray, bits: int | None = None) -> dict:
    """The positions and position_bits fields of free-vertex gaps: each gap's low
    `bits` bits packed apart (nearly uniform, so raw bits beat an entropy coder on
    them) and its high part with the count of low bits first as varints. By default
    the split with the smallest estimated size."""
    gaps = np.asarray(gaps, dtype=np.int64)
    if bits is None:
        bits = 0
        if len(gaps):
            # the best split lies a few bits below the mean gap's size
            top = min(MAX_POSITION_BITS, int(np.log2(gaps.mean() + 1)) + 1)
            ks = range(max(0, top - 5), top + 1)
            # the varint bytes of gaps >> k for every k, counted in one compiled pass each
            counts = _samples.varint_histograms(np.ascontiguousarray(gaps), ks[0], ks[-1])
            sizes = [_histogram_entropy(c) + len(gaps) * k / 8 for c, k in zip(counts, ks)]
            bits = ks[int(np.argmin(sizes))]
    low = (gaps[:, None] >> np.arange(bits - 1, -1, -1)) & 1
    return dict(
        positions=varints(np.r_[bits, gaps >> bits]),
        position_bits=np.packbits(low.astype(np.uint8).ravel()).tobytes(),
    )


def _free_keys(m, free: int, span: int, width: int, rows: int, where: str) -> np.ndarray:
    """The keys of the free vertices (pixel keys, or Hilbert keys when stored along the
    curve) from the positions and position_bits fields, each below `span`."""
    nums = unvarints(m.positions, free + 1, f"{where} positions")
    bits = int(nums[0])
    if bits > MAX_POSITION_BITS:
        raise CorruptError(f"{where}: {bits} low bits per position, more than {MAX_POSITION_BITS}")
    packed = np.frombuffer(m.position_bits, np.uint8)
    if len(packed) != (free * bits + 7) // 8:
        raise CorruptError(f"{where}: {len(packed)} bytes of position bits for {free} positions of {bits} bits")
    pad = 8 * len(packed) - free * bits  # all in the last byte
    if pad and packed[-1] & ((1 << pad) - 1):
        raise CorruptError(f"{where}: position bits padded with ones")
    # each gap's high part, its low bits and the running sum in one compiled pass
    ok, keys = _fields.position_keys(nums[1:], packed, bits, span)
    if not ok:
        raise CorruptError(f"{where}: a vertex lies outside the {width}x{rows} band")
    return keys


#: x and y of a step turned by r quarter turns (x, y) -> (-y, x), by r
_COS = np.array([1, 0, -1, 0])
_SIN = np.array([0, 1, 0, -1])
_COS.flags.writeable = _SIN.flags.writeable = False


def quadrants(steps: np.ndarray) -> np.ndarray:
    """The quadrant 0..3 of each non-zero step (dx, dy): 0 for dx > 0 and dy >= 0, and
    each quarter turn (x, y) -> (-y, x) adds one (ATM.md §4.2.2)."""
    dx, dy = steps[:, 0], steps[:, 1]
    return np.where(dx > 0, np.where(dy >= 0, 0, 3), np.where(dy > 0, 1, np.where(dx < 0, 2, 3)))


def turn(steps: np.ndarray, quarters: np.ndarray) -> np.ndarray:
    """Each step turned by its number of quarter turns (x, y) -> (-y, x)."""
    c, s = _COS[quarters % 4], _SIN[quarters % 4]
    return np.stack([c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]], 1)


def _first_steps(lengths: np.ndarray) -> np.ndarray:
    """Index of the first step of each polyline of `lengths` points."""
    return np.cumsum(lengths - 1) - (lengths - 1)


def turned_steps(steps: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The steps as stored (ATM.md §4.2.2): each turned back by the quadrant of the
    step before it on its polyline, so that a polyline going on in about the same
    direction gives about the same numbers whichever way it runs."""
    back = np.r_[0, quadrants(steps[:-1])] if len(steps) else np.zeros(0, np.int64)
    back[_first_steps(lengths)] = 0
    return turn(steps, -back)


def unturned_steps(stored: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The inverse of turned_steps: a step's quadrant is its stored one plus that of
    the step before it, so the turn of each step is a running sum of the stored
    quadrants before it on its polyline."""
    if not len(stored):
        return stored
    q = quadrants(stored)
    before = np.cumsum(q)
    before -= q
    first = _first_steps(lengths)
    return turn(stored, before - np.repeat(before[first], lengths - 1))


#: Vertex steps vary with fan area within 1/STEP_RANGE .. STEP_RANGE times the base step.
STEP_RANGE = 4.0


def vertex_steps(vertices: np.ndarray, triangles: np.ndarray, step: int, top_pinned: bool,
                 areas: np.ndarray | None = None) -> np.ndarray:
    """Every vertex's quantisation step (ATM.md §4.2.2): `step` scaled by the square
    root of the mean fan area over the vertex's own, the factor kept within 1/4..4.
    A vertex's rounding error spreads over its fan, so vertices with large fans
    (smooth regions) get finer steps and crowded ones coarser: the same bits then buy
    less squared error. Step 1 stays 1 everywhere (exact samples); the first row of a
    band below another has step 1, its samples being the band above's. areas: the
    triangles' doubled_areas, when the caller has them."""
    n = len(vertices)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    if areas is None:
        areas = doubled_areas(vertices, triangles)
    # a compiled kernel, the one band_values uses: encoder and decoder share the arithmetic
    steps = _fields.vertex_steps(triangles, np.ascontiguousarray(areas, dtype=np.int64), n, step, STEP_RANGE)
    if steps is None:
        raise CorruptError(f"a triangle refers to a vertex beyond the {n} stored")
    if top_pinned:
        steps[vertices[:, 1] == 0] = 1
    return steps


def _stored_order(mesh: Mesh):
    """(order, inverse, sorted keys, polylines): the vertices in raster order, as
    stored, and the polylines renumbered to it (in their own order: with cocircular
    vertices, the constrained Delaunay triangulation a decoder rebuilds depends on the
    order of the segments)."""
    keys = mesh.vertices[:, 1] * mesh.width + mesh.vertices[:, 0]
    order = np.argsort(keys, kind="stable")
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.arange(len(order))
    return order, inverse, keys[order], [inverse[c] for c in mesh.constraints]


def stored_permutation(mesh: Mesh) -> np.ndarray:
    """Old vertex index of each vertex in stored order (in_stored_order's)."""
    return _stored_order(mesh)[0]


def in_stored_order(mesh: Mesh, *, triangulate_again: bool = True) -> Mesh:
    """The mesh with its vertices in stored order and its polylines renumbered to it;
    triangulated from that order as a decoder rebuilds the triangles (or, with
    triangulate_again=False, its own triangles renumbered). A mesh made this way needs
    no check that a decoder gets its triangles (encode_band's `delaunay`)."""
    order, inverse, _, lines = _stored_order(mesh)
    vertices = mesh.vertices[order]
    if triangulate_again:
        flat = _flat(lines)
        triangles = triangulate(vertices, chain_steps(flat, np.array([len(c) for c in lines], np.int64)))
    else:
        triangles = inverse[mesh.triangles]
    return Mesh(vertices, mesh.values[order], triangles, mesh.width, mesh.height, lines, mesh.holes)


def _flat(lines: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(lines) if lines else np.zeros(0, np.int64)


def _sample_order(vertices: np.ndarray, flat: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sequence, free mask, the free vertices' Hilbert keys in increasing order) for
    raster-ordered vertices: the polyline vertices in the order the polylines first
    reach them (a wall's vertices sit on one side of a step, so each predicts the next
    well), then every other vertex along the Hilbert curve of `levels` levels."""
    first_seen = np.unique(flat, return_index=True)[1]
    on_line = flat[np.sort(first_seen)]
    free = np.ones(len(vertices), dtype=bool)
    free[on_line] = False
    free_idx = np.flatnonzero(free)
    keys = hilbert_keys(vertices[free_idx, 0], vertices[free_idx, 1], levels)
    along = np.argsort(keys)
    return np.concatenate([on_line, free_idx[along]]), free, keys[along]


def sample_parents(triangles: np.ndarray, seq_order: np.ndarray) -> np.ndarray:
    """For each place j of the sample sequence (ATM.md §4.2.4), the place of the sample
    it is predicted from: of the vertices that share a triangle with it and come
    before it, the last; j - 1 if none does (-1: predicted from 0). A neighbour lies on
    the same surface far more often than the previous vertex along the curve, which
    may be across the image."""
    parent = _fields.sample_parents(np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3),
                                    np.ascontiguousarray(seq_order, dtype=np.int64))
    if parent is None:
        raise CorruptError("the sample order is no permutation of the vertices, or a triangle "
                           "refers to a vertex beyond them")
    return parent


def tree_sums(increments: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Each sample as its increment plus its parent's sample (parent[j] < j; -1: none),
    in one pass in sequence order (a compiled kernel; CorruptError if a parent is not
    earlier)."""
    inc = np.asarray(increments, dtype=np.int64)
    # rows of all channels (explicitly: -1 cannot be inferred when there are no rows)
    rows = inc.reshape(inc.shape[0], int(np.prod(inc.shape[1:], dtype=np.int64)))
    sums = _fields.tree_sums(np.ascontiguousarray(rows),
                             np.ascontiguousarray(parent, dtype=np.int64))
    if sums is None:
        raise CorruptError("a sample's parent does not come before it")
    return sums.reshape(inc.shape)


@dataclass(frozen=True, eq=False)
class Layout:
    """How a band mesh is stored: its vertices' stored order (`order`, and `inverse`
    from old to stored numbering), their pixel keys in that order, the polylines
    renumbered (`lines`; `flat` one after another, of `lengths`) and their steps as
    vertex pairs (`walls`), the canonical triangles and their doubled areas, and the
    sample sequence (`seq`, the `free` vertices and their Hilbert keys, each sample's
    `parents` place). It depends on the mesh's vertices, triangles and polylines, not
    on its values: quantise and encode_band share one."""

    order: np.ndarray
    inverse: np.ndarray
    sorted_keys: np.ndarray
    vertices: np.ndarray
    lines: list
    flat: np.ndarray
    lengths: np.ndarray
    walls: np.ndarray
    triangles: np.ndarray
    areas: np.ndarray
    seq: np.ndarray
    free: np.ndarray
    curve_keys: np.ndarray
    parents: np.ndarray
    #: steps() made so far, by (step, top_pinned): quantise and encode_band ask alike
    _steps: dict = field(default_factory=dict, init=False, repr=False)

    def steps(self, step: int, top_pinned: bool) -> np.ndarray:
        """Every stored vertex's quantisation step (vertex_steps; read-only, made once
        per (step, top_pinned) for this layout)."""
        key = (int(step), bool(top_pinned))
        if key not in self._steps:
            steps = vertex_steps(self.vertices, self.triangles, step, top_pinned, self.areas)
            steps.flags.writeable = False
            self._steps[key] = steps
        return self._steps[key]


def layout(mesh: Mesh) -> Layout:
    """The Layout of a band mesh."""
    order, inverse, sorted_keys, lines = _stored_order(mesh)
    vertices = mesh.vertices[order]
    flat = _flat(lines)
    lengths = np.array([len(c) for c in lines], dtype=np.int64)
    # canonical_triangles(inverse[mesh.triangles]) by a counting sort (a comparison
    # sort of 1.2M triangles took 0.16 s)
    triangles = _renumber.canonical_renumbered(np.ascontiguousarray(mesh.triangles, dtype=np.int64), inverse)
    seq, free, curve_keys = _sample_order(vertices, flat, hilbert_levels(mesh.width, mesh.height))
    return Layout(
        order, inverse, sorted_keys, vertices, lines, flat, lengths, chain_steps(flat, lengths), triangles,
        doubled_areas(vertices, triangles), seq, free, curve_keys, sample_parents(triangles, seq),
    )


def quantise(mesh: Mesh, step: int, top_pinned: bool, lay: Layout | None = None) -> Mesh:
    """A copy of the mesh with its samples as the decoder will rebuild them from residuals with
    base step `step` (closed-loop: each sample is coded against its parent as
    rebuilt, so rounding errors do not add up). Call with the final triangles; pass
    the same step and top_pinned to the writer. lay: the mesh's layout(), if made."""
    if step == 1:
        return mesh
    lay = layout(mesh) if lay is None else lay
    order, inverse, seq = lay.order, lay.inverse, lay.seq
    steps = np.ascontiguousarray(lay.steps(step, top_pinned)[seq], dtype=np.int64)
    top = int(np.iinfo(mesh.dtype).max)
    values = mesh.values[order].reshape(len(order), -1)[seq].astype(np.int64)
    # sequential by nature (each residual is taken against the parent's sample as
    # rebuilt): a compiled loop; the decoder's side is a sum along the tree
    out = _samples.quantised(values, steps, np.ascontiguousarray(lay.parents, dtype=np.int64), top)
    values = np.empty_like(out)
    values[seq] = out
    values = values[inverse].reshape(mesh.values.shape).astype(mesh.dtype)
    return Mesh(mesh.vertices, values, mesh.triangles, mesh.width, mesh.height, mesh.constraints, mesh.holes)


def encode_band(y0: int, mesh: Mesh, step: int = 1, delaunay: bool | None = None,
                lay: Layout | None = None, rebuild: bool = True) -> dict:
    """The MeshPayload fields for a validated band mesh whose samples are as
    quantise(mesh, step, y0 > 0) left them (any samples with step 1). delaunay: True
    when the caller knows the triangles are the ones a decoder rebuilds (a mesh from
    in_stored_order, or a mesher's Meshed.delaunay); otherwise it triangulates to
    find out. lay: the mesh's layout(), if made (quantise's). rebuild=False lists the
    triangles even where a decoder could rebuild them (codec.limits)."""
    n = len(mesh.vertices)
    lay = layout(mesh) if lay is None else lay
    order, sorted_keys, vertices, lines = lay.order, lay.sorted_keys, lay.vertices, lay.lines
    values = mesh.values[order].reshape(n, -1)
    triangles, flat, lengths, walls = lay.triangles, lay.flat, lay.lengths, lay.walls

    if not rebuild:
        delaunay = False
    elif not delaunay:
        try:
            rebuilt = canonical_triangles(triangulate(vertices, walls))
            delaunay = rebuilt.shape == triangles.shape and bool((rebuilt == triangles).all())
        except ATMError:
            delaunay = False
    steps = vertices[walls[:, 1]] - vertices[walls[:, 0]]
    start_keys = sorted_keys[flat[np.cumsum(lengths) - lengths]]

    seq_order, free, curve_keys, parents = lay.seq, lay.free, lay.curve_keys, lay.parents
    seq_steps = lay.steps(step, y0 > 0)[seq_order][:, None]
    in_order = values[seq_order].astype(np.int64)
    diffs = in_order - np.where(parents[:, None] >= 0, in_order[parents], 0)
    residuals = diffs // seq_steps
    if (residuals * seq_steps != diffs).any():
        raise ValueError(f"the samples were not quantised with step {step} (meshcode.quantise)")
    # the free vertices' positions in raster order or along the Hilbert curve, whichever
    # is smaller: clustered vertices (a range image's walls and corners) are closer
    # along the curve, evenly spread ones along the rows
    raster = position_fields(np.diff(sorted_keys[free], prepend=-1) - 1)
    curve = position_fields(np.diff(curve_keys, prepend=-1) - 1)
    sizes = [frames.trial_size(f["positions"]) + len(f["position_bits"]) for f in (raster, curve)]
    position_order = schema.POSITIONS_RASTER if sizes[0] <= sizes[1] else schema.POSITIONS_HILBERT
    tri_fields = np.zeros(0, np.int64)
    if not delaunay and len(triangles):
        a = triangles[:, 0]
        tri_fields = np.stack(
            [np.diff(a, prepend=0), triangles[:, 1] - a - 1, triangles[:, 2] - a - 1], 1
        ).ravel()
    return dict(
        y0=y0,
        rows=mesh.height,
        vertex_count=n,
        triangle_count=len(triangles),
        polyline_count=len(lines),
        polyline_index_count=len(flat),
        connectivity=schema.DELAUNAY if delaunay else schema.LISTED,
        position_order=position_order,
        triangle_crc=triangle_crc(triangles),
        sample_step=step,
        polyline_lengths=varints(lengths),
        polyline_starts=varints(zigzag(np.diff(start_keys, prepend=0))),
        polyline_steps=varints(zigzag(turned_steps(steps, lengths)).ravel()),
        **(raster if position_order == schema.POSITIONS_RASTER else curve),
        samples=varints(zigzag(residuals).ravel()),
        triangles=varints(tri_fields),
    )


_EMPTY = np.zeros(0, np.int64)
_EMPTY.flags.writeable = False
#: _polylines of a band without polylines (read-only: shared by every such band)
_NO_LINES = (_EMPTY, _EMPTY, _EMPTY, _EMPTY)


def _polylines(m, width: int, rows: int, where: str) -> tuple[np.ndarray, ...]:
    """(lengths, the distinct keys sorted, each point's rank among them, the ranks in
    the order the chains first reach them: _fields.line_ranks) of a parsed
    MeshPayload's polylines, checked to lie in the band: the
    steps turned back (unturned_steps) and walked from each start in one compiled
    pass, its checks in the order of the fields."""
    count, total = int(m.polyline_count), int(m.polyline_index_count)
    if not (count or total or m.polyline_lengths or m.polyline_starts or m.polyline_steps):
        # no polylines (most small bands): none of the arrays below has an element
        return _NO_LINES
    lengths = unvarints(m.polyline_lengths, count, f"{where} polyline lengths")
    if count > total:  # each polyline has two points or more
        raise CorruptError(f"{where}: polyline lengths do not add up")
    # the other fields' varints are refused in the order the fields come, after the
    # kernel's checks of the fields before them
    ok_starts, starts = _fields.unvarints(np.frombuffer(m.polyline_starts, np.uint8), count, MAX_VARINT_BYTES)
    ok_steps, steps = _fields.unvarints(np.frombuffer(m.polyline_steps, np.uint8), 2 * (total - count), MAX_VARINT_BYTES)
    status, chain_keys = _fields.chains(lengths, starts, steps, total, width, rows)
    if status == _fields.Chains.CHAINS_LENGTHS:
        raise CorruptError(f"{where}: polyline lengths do not add up")
    if ok_starts != _fields.Varints.VARINTS_OK:
        unvarints(m.polyline_starts, count, f"{where} polyline starts")  # raises its error
    if status == _fields.Chains.CHAINS_START:
        raise CorruptError(f"{where}: a polyline starts outside the {width}x{rows} band")
    if ok_steps != _fields.Varints.VARINTS_OK:
        unvarints(m.polyline_steps, 2 * (total - count), f"{where} polyline steps")  # raises its error
    if status == _fields.Chains.CHAINS_EMPTY:
        raise CorruptError(f"{where}: a polyline step is empty")
    if status == _fields.Chains.CHAINS_LONG:
        raise CorruptError(f"{where}: a polyline step is longer than the band")
    if status == _fields.Chains.CHAINS_LEAVES:
        raise CorruptError(f"{where}: a polyline leaves the {width}x{rows} band")
    # the distinct pixels, each point's rank among them and their first-reached order
    # (keys below width * rows, the chains checked: sorted in linear passes)
    line_keys, ranks, appear = _fields.line_ranks(chain_keys, _fields.argsort_keys(chain_keys, width * rows))
    return lengths, line_keys, ranks, appear


def _front(m, n: int, width: int, rows: int, levels: int, where: str) -> tuple[np.ndarray, ...]:
    """(vertices, flat, lengths, walls, sample order): what _fields.band_front makes
    of a parsed MeshPayload, by its separate passes, each refusing what is wrong with
    its own message, in the order of the fields (decode_band's way when band_front
    refuses the fields)."""
    pixels = width * rows
    # polylines first: their points are vertices the positions do not repeat
    lengths, line_keys, ranks, appear = _polylines(m, width, rows, where)
    free = n - len(line_keys)
    if free < 0:
        raise CorruptError(f"{where}: the polylines have more vertices than the {n} stored")
    if m.position_order not in (schema.POSITIONS_RASTER, schema.POSITIONS_HILBERT):
        raise CorruptError(f"{where}: unknown position order {m.position_order}")
    by_rows = m.position_order == schema.POSITIONS_RASTER
    span = pixels if by_rows else 1 << 2 * levels  # the keys' range
    free_keys = _free_keys(m, free, span, width, rows, where)
    if not by_rows:
        x, y = hilbert_points(free_keys, levels)
        if free and (x.max() >= width or y.max() >= rows):
            raise CorruptError(f"{where}: a vertex lies outside the {width}x{rows} band")
        free_keys = y * width + x
        by_curve = _fields.argsort_keys(free_keys, pixels)  # distinct keys below pixels: linear passes
        free_keys = free_keys[by_curve]
    # Both key lists are increasing: merged in one compiled pass, which also finds
    # each polyline point's vertex (flat) and the walls as vertex pairs
    ok, vertices, free_index, flat, walls, on_line = _fields.band_vertices(
        line_keys, free_keys, ranks, appear, lengths, width)
    if not ok:
        raise CorruptError(f"{where}: a vertex is stored both on a polyline and by position")
    # the encoder's _sample_order, from the parts known here: the positions along the
    # curve are already in its order
    if by_rows:
        # their Hilbert keys and linear radix passes over them, in one compiled call
        curve = _fields.curve_order(vertices, free_index, *hilbert_tables(levels), 1 << 2 * levels)
        if curve is None:  # the merge gave places of vertices inside the band: no file reaches it
            raise CorruptError(f"{where}: a vertex lies outside the {width}x{rows} band")
    else:
        curve = np.empty(free, np.int64)
        curve[by_curve] = free_index
    return vertices, flat, lengths, walls, np.concatenate([on_line, curve]) if len(flat) else curve


@functools.cache
def _largest(dtype: np.dtype) -> int:
    """The largest sample of an unsigned storage type (np.iinfo costs more than a
    small band's samples)."""
    return int(np.iinfo(dtype).max)


def decode_band(m, width: int, dtype: np.dtype, channels: int, where: str,
                triangulator: Delaunay | None = None) -> tuple[Mesh, tuple]:
    """The Mesh of a parsed MeshPayload and the element checks of _fields.mesh_checks
    (for mesh.validate, which then needs no areas); CorruptError if any field
    is inconsistent. Structural checks of the result are left to mesh.validate. A
    Delaunay band is triangulated in `triangulator`'s buffers when one is given (its
    owner's, reused band after band)."""
    n, rows = int(m.vertex_count), int(m.rows)
    if n > limits.max_vertices(width, rows):
        raise LimitError(f"{where}: {n:,} vertices is too many for {width}x{rows} pixels")
    if m.triangle_count > limits.max_triangles(width, rows):
        raise LimitError(f"{where}: {m.triangle_count:,} triangles is too many for {width}x{rows} pixels")
    if m.polyline_index_count > 2 * limits.max_vertices(width, rows):
        raise LimitError(f"{where}: {m.polyline_index_count:,} polyline indices is too many")
    if m.connectivity not in (schema.LISTED, schema.DELAUNAY):
        raise CorruptError(f"{where}: unknown connectivity code {m.connectivity}")
    # the polylines, the free vertices' positions and the sample order in one compiled
    # call; should it refuse the fields, the separate passes read them again and say
    # what is wrong, in the order of the fields
    levels = hilbert_levels(width, rows)
    front = None
    if m.position_order in (schema.POSITIONS_RASTER, schema.POSITIONS_HILBERT):
        status, vertices, flat, lengths, walls, seq_order = front = _fields.band_front(
            m.polyline_lengths, m.polyline_starts, m.polyline_steps, int(m.polyline_count),
            int(m.polyline_index_count), m.positions, m.position_bits, n, width, rows,
            m.position_order == schema.POSITIONS_RASTER, MAX_VARINT_BYTES, MAX_POSITION_BITS,
            *hilbert_tables(levels), *hilbert_inverse_tables(), 1 << 2 * levels)
    if front is None or status != _fields.Front.FRONT_OK:
        vertices, flat, lengths, walls, seq_order = _front(m, n, width, rows, levels, where)
    lines = Polylines(flat, lengths)
    if not len(flat):
        walls = None

    if m.connectivity == schema.DELAUNAY:
        if m.triangles:
            raise CorruptError(f"{where}: triangles listed for a Delaunay band")
        # the triangulation adds no vertex, and strict refuses a step over a vertex, so
        # every step is an edge (mesh.validate need not search the edges)
        try:
            # in canonical order, with their CRC from the kernel's pass that wrote them
            run = delaunay_and_crc if triangulator is None else triangulator.triangles_and_crc
            triangles, crc = run(vertices, walls, strict=True)
        except ATMError as exc:
            raise CorruptError(f"{where}: {exc}") from None
    else:
        t = unvarints(m.triangles, 3 * m.triangle_count, f"{where} triangles").reshape(-1, 3)
        a = np.cumsum(t[:, 0])
        triangles = np.stack([a, a + t[:, 1] + 1, a + t[:, 2] + 1], 1)
        crc = triangle_crc(triangles)
    if len(triangles) != m.triangle_count or crc != m.triangle_crc:
        raise CorruptError(
            # ATM.md 4.2.5 defines the Delaunay triangles uniquely: the CRC only checks
            f"{where}: the triangles differ from the encoder's (CRC mismatch): the file is damaged"
        )
    # samples last: their steps depend on the triangles' fan areas
    if m.sample_step < 1:
        raise CorruptError(f"{where}: sample step 0")
    top = _largest(dtype)
    # the samples' varints, steps, parents and running sums in one compiled pass
    # (unvarints, vertex_steps, sample_parents and tree_sums' arithmetic), every index
    # checked there; with mesh.validate's element checks from its pass over the triangles
    status, values, _, checks = _fields.band_values(
        vertices, np.ascontiguousarray(triangles, dtype=np.int64), np.frombuffer(m.samples, np.uint8), channels,
        seq_order, int(m.sample_step), STEP_RANGE, m.y0 > 0, top, MAX_VARINT_BYTES, width, rows, False,
    )
    if status == _fields.Values.VALUES_COUNT or status == _fields.Values.VALUES_LONG:
        unvarints(m.samples, n * channels, f"{where} samples")  # raises its error
    if status == _fields.Values.VALUES_CORNER:
        raise CorruptError(f"{where}: a triangle refers to a vertex beyond the {n} stored")
    if status == _fields.Values.VALUES_RESIDUAL:
        raise CorruptError(f"{where}: a sample residual exceeds the {dtype} range")
    if status == _fields.Values.VALUES_ORDER:
        raise CorruptError(f"{where}: the sample order is no permutation of the vertices")
    if status == _fields.Values.VALUES_SAMPLE:
        raise CorruptError(f"{where}: a sample leaves the {dtype} range")
    if values.dtype != dtype:  # storage is uint8 or uint16: the kernel's own types
        values = values.astype(dtype)

    return Mesh(vertices, values, triangles, width, rows, lines), checks
