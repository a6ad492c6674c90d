"""One band's mesh <-> the fields of its MESH payload (format_spec/ATM.md §4.2).

Vertices are stored in raster order as gaps between their pixel indices; samples as
differences along the Hilbert curve through the vertices; polylines as index
differences; triangles either listed (canonical order, differences) or not stored at
all and rebuilt by constrained Delaunay triangulation, with a CRC of the canonical
list either way so that a decoder can prove it has the encoder's triangles.
"""

from __future__ import annotations

import numpy as np

from format_spec import schema

from . import limits
from .coding import (
    canonical_triangles,
    hilbert_keys,
    triangle_crc,
    unvarints,
    unzigzag,
    varints,
    zigzag,
)
from .errors import ATMError, CorruptError, LimitError
from .mesh import Mesh, segments
from .triangulate import triangulate


def _segments(constraints: list[np.ndarray]) -> np.ndarray | None:
    return segments(constraints) if constraints else None


def _hilbert_order(vertices: np.ndarray) -> np.ndarray:
    return np.argsort(hilbert_keys(vertices[:, 0], vertices[:, 1]), kind="stable")


def _to_planes(residuals: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Residuals (mod 2^bits) as byte planes: all low bytes, then all high bytes."""
    r = residuals.astype(dtype.newbyteorder("<")).ravel()
    return r.view(np.uint8).reshape(-1, dtype.itemsize).T.ravel()


def _from_planes(planes: np.ndarray, dtype: np.dtype, count: int) -> np.ndarray:
    b = planes.reshape(dtype.itemsize, count).T.copy()
    return b.view(dtype.newbyteorder("<")).ravel().astype(dtype)


def encode_band(y0: int, mesh: Mesh) -> dict:
    """The MeshPayload fields for a validated band mesh."""
    w, n = mesh.width, len(mesh.vertices)
    keys = mesh.vertices[:, 1] * w + mesh.vertices[:, 0]
    order = np.argsort(keys, kind="stable")
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.arange(n)
    vertices = mesh.vertices[order]
    values = mesh.values[order].reshape(n, -1)
    triangles = canonical_triangles(inverse[mesh.triangles])
    lines = [inverse[c] for c in mesh.constraints]

    try:
        rebuilt = canonical_triangles(triangulate(vertices, _segments(lines)))
        delaunay = rebuilt.shape == triangles.shape and bool((rebuilt == triangles).all())
    except ATMError:
        delaunay = False

    sorted_keys = keys[order]
    gaps = np.diff(sorted_keys, prepend=-1) - 1
    h = _hilbert_order(vertices)
    # samples that are all multiples of a step are stored divided by it: an encoder
    # that rounds values to a coarser step pays fewer bits for them
    step = int(np.gcd.reduce(values.ravel().astype(np.int64))) if values.size else 1
    step = min(max(step, 1), 65535)
    while step > 1 and (values % step).any():  # only when the gcd exceeded 65535
        step -= 1
    seq = values[h].astype(np.int64) // step
    residuals = np.diff(seq, axis=0, prepend=np.zeros((1, seq.shape[1]), np.int64))
    residuals %= 1 << (8 * mesh.dtype.itemsize)
    flat = np.concatenate(lines) if lines else np.zeros(0, np.int64)
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
        triangle_crc=triangle_crc(triangles),
        sample_step=step,
        positions=varints(gaps),
        samples=_to_planes(residuals, mesh.dtype),
        polyline_lengths=varints(np.array([len(c) for c in lines], dtype=np.int64)),
        polyline_indices=varints(zigzag(np.diff(flat, prepend=0))),
        triangles=varints(tri_fields),
    )


def decode_band(m, width: int, dtype: np.dtype, channels: int, where: str) -> Mesh:
    """The Mesh of a parsed MeshPayload; CorruptError if any field is inconsistent.
    Structural checks of the result are left to mesh.validate."""
    n, rows = int(m.vertex_count), int(m.rows)
    if n > limits.max_vertices(width, rows):
        raise LimitError(f"{where}: {n:,} vertices is too many for {width}x{rows} pixels")
    if m.triangle_count > limits.max_triangles(width, rows):
        raise LimitError(f"{where}: {m.triangle_count:,} triangles is too many for {width}x{rows} pixels")
    if m.polyline_index_count > 2 * limits.max_vertices(width, rows):
        raise LimitError(f"{where}: {m.polyline_index_count:,} polyline indices is too many")
    if m.connectivity not in (schema.LISTED, schema.DELAUNAY):
        raise CorruptError(f"{where}: unknown connectivity code {m.connectivity}")

    keys = np.cumsum(unvarints(m.positions, n, f"{where} positions") + 1) - 1
    if n and keys[-1] >= width * rows:
        raise CorruptError(f"{where}: a vertex lies outside the {width}x{rows} band")
    vertices = np.stack([keys % width, keys // width], 1)

    if m.sample_step < 1:
        raise CorruptError(f"{where}: sample step 0")
    residuals = _from_planes(m.samples, dtype, n * channels).astype(np.int64).reshape(n, channels)
    seq = np.cumsum(residuals, axis=0) % (1 << (8 * dtype.itemsize))
    seq *= m.sample_step
    if n and seq.max() > np.iinfo(dtype).max:
        raise CorruptError(f"{where}: a sample times the step {m.sample_step} exceeds {dtype}")
    values = np.empty((n, channels), dtype=dtype)
    values[_hilbert_order(vertices)] = seq
    values = values[:, 0] if channels == 1 else values

    lengths = unvarints(m.polyline_lengths, m.polyline_count, f"{where} polyline lengths")
    if lengths.sum() != m.polyline_index_count or (len(lengths) and lengths.min() < 2):
        raise CorruptError(f"{where}: polyline lengths do not add up")
    flat = np.cumsum(unzigzag(unvarints(m.polyline_indices, m.polyline_index_count, f"{where} polylines")))
    if len(flat) and (flat.min() < 0 or flat.max() >= n):
        raise CorruptError(f"{where}: a constraint polyline refers to a missing vertex")
    lines = np.split(flat, np.cumsum(lengths)[:-1]) if len(lengths) else []

    if m.connectivity == schema.DELAUNAY:
        if m.triangles:
            raise CorruptError(f"{where}: triangles listed for a Delaunay band")
        segments = _segments(lines)
        if segments is not None and (segments[:, 0] == segments[:, 1]).any():
            raise CorruptError(f"{where}: a constraint segment joins a vertex to itself")
        try:
            triangles = canonical_triangles(triangulate(vertices, segments))
        except ATMError as exc:
            raise CorruptError(f"{where}: {exc}") from None
    else:
        t = unvarints(m.triangles, 3 * m.triangle_count, f"{where} triangles").reshape(-1, 3)
        a = np.cumsum(t[:, 0])
        triangles = np.stack([a, a + t[:, 1] + 1, a + t[:, 2] + 1], 1)
    if len(triangles) != m.triangle_count or triangle_crc(triangles) != m.triangle_crc:
        raise CorruptError(
            f"{where}: the triangles differ from the encoder's (CRC mismatch); "
            + (
                "this machine's Delaunay triangulation differs from the encoder's"
                if m.connectivity == schema.DELAUNAY
                else "the file is damaged"
            )
        )
    return Mesh(vertices, values, triangles, width, rows, lines)
