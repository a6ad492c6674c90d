"""CPU decoder: rasterise the mesh with exact integer plane interpolation.

Every vertex and pixel centre is an integer point, so each pixel's barycentric weights
are exact integers and the rounded value is the same whichever triangle covers the
pixel (see format_spec/ATM.md, "Decoding"). Work is vectorised over triangles and
pixels in batches whose size bounds memory.
"""

from __future__ import annotations

import numpy as np

from .errors import CorruptError
from .mesh import Mesh

#: Bounding-box pixels handled per batch; bounds the decoder's temporary memory.
BATCH_PIXELS = 1 << 19


def _round_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Exact round-half-up of num / den for den > 0."""
    return (2 * num + den) // (2 * den)


def _finish(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(values, info.min, info.max).astype(dtype)


def render_line(mesh: Mesh) -> np.ndarray:
    """Decode a mesh of an image one pixel high or wide (no triangles)."""
    w, h = mesh.width, mesh.height
    along = mesh.vertices[:, 0] if h == 1 else mesh.vertices[:, 1]
    order = np.argsort(along, kind="stable")
    s = along[order].astype(np.int64)
    vals = mesh.values[order].astype(np.int64).reshape(len(s), -1)
    n = max(w, h)
    p = np.arange(n, dtype=np.int64)
    if len(s) == 1:
        out = np.repeat(vals, n, axis=0)
    else:
        k = np.clip(np.searchsorted(s, p, side="right") - 1, 0, len(s) - 2)
        a, b = s[k], s[k + 1]
        num = vals[k] * (b - p)[:, None] + vals[k + 1] * (p - a)[:, None]
        out = _round_div(num, (b - a)[:, None])
    shape = (h, w) if mesh.channels == 1 else (h, w, mesh.channels)
    return _finish(out, mesh.dtype).reshape(shape)


def render(mesh: Mesh) -> np.ndarray:
    """Decode a validated mesh to an image of its dtype and channel count."""
    if len(mesh.triangles) == 0:
        return render_line(mesh)
    w, h, c = mesh.width, mesh.height, mesh.channels
    v = mesh.vertices.astype(np.int64)
    t = mesh.triangles
    vals = mesh.values.astype(np.int64).reshape(len(v), c)
    px_, py_ = v[t, 0], v[t, 1]  # M x 3 corner coordinates
    x0 = px_.min(axis=1)
    y0 = py_.min(axis=1)
    bw = px_.max(axis=1) - x0 + 1
    bh = py_.max(axis=1) - y0 + 1
    counts = bw * bh
    out = np.zeros((h * w, c), dtype=np.int64)
    covered = np.zeros(h * w, dtype=bool)
    ends = np.cumsum(counts)
    starts = ends - counts
    # batch boundaries: consecutive triangles whose boxes add up to about BATCH_PIXELS
    cuts = np.searchsorted(ends, np.arange(BATCH_PIXELS, ends[-1], BATCH_PIXELS), side="left")
    bounds = np.unique(np.concatenate([[0], cuts + 1, [len(t)]]).clip(0, len(t)))
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        idx = np.arange(lo, hi)
        n = counts[idx]
        tri = np.repeat(idx, n)
        off = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(starts[idx] - starts[lo], n)
        bwt = bw[tri]
        x = x0[tri] + off % bwt
        y = y0[tri] + off // bwt
        cx, cy = px_[tri], py_[tri]
        # w_i = cross(p_{i+2} - p_{i+1}, p - p_{i+1}): the weight of corner i, times area
        wts = []
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            wts.append((cx[:, k] - cx[:, j]) * (y - cy[:, j]) - (cy[:, k] - cy[:, j]) * (x - cx[:, j]))
        inside = (wts[0] >= 0) & (wts[1] >= 0) & (wts[2] >= 0)
        tri_in = tri[inside]
        den = (wts[0] + wts[1] + wts[2])[inside][:, None]
        num = sum(wts[i][inside][:, None] * vals[t[tri_in, i]] for i in range(3))
        pix = y[inside] * w + x[inside]
        out[pix] = _round_div(num, den)
        covered[pix] = True
    if not covered.all():
        missing = int(np.flatnonzero(~covered)[0])
        raise CorruptError(
            f"the mesh leaves pixel (row {missing // w}, column {missing % w}) uncovered"
        )
    shape = (h, w) if c == 1 else (h, w, c)
    return _finish(out, mesh.dtype).reshape(shape)
