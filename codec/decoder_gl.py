"""OpenGL z-buffer decoder (the seed's §3.4.2): rasterise the mesh with moderngl.

A headless context (EGL; Mesa's llvmpipe renders on machines without a GPU) is created
on first use and kept; importing this module touches no GL.

Geometry. Mesh point (x, y) maps to window point (x - x0 + 1/2, y - y0 + 1/2) of a tile
whose first pixel is (x0, y0), so OpenGL's pixel centres fall on the integer points of
the mesh: pixel (row y, column x) samples the mesh at (x, y), as in the CPU decoder. The
viewport is a power of two wide and high (the framebuffer is only the tile's size), so
every coordinate and transform step is exact in float32 and vertices land exactly on the
rasteriser's sub-pixel grid. Window row 0 is image row y0, which is also the first row
glReadPixels returns, so no flip is needed. Images larger than a tile (MAX_TILE, within
the context's maximum viewport and renderbuffer size) are rendered tile by tile.

Border. The outermost pixel centres lie exactly on the mesh's outer boundary, where the
fill rule would drop those of two sides. A one-pixel skirt closes that gap: each
boundary edge is extruded outwards into a quad whose values are constant across it
(equal to the edge's linear interpolation along it) and each image corner gets a square
of the corner's value. The boundary edges are then shared, watertight edges, so every
border pixel is drawn exactly once, and on the boundary line the skirt's value is the
mesh's own.

Values (exact mode, the default; needs OpenGL 4.0 for double precision). A geometry
shader hands each fragment its triangle's three integer corners and values; the fragment
shader evaluates the CPU decoder's normative rule, floor((2 sum w_i v_i + D) / 2D), with
the integer edge weights w_i in int32 (|w_i| <= 2 W H < 2**31) and the sums in double
(< 2**53, exact), corrects the quotient by its exact remainder, and writes the integer
into an R32F (gray) or RGBA32F (colour) target, which holds every 16-bit value exactly.
On a shared edge both triangles give the same value, so GL and CPU images are identical.

Values (float mode, exact=False, and the fallback on contexts without doubles): vertex
values as float32 interpolated by the rasteriser, rounded half up on read-back. float32
interpolation is off by up to ~2e-3 for 8-bit and ~0.7 for 16-bit data here, so values
whose exact fraction is one half may round either way: within 1 of the CPU decoder.

A second R32I target records gl_PrimitiveID + 1 (0 where nothing drew): a pixel left at
0 is a CorruptError, as in the CPU decoder.
"""

from __future__ import annotations

import threading

import numpy as np

from .errors import BackendError, CorruptError, UnsupportedError
from .mesh import Mesh, orient

#: Largest tile side rendered at once; bounds the read-back memory (16 bytes a pixel).
MAX_TILE = 2048
#: The exact shader's int32 edge weights stay below 2**31 up to this many pixels.
MAX_EXACT_PIXELS = 1 << 30

INSTALL_HINT = (
    "install Mesa's EGL and software renderer (Debian/Ubuntu: apt-get install libegl1 "
    "libegl-mesa0 libgl1-mesa-dri) or decode with backend='cpu'"
)

_FLOAT_VS = """
#version 330
uniform vec2 origin;   // the tile's first pixel, minus one half
uniform vec2 scale;    // 2 / viewport size (a power of two: exact)
in ivec2 pos;
in vec3 val;
out vec3 v_val;
void main() {
    gl_Position = vec4((vec2(pos) - origin) * scale - 1.0, 0.0, 1.0);
    v_val = val;
}
"""

_FLOAT_FS = """
#version 330
in vec3 v_val;
layout(location = 0) out vec4 value;
layout(location = 1) out int prim;
void main() {
    value = vec4(v_val, 1.0);
    prim = gl_PrimitiveID + 1;
}
"""

_EXACT_VS = """
#version 400
uniform vec2 origin;
uniform vec2 scale;
in ivec2 pos;
in vec3 val;
flat out ivec2 g_pos;
flat out vec3 g_val;
void main() {
    gl_Position = vec4((vec2(pos) - origin) * scale - 1.0, 0.0, 1.0);
    g_pos = pos;
    g_val = val;
}
"""

# passes the whole triangle (corners and values) to every fragment, unchanged
_EXACT_GS = """
#version 400
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
flat in ivec2 g_pos[];
flat in vec3 g_val[];
flat out ivec2 p0, p1, p2;
flat out vec3 v0, v1, v2;
void main() {
    for (int i = 0; i < 3; i++) {
        gl_Position = gl_in[i].gl_Position;
        gl_PrimitiveID = gl_PrimitiveIDIn;
        p0 = g_pos[0]; p1 = g_pos[1]; p2 = g_pos[2];
        v0 = g_val[0]; v1 = g_val[1]; v2 = g_val[2];
        EmitVertex();
    }
    EndPrimitive();
}
"""

_EXACT_FS = """
#version 400
uniform ivec2 first;   // the tile's first pixel
flat in ivec2 p0, p1, p2;
flat in vec3 v0, v1, v2;
layout(location = 0) out vec4 value;
layout(location = 1) out int prim;
int weight(ivec2 a, ivec2 b, ivec2 p) {
    return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
}
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) + first;   // centres are at i + 1/2: exact
    int w0 = weight(p1, p2, p);
    int w1 = weight(p2, p0, p);
    int w2 = weight(p0, p1, p);
    int d = w0 + w1 + w2;
    if (d < 0) { w0 = -w0; w1 = -w1; w2 = -w2; d = -d; }
    dvec3 t = 2.0LF * (double(w0) * dvec3(v0) + double(w1) * dvec3(v1) + double(w2) * dvec3(v2))
              + double(d);
    double den = 2.0LF * double(d);
    dvec3 q = floor(t / den);
    // t, den and q * den are exact integers: fix any rounding of the division
    dvec3 r = t - q * den;
    q += dvec3(greaterThanEqual(r, dvec3(den))) - dvec3(lessThan(r, dvec3(0.0LF)));
    value = vec4(vec3(q), 1.0);
    prim = gl_PrimitiveID + 1;
}
"""


class _GL:
    """The cached context and the program drawing the mesh."""

    def __init__(self) -> None:
        try:
            import moderngl
        except ImportError as exc:  # pragma: no cover - moderngl is a dependency
            raise BackendError(f"the OpenGL backend needs moderngl ({exc}); {INSTALL_HINT}") from None
        try:
            self.ctx = moderngl.create_standalone_context(backend="egl")
        except Exception as exc:  # moderngl raises bare Exception for EGL failures
            raise BackendError(
                f"no headless OpenGL context could be created ({_one_line(exc)}); {INSTALL_HINT}"
            ) from None
        if self.ctx.version_code < 330:
            version = self.ctx.version_code
            self.ctx.release()
            raise BackendError(f"OpenGL 3.3 is needed, this context has {version}; {INSTALL_HINT}")
        self.float_program = self.ctx.program(vertex_shader=_FLOAT_VS, fragment_shader=_FLOAT_FS)
        # doubles in shaders are core in OpenGL 4.0
        self.exact_program = None
        if self.ctx.version_code >= 400:
            self.exact_program = self.ctx.program(
                vertex_shader=_EXACT_VS, geometry_shader=_EXACT_GS, fragment_shader=_EXACT_FS
            )
        vx, vy = self.ctx.info["GL_MAX_VIEWPORT_DIMS"]
        limit = min(vx, vy, int(self.ctx.info["GL_MAX_RENDERBUFFER_SIZE"]))
        # the viewport is the tile rounded up to a power of two, so keep that within limits
        self.tile = min(MAX_TILE, 1 << (limit.bit_length() - 1))
        self.lock = threading.Lock()


_state: _GL | None = None
_failure: BackendError | None = None
_create_lock = threading.Lock()


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _create() -> _GL:
    """Make the context (the factory tests replace to simulate a machine without GL)."""
    return _GL()


def context() -> _GL:
    """The shared GL state, created on first use; BackendError if GL is unusable."""
    global _state, _failure
    with _create_lock:
        if _state is None:
            if _failure is not None:
                raise _failure
            try:
                _state = _create()
            except BackendError as exc:
                _failure = exc  # do not retry a slow, failing EGL probe on every call
                raise
    return _state


def available() -> bool:
    """True if a GL context can be made (creating it if need be)."""
    try:
        context()
    except BackendError:
        return False
    return True


def _skirt(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skirt geometry around the mesh: (vertices, values, triangles), the triangles
    indexing the mesh's vertices followed by the skirt's own."""
    w, h = mesh.width, mesh.height
    v = mesh.vertices.astype(np.int64)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    n = len(v)
    vals = mesh.values.reshape(n, -1)
    # boundary edges: in a mesh that tiles the image (what mesh.validate checks), each
    # side of it is cut into edges by the vertices on it that triangles use
    used = np.zeros(n, bool)
    used[t.ravel()] = True
    sides = []  # each side's used vertices in order along it: top, bottom, left, right
    for on, along in ((v[:, 1] == 0, v[:, 0]), (v[:, 1] == h - 1, v[:, 0]),
                      (v[:, 0] == 0, v[:, 1]), (v[:, 0] == w - 1, v[:, 1])):
        side = np.flatnonzero(on & used)
        sides.append(side[np.argsort(along[side])])
    a = np.concatenate([side[:-1] for side in sides])
    b = np.concatenate([side[1:] for side in sides])
    # outward unit offset of each boundary edge, from the side it lies on
    off = np.repeat(np.array([[0, -1], [0, 1], [-1, 0], [1, 0]], np.int64),
                    [max(len(side) - 1, 0) for side in sides], axis=0)
    m = len(a)
    # quad a, b, b', a' as triangles (a, b, b') and (a, b', a'); a' = n + 2i, b' = n + 2i + 1
    skirt_v = np.empty((2 * m, 2), np.int64)
    skirt_v[0::2] = v[a] + off
    skirt_v[1::2] = v[b] + off
    skirt_vals = np.empty((2 * m, vals.shape[1]), vals.dtype)
    skirt_vals[0::2] = vals[a]
    skirt_vals[1::2] = vals[b]
    ia = n + 2 * np.arange(m)
    quads = np.concatenate([np.stack([a, b, ia + 1], 1), np.stack([a, ia + 1, ia], 1)])
    # corner squares of the corner's value, outside each image corner
    corners = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.int64)
    out_dir = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.int64)
    # the ends of the top and bottom sides, in the order of `corners`
    top, bottom = sides[0], sides[1]
    if len(top) == 0 or len(bottom) == 0:
        raise CorruptError("the mesh lacks a vertex at an image corner")
    corner_idx = np.array([top[0], top[-1], bottom[-1], bottom[0]])
    if not np.array_equal(v[corner_idx], corners):
        raise CorruptError("the mesh lacks a vertex at an image corner")
    dx = out_dir * [1, 0]
    dy = out_dir * [0, 1]
    cv = np.stack([corners + dx, corners + out_dir, corners + dy], axis=1).reshape(-1, 2)
    cvals = np.repeat(vals[corner_idx], 3, axis=0)
    k = n + 2 * m + 3 * np.arange(4)
    ctri = np.concatenate([np.stack([corner_idx, k, k + 1], 1), np.stack([corner_idx, k + 1, k + 2], 1)])
    sv = np.concatenate([skirt_v, cv])
    tris = orient(np.concatenate([v, sv]), np.concatenate([quads, ctri]))
    return sv, np.concatenate([skirt_vals, cvals]), tris


def render(mesh: Mesh, exact: bool = True) -> np.ndarray:
    """Decode a validated mesh with OpenGL to an image of its dtype and channels.

    exact: evaluate the normative integer rule in the shader (identical to the CPU
    decoder); False, or a context without doubles, interpolates in float32 (within 1).
    """
    gl = context()
    if len(mesh.triangles) == 0:
        # one pixel wide or high: no triangles to rasterise, only the exact 1-D rule
        from .decoder_cpu import render_line

        return render_line(mesh)
    w, h, c = mesh.width, mesh.height, mesh.channels
    program = gl.exact_program if exact else None
    if program is not None and w * h > MAX_EXACT_PIXELS:
        raise UnsupportedError(f"a {w}x{h} image is too large for the exact OpenGL decoder")
    program = program or gl.float_program
    sv, svals, stri = _skirt(mesh)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    tris = np.concatenate([t, stri]).astype(np.int32)
    verts = np.concatenate([mesh.vertices.astype(np.int64), sv])
    # interleaved vertex data: x, y as int32, then three float32 value slots
    vdata = np.zeros(len(verts), dtype=[("pos", "<i4", 2), ("val", "<f4", 3)])
    vdata["pos"] = verts
    vdata["val"][:, :c] = np.concatenate([mesh.values.reshape(len(mesh.vertices), c), svals])
    value = np.empty((h, w, c), np.float32)
    drawn = np.empty((h, w), np.int32)
    tile = gl.tile
    tiles = [(x0, y0) for y0 in range(0, h, tile) for x0 in range(0, w, tile)]
    if len(tiles) == 1:
        picks = [tris]
    else:
        # per tile, the triangles whose bounding box reaches it
        px, py = verts[tris, 0], verts[tris, 1]
        lo_x, hi_x, lo_y, hi_y = px.min(1), px.max(1), py.min(1), py.max(1)
        picks = [
            tris[(hi_x >= x0) & (lo_x < x0 + tile) & (hi_y >= y0) & (lo_y < y0 + tile)]
            for x0, y0 in tiles  # a loop over tiles
        ]
    with gl.lock, gl.ctx:
        vbo = gl.ctx.buffer(vdata.tobytes())
        try:
            for (x0, y0), pick in zip(tiles, picks):  # a loop over tiles
                tw, th = min(tile, w - x0), min(tile, h - y0)
                _draw(gl, program, vbo, pick, x0, y0, tw, th, c,
                      value[y0:y0 + th, x0:x0 + tw], drawn[y0:y0 + th, x0:x0 + tw])
        finally:
            vbo.release()
    if not drawn.all():
        y, x = np.argwhere(drawn == 0)[0]
        raise CorruptError(f"the mesh leaves pixel (row {y}, column {x}) uncovered")
    if program is gl.float_program:
        value = np.floor(value.astype(np.float64) + 0.5)  # round half up, as the CPU does
    top = np.iinfo(mesh.dtype).max
    out = np.clip(value, 0, top).astype(mesh.dtype)
    return out[:, :, 0] if c == 1 else out


def _draw(gl: _GL, program, vbo, tris: np.ndarray, x0: int, y0: int, tw: int, th: int,
          c: int, value: np.ndarray, drawn: np.ndarray) -> None:
    """Render one tile into `value` (th x tw x c) and `drawn` (primitive + 1, 0 = none)."""
    ctx = gl.ctx
    comps = 1 if c == 1 else 4
    rb_val = ctx.renderbuffer((tw, th), components=comps, dtype="f4")
    rb_prim = ctx.renderbuffer((tw, th), components=1, dtype="i4")
    fbo = ctx.framebuffer(color_attachments=[rb_val, rb_prim])
    ibo = ctx.buffer(tris.tobytes())
    vao = ctx.vertex_array(program, [(vbo, "2i 3f", "pos", "val")], index_buffer=ibo,
                           index_element_size=4)
    try:
        fbo.use()
        # 0.0 clears both targets to all-zero bits: prim 0 means "not drawn"
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        vw, vh = 1 << max(tw - 1, 1).bit_length(), 1 << max(th - 1, 1).bit_length()
        ctx.viewport = (0, 0, vw, vh)
        ctx.disable(ctx.DEPTH_TEST | ctx.BLEND | ctx.CULL_FACE)
        program["origin"].value = (x0 - 0.5, y0 - 0.5)
        program["scale"].value = (2.0 / vw, 2.0 / vh)
        if "first" in program:
            program["first"].value = (x0, y0)
        vao.render(mode=ctx.TRIANGLES)
        raw = fbo.read(viewport=(0, 0, tw, th), components=comps, dtype="f4", attachment=0)
        value[:] = np.frombuffer(raw, np.float32).reshape(th, tw, comps)[:, :, :c]
        raw = fbo.read(viewport=(0, 0, tw, th), components=1, dtype="i4", attachment=1)
        drawn[:] = np.frombuffer(raw, np.int32).reshape(th, tw)
    finally:
        for obj in (vao, ibo, fbo, rb_prim, rb_val):
            obj.release()
