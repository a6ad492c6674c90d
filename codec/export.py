"""The mesh of an .atm file in other people's formats: OBJ, PLY, SVG, and a PNG overlay.

Coordinates are the codec's own: x is the column and y the row of a pixel centre (so y
grows downwards, as in the image), and z is the vertex's sample value (for RGB, its
luma, with the colour stored alongside where the format has room for it).
Walls (the constraint polylines) are kept: OBJ `l` lines, PLY `edge` elements, a red
path in SVG and red lines in the overlay.
"""

from __future__ import annotations

import io
import math

import numpy as np

from .errors import ATMError
from .decoding import render
from .mesh import Mesh, edges

#: ITU-R BT.601 luma weights, used as z for RGB vertices.
LUMA = np.array([0.299, 0.587, 0.114])

#: Overlay colours (RGB): triangle edges and walls.
EDGE_COLOUR = (40, 200, 255)
WALL_COLOUR = (255, 40, 40)


def _z(mesh: Mesh) -> np.ndarray:
    values = mesh.values.astype(np.float64)
    return values if values.ndim == 1 else values @ LUMA


def unique_edges(mesh: Mesh) -> np.ndarray:
    """The triangulation's undirected edges, each once, as E x 2 vertex indices."""
    if len(mesh.triangles) == 0:
        # a one-pixel-wide image: its vertices lie on one line, in order along it
        order = np.lexsort((mesh.vertices[:, 0], mesh.vertices[:, 1]))
        return np.stack([order[:-1], order[1:]], axis=1)
    pairs = np.sort(edges(mesh.triangles), axis=1)
    return np.unique(pairs, axis=0)


def wall_segments(mesh: Mesh) -> np.ndarray:
    """The walls' segments as W x 2 vertex indices."""
    if not mesh.constraints:
        return np.zeros((0, 2), np.int64)
    return np.concatenate([np.stack([c[:-1], c[1:]], axis=1) for c in mesh.constraints]).astype(np.int64)


def to_obj(mesh: Mesh, z: np.ndarray | None = None) -> bytes:
    """Wavefront OBJ: one `v x y z` line per vertex (RGB meshes add `r g b` in 0..1, the
    common vertex-colour extension), `f` lines with 1-based indices, `l` lines for walls.
    z: the vertices' heights (default: their stored samples; codec.terrain gives them in
    data units)."""
    out = io.BytesIO()
    out.write(
        f"# .atm mesh {mesh.width}x{mesh.height}: x = column, y = row, z = sample value\n".encode()
    )
    v = mesh.vertices.astype(np.float64)
    columns = [v[:, 0], v[:, 1], _z(mesh) if z is None else z]
    fmt = "v %d %d %.9g"  # 9 digits: metres to the millimetre on any terrain
    if mesh.channels == 3:
        top = float(np.iinfo(mesh.dtype).max)
        columns += list((mesh.values.astype(np.float64) / top).T)
        fmt += " %.6g %.6g %.6g"
    np.savetxt(out, np.stack(columns, axis=1), fmt=fmt)
    if len(mesh.triangles):
        np.savetxt(out, mesh.triangles + 1, fmt="f %d %d %d")
    for line in mesh.constraints:
        out.write(("l " + " ".join(map(str, (line + 1).tolist())) + "\n").encode())
    return out.getvalue()


def to_ply(mesh: Mesh, z: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY: vertices (x, y, z as float32, plus red/green/blue for
    RGB), faces, and the walls' segments as `edge` elements. z as for to_obj."""
    v = np.empty(
        len(mesh.vertices),
        [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
        + ([("red", "u1"), ("green", "u1"), ("blue", "u1")] if mesh.channels == 3 else []),
    )
    v["x"], v["y"], v["z"] = mesh.vertices[:, 0], mesh.vertices[:, 1], _z(mesh) if z is None else z
    if mesh.channels == 3:
        # PLY colours are 8-bit; 16-bit samples keep their top byte
        shift = 8 * (mesh.dtype.itemsize - 1)
        for i, name in enumerate(("red", "green", "blue")):
            v[name] = mesh.values[:, i].astype(np.uint32) >> shift
    f = np.empty(len(mesh.triangles), [("n", "u1"), ("i", "<i4", (3,))])
    f["n"], f["i"] = 3, mesh.triangles
    walls = wall_segments(mesh).astype("<i4")
    colour = "property uchar red\nproperty uchar green\nproperty uchar blue\n" if mesh.channels == 3 else ""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment .atm mesh {mesh.width}x{mesh.height}: x = column, y = row, z = sample value\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n{colour}"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\n"
        f"element edge {len(walls)}\nproperty int vertex1\nproperty int vertex2\n"
        "end_header\n"
    )
    return header.encode() + v.tobytes() + f.tobytes() + walls.tobytes()


def _svg_path(points: np.ndarray, pairs: np.ndarray) -> str:
    """One SVG path of separate segments ("M x y L x y" each)."""
    if len(pairs) == 0:
        return ""
    # pixel centres sit at half-integers in a viewBox whose unit is the pixel
    p = points.astype(np.float64) + 0.5
    a, b = p[pairs[:, 0]], p[pairs[:, 1]]
    coords = np.concatenate([a, b], axis=1)
    return " ".join("M%g %gL%g %g" % tuple(row) for row in coords.tolist())


def to_svg(mesh: Mesh, *, stroke: float = 0.15) -> str:
    """An SVG of the triangulation over a width x height viewBox (one unit per pixel):
    the triangle edges in one blue path, the walls in a thicker red one."""
    w, h = mesh.width, mesh.height
    edge_path = _svg_path(mesh.vertices, unique_edges(mesh))
    wall_path = _svg_path(mesh.vertices, wall_segments(mesh))
    size = 800 / max(w, h)  # a comfortable default display size; the viewBox scales
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {w} {h}" '
        f'width="{w * size:.0f}" height="{h * size:.0f}">\n'
        f"<title>.atm mesh: {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles, "
        f"{len(mesh.constraints)} walls</title>\n"
        f'<rect width="{w}" height="{h}" fill="white"/>\n'
        f'<path id="edges" d="{edge_path}" fill="none" stroke="#1e6fd9" '
        f'stroke-width="{stroke}" stroke-linecap="round"/>\n'
        f'<path id="walls" d="{wall_path}" fill="none" stroke="#e0201c" '
        f'stroke-width="{3 * stroke}" stroke-linecap="round"/>\n'
        "</svg>\n"
    )


def display_rgb(image: np.ndarray, nodata: float | None = None) -> np.ndarray:
    """An image as 8-bit RGB for viewing: 16-bit, signed and float samples are stretched
    to the range of the pixels with data (depth and elevation rarely use all 16 bits, and
    a nodata value such as -9999 would wash the rest out), holes (NaN or `nodata`) are
    black, gray becomes three channels."""
    img = image.astype(np.float64)
    if image.dtype != np.uint8:
        finite = np.isfinite(img)
        if nodata is not None and not math.isnan(nodata):
            valid = img != nodata
            finite &= valid if valid.ndim == 2 else valid.all(axis=2, keepdims=True)
        lo, hi = (float(img[finite].min()), float(img[finite].max())) if finite.any() else (0.0, 0.0)
        img = np.where(finite, (img - lo) * (255.0 / (hi - lo)) if hi > lo else 0.0, 0.0)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return np.repeat(img[:, :, None], 3, axis=2) if img.ndim == 2 else img


def auto_scale(width: int, height: int, target: int = 1024) -> int:
    """An enlargement that makes a small image about `target` pixels on its long side,
    so that the mesh's lines do not hide the pixels (at most 8, at least 1)."""
    return int(min(8, max(1, target // max(width, height))))


def overlay_png(
    mesh: Mesh, image: np.ndarray | None = None, *, scale: int = 1, antialias: bool = False,
    nodata: float | None = None,
) -> np.ndarray:
    """The decoded image (rendered from `mesh` unless given) as 8-bit RGB, enlarged
    `scale` times, with the triangle edges and the walls drawn over it.

    antialias: smoother lines, but a PNG of the result is about four times larger."""
    import cv2

    if image is None:
        image = render(mesh)
    rgb = display_rgb(image, nodata)
    if scale > 1:
        rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    rgb = np.ascontiguousarray(rgb)
    bits = 4  # cv2's fixed-point shift: lines land on pixel centres at any scale
    centres = np.rint((mesh.vertices.astype(np.float64) * scale + (scale - 1) / 2) * (1 << bits))
    centres = centres.astype(np.int32)
    lines = rgb.copy()
    line_type = cv2.LINE_AA if antialias else cv2.LINE_8
    for pairs, colour, thickness in (
        (unique_edges(mesh), EDGE_COLOUR, 1),
        (wall_segments(mesh), WALL_COLOUR, max(1, scale // 2 + 1)),
    ):
        if len(pairs):
            # all segments in one call: a list of 2-point arrays, no per-triangle loop
            segments = list(centres[pairs])
            cv2.polylines(lines, segments, False, colour, thickness, line_type, bits)
    # lines at 75 % opacity: the image stays readable under a dense mesh
    return cv2.addWeighted(lines, 0.75, rgb, 0.25, 0)


def png_bytes(rgb: np.ndarray) -> bytes:
    """An 8-bit RGB picture as PNG bytes, at zlib's strongest level: overlays are kept
    in documentation, and level 9 makes them about a quarter of OpenCV's default size."""
    import cv2

    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise ATMError("OpenCV could not encode the overlay as PNG")
    return buf.tobytes()
