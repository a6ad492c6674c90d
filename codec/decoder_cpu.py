"""CPU decoder: exact integer scanline rasterisation of the mesh.

Decoding rule (normative, see format_spec/ATM.md "Decoding"). Vertex (x, y) is the
centre of pixel (row y, column x). A pixel p inside triangle (p0, p1, p2) with doubled
area D > 0 has the integer edge-function weights

    w_i = (x_k - x_j)(y - y_j) - (y_k - y_j)(x - x_j),   j = i+1, k = i+2 (mod 3),

with w_0 + w_1 + w_2 = D, and for each channel its value is

    floor((2 * sum_i w_i v_i + D) / (2 D))       (round half up of sum w_i v_i / D),

clipped to the dtype. Because every vertex and pixel centre is an integer point this is
exact, and a pixel on an edge shared by two triangles gets the same value from either.

Ownership rule (which triangle writes a pixel): the top-left rule, with the image's
right and bottom borders included. Pixel p belongs to the one triangle that contains
the point p + (sx*e, sy*e*e) for an infinitesimal e > 0, where sx = +1 except in the
last column (sx = -1) and sy = +1 except in the last row (sy = -1). In scanline terms,
with [xl, xr] the triangle's exact cross-section on row y:

* row y is the triangle's if ymin <= y < ymax, or if y = ymax = H - 1;
* column x of such a row is the triangle's if xl <= x < xr, or if xl < x = xr = W - 1.

For a mesh that tiles the image (what mesh.validate checks) every pixel is thus written
exactly once. The decoder still checks that every pixel is written exactly once,
for meshes handed to it unvalidated, and raises CorruptError otherwise (a pixel
uncovered, or covered twice); for a mesh the caller knows to tile the image (render's
`tiles`: a file's bands, which the Reader validated) it only counts the pixels written.

The rasteriser is a compiled kernel (codec/_rasterise.pyx, built by the package's
own build), exact integer arithmetic throughout, that releases the GIL: threads
decoding different files run in parallel. Each call owns its buffers (the image and
the counters of its coverage check); nothing is shared between calls. The kernel
checks every index it reads (vertices inside the image, triangle corners among the
vertices), so a mesh that skipped validation cannot make it write out of bounds.
"""

from __future__ import annotations

import numpy as np

from .errors import CorruptError, OptionError, UnsupportedError
from .mesh import Mesh
from .native import _rasterise

_TOTAL, _SPANS = _rasterise.Check.CHECK_TOTAL, _rasterise.Check.CHECK_SPANS

#: The sample types the kernel writes (ATM.md §3: the stored sample types).
_SAMPLES = (np.dtype(np.uint8), np.dtype(np.uint16))

#: The corner index types the kernel reads.
_INDICES = (np.dtype(np.int32), np.dtype(np.int64))


def _round_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Exact round-half-up of num / den for den > 0 (integer arrays)."""
    return (2 * num + den) // (2 * den)


def _finish(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(values, info.min, info.max).astype(dtype)


def image_shape(mesh: Mesh) -> tuple[int, ...]:
    """The decoded image's shape: (H, W), or (H, W, C) for C > 1 channels."""
    return (mesh.height, mesh.width) if mesh.channels == 1 else (mesh.height, mesh.width, mesh.channels)


def check_out(out: np.ndarray, mesh: Mesh) -> None:
    """Refuse, by what is wrong with it, an array that a render cannot write into in
    place: the image's shape and sample type, C-contiguous, writeable."""
    shape, dtype = image_shape(mesh), np.dtype(mesh.dtype)
    if not isinstance(out, np.ndarray):
        raise OptionError(f"out must be a numpy array, not {type(out).__name__}")
    if out.shape != shape or out.dtype != dtype:
        raise OptionError(f"out is a {out.shape} {out.dtype} array; this mesh renders to shape {shape}, "
                          f"dtype {dtype} (e.g. numpy.empty({shape}, numpy.{dtype}))")
    if not out.flags.c_contiguous:
        raise OptionError("out must be C-contiguous (numpy.ascontiguousarray, or a new numpy.empty)")
    if not out.flags.writeable:
        raise OptionError("out is read-only; pass a writeable array")


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


def render(mesh: Mesh, *, tiles: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """Decode a mesh to an image of its dtype and channel count. tiles=True: the caller
    knows the triangles tile the image (mesh.validate passed: a decoder's band meshes,
    and bands stacked by stream.stack_bands), so the kernel checks only the count of
    the pixels it writes, not each row's spans (ATM.md §4.2.3; codec/_rasterise.pyx).
    out: an array to render into and return (check_out's), instead of a new one: a
    caller that decodes many images can keep one, and the kernel writes straight into
    it (no image to allocate, fault in and copy). No other thread may use `out` during
    the call (the kernel merges short spans into it word by word), and its content is
    undefined after a CorruptError."""
    if out is not None:
        check_out(out, mesh)
    if len(mesh.triangles) == 0:
        if out is None:
            return render_line(mesh)
        out[...] = render_line(mesh)
        return out
    w, h, c = mesh.width, mesh.height, mesh.channels
    if w * h > 1 << 32:
        # keeps every numerator of the kernel's exact arithmetic below 2**53
        raise UnsupportedError(f"a {w}x{h} image is too large for the CPU decoder")
    if mesh.dtype not in _SAMPLES or c > 4:
        raise UnsupportedError(
            f"the CPU decoder renders uint8 or uint16 samples in 1 to 4 channels, not "
            f"{c} channel(s) of {mesh.dtype}"
        )
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.int64)
    values = np.ascontiguousarray(mesh.values).reshape(len(vertices), c)
    # the kernel reads int32 corners as they are (half the memory of int64)
    index = mesh.triangles.dtype if mesh.triangles.dtype in _INDICES else np.dtype(np.int64)
    triangles = np.ascontiguousarray(mesh.triangles, dtype=index)
    # zeroed (by the kernel, without the GIL), not left as allocated: with tiles=True
    # only the count of written pixels is checked, so should a broken mesh ever pass
    # validation, no stale memory reaches the caller (the image's own shape, so that
    # the result owns its memory: a decode may return it)
    image = np.empty(image_shape(mesh), dtype=mesh.dtype) if out is None else out
    check = _TOTAL if tiles else _SPANS
    status, detail = _rasterise.rasterise(vertices, values, triangles, image.reshape(h * w, c), w, h, check,
                                          zero=out is None)
    if status:
        _refuse(status, detail, w, h, len(vertices))
    # no clipping needed: in a triangle every value is a convex combination of values of
    # the dtype, and round-half-up of such a mean stays within the dtype
    return image


def _refuse(status: int, detail: int, w: int, h: int, n: int) -> None:
    """Raise the CorruptError of the kernel's status."""
    if status == _rasterise.Status.BAD_VERTEX:
        raise CorruptError(f"vertex {detail} lies outside the {w}x{h} image")
    if status == _rasterise.Status.BAD_INDEX:
        raise CorruptError(f"triangle {detail} refers to a vertex beyond the {n} stored")
    if status == _rasterise.Status.UNCOVERED:
        _fail(detail, w, "leaves it uncovered")
    if status == _rasterise.Status.TWICE:
        _fail(detail, w, "covers it twice")


def _fail(pixel: int, width: int, what: str) -> None:
    raise CorruptError(f"the mesh {what}: pixel (row {pixel // width}, column {pixel % width})")
