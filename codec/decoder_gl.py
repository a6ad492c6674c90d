"""OpenGL decoder (the paper's §3.4.2, "Approximation of Digital Images with
Discontinuity-Preserving Adaptive Triangular Meshes"): rasterise the mesh with moderngl.

A headless context (EGL; Mesa's llvmpipe renders on machines without a GPU) is created
on first use and kept; importing this module touches no GL.

Geometry. Mesh point (x, y) maps to window point (x - x0 + 1/2, y - y0 + 1/2) of a tile
whose first pixel is (x0, y0), so OpenGL's pixel centres fall on the integer points of
the mesh: pixel (row y, column x) samples the mesh at (x, y), as in the CPU decoder.
Window row 0 is image row y0, which is also the first row glReadPixels returns, so no
flip is needed. Images larger than a tile (MAX_TILE, within the context's maximum
viewport and renderbuffer size) are rendered tile by tile.

Coverage is decided in integers, not by the rasteriser. The rasteriser's own edge tests
cannot be trusted near long edges: a triangle reaching far outside the viewport (a wide
image's band, a large triangle seen from a small tile) is clipped in floating point, and
the clipped edges move by enough to hand pixels a thousandth of a pixel from an edge to
the neighbouring triangle, whose plane then gives them a value thousands of levels off.
So a geometry shader draws each triangle with its edges pushed out by MARGIN pixels and
its sharp corners capped (a superset of its pixels whatever the clipping does), and the
fragment shader keeps a pixel only if the triangle's exact integer edge weights are all
non-negative (boundary included, which also covers the image's border). Pixels on a
shared edge may be written by both triangles: the rule gives them the same value
(ATM.md §5), so the order does not matter.

Values (exact mode, the default; needs OpenGL 4.0 for double precision). The fragment
shader evaluates the CPU decoder's normative rule, floor((2 sum w_i v_i + D) / 2D), with
the integer edge weights w_i in int32 (|w_i| <= 2 W H < 2**31) and the sums in double
(< 2**53, exact), corrects the quotient by its exact remainder, and writes the integer
into an R32F (gray) or RGBA32F (colour) target, which holds every 16-bit value exactly.
GL and CPU images are identical.

Values (float mode, exact=False, and the fallback on contexts without doubles): the same
weights, the interpolation sum w_i v_i / D in float32, rounded half up on read-back:
values whose exact fraction is one half may round either way, so within 1 of the CPU
decoder.

A second R32I target records gl_PrimitiveID + 1 (0 where nothing drew): a pixel left at
0 is a CorruptError, as in the CPU decoder.
"""

from __future__ import annotations

import threading

import numpy as np

from .errors import BackendError, CorruptError, UnsupportedError
from .mesh import Mesh

#: Largest tile side rendered at once; bounds the read-back memory (16 bytes a pixel).
MAX_TILE = 2048
#: The exact shader's int32 edge weights stay below 2**31 up to this many pixels.
MAX_EXACT_PIXELS = 1 << 30
#: Half-width in pixels of the rectangle drawn around each edge. The float32 window
#: coordinates of the clipped geometry are off by at most MAX_DIMENSION * 2**-23 of a
#: pixel (1/8 at the largest image side), well inside it.
MARGIN = 0.75
#: Corners whose pushed-out point would lie more than MARGIN * sqrt(2 / _MIN_K) away
#: (angles under about 11 degrees) are capped instead, by a chord at least 0.9 MARGIN
#: from them.
_MIN_K = 0.02

INSTALL_HINT = (
    "install Mesa's EGL and software renderer (Debian/Ubuntu: apt-get install libegl1 "
    "libegl-mesa0 libgl1-mesa-dri) or use the CPU decoder: --backend cpu on the command line, "
    "backend='cpu' in Python"
)

_VS = """
#version {version}
in ivec2 pos;
in vec3 val;
flat out ivec2 g_pos;
flat out vec3 g_val;
void main() {{
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);   // the geometry shader places the vertices
    g_pos = pos;
    g_val = val;
}}
"""

# draws a superset of the triangle's pixels, whatever the clipping: the triangle with its
# edges pushed out by MARGIN, a convex polygon of 3 to 6 corners. Each vertex carries the
# whole triangle (corners and values) to the fragment shader.
_GS = """
#version {version}
uniform vec2 origin;   // the tile's first pixel, minus one half
uniform vec2 scale;    // 2 / viewport size (a power of two: exact)
layout(triangles) in;
layout(triangle_strip, max_vertices = 6) out;
flat in ivec2 g_pos[];
flat in vec3 g_val[];
flat out ivec2 p0, p1, p2;
flat out vec3 v0, v1, v2;
void emit(vec2 q) {{
    gl_Position = vec4(q * scale - 1.0, 0.0, 1.0);
    gl_PrimitiveID = gl_PrimitiveIDIn;
    p0 = g_pos[0]; p1 = g_pos[1]; p2 = g_pos[2];
    v0 = g_val[0]; v1 = g_val[1]; v2 = g_val[2];
    EmitVertex();
}}
void main() {{
    vec2 q[3];
    for (int i = 0; i < 3; i++) q[i] = vec2(g_pos[i]) - origin;  // exact below 2**23
    vec2 e = q[1] - q[0], f = q[2] - q[0];
    if (e.x * f.y - e.y * f.x < 0.0) {{ vec2 s = q[1]; q[1] = q[2]; q[2] = s; }}
    vec2 n[3];  // outward unit normal of the edge from corner i to corner i + 1
    for (int i = 0; i < 3; i++) {{
        vec2 d = normalize(q[(i + 1) % 3] - q[i]);
        n[i] = vec2(d.y, -d.x);
    }}
    // the corners of the pushed-out triangle, in order: where a corner's two edges meet
    // once pushed out (MARGIN / cos(half the angle between their normals) from it), or,
    // at a sharp corner where that is far, two points capping it MARGIN beyond it
    vec2 c[6];
    int count = 0;
    for (int i = 0; i < 3; i++) {{
        vec2 a = n[(i + 2) % 3], b = n[i];
        float k = 1.0 + dot(a, b);
        if (k >= {min_k}) {{
            c[count++] = q[i] + (a + b) * ({margin} / k);
        }} else {{
            c[count++] = q[i] + (a - vec2(a.y, -a.x)) * {margin};  // along the edge in, on
            c[count++] = q[i] + (b + vec2(b.y, -b.x)) * {margin};  // back along the edge out
        }}
    }}
    // a convex polygon as one strip: corners 0, 1, count - 1, 2, count - 2, ...
    for (int j = 0; j < count; j++) {{
        emit(c[(j & 1) == 1 ? (j + 1) / 2 : (count - j / 2) % count]);
    }}
    EndPrimitive();
}}
"""

# the triangle's integer edge weights at the pixel, positive inside; pixels outside
# the closed triangle are discarded
_FS_HEAD = """
#version {version}
uniform ivec2 first;   // the tile's first pixel
flat in ivec2 p0, p1, p2;
flat in vec3 v0, v1, v2;
layout(location = 0) out vec4 value;
layout(location = 1) out int prim;
int weight(ivec2 a, ivec2 b, ivec2 p) {{
    return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
}}
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy) + first;   // centres are at i + 1/2: exact
    int w0 = weight(p1, p2, p);
    int w1 = weight(p2, p0, p);
    int w2 = weight(p0, p1, p);
    int d = w0 + w1 + w2;
    if (d < 0) {{ w0 = -w0; w1 = -w1; w2 = -w2; d = -d; }}
    if (w0 < 0 || w1 < 0 || w2 < 0) discard;
"""

_EXACT_FS = _FS_HEAD + """
    dvec3 t = 2.0LF * (double(w0) * dvec3(v0) + double(w1) * dvec3(v1) + double(w2) * dvec3(v2))
              + double(d);
    double den = 2.0LF * double(d);
    dvec3 q = floor(t / den);
    // t, den and q * den are exact integers: fix any rounding of the division
    dvec3 r = t - q * den;
    q += dvec3(greaterThanEqual(r, dvec3(den))) - dvec3(lessThan(r, dvec3(0.0LF)));
    value = vec4(vec3(q), 1.0);
    prim = gl_PrimitiveID + 1;
}}
"""

_FLOAT_FS = _FS_HEAD + """
    vec3 s = float(w0) * v0 + float(w1) * v1 + float(w2) * v2;
    value = vec4(s / float(d), 1.0);
    prim = gl_PrimitiveID + 1;
}}
"""


def _program(ctx, version: int, fragment: str):
    def source(text: str) -> str:
        return text.format(version=version, margin=repr(MARGIN), min_k=repr(_MIN_K)).lstrip()

    return ctx.program(vertex_shader=source(_VS), geometry_shader=source(_GS), fragment_shader=source(fragment))


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
        self.float_program = _program(self.ctx, 330, _FLOAT_FS)
        # doubles in shaders are core in OpenGL 4.0
        self.exact_program = _program(self.ctx, 400, _EXACT_FS) if self.ctx.version_code >= 400 else None
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
    tris = np.asarray(mesh.triangles, dtype=np.int32)
    verts = mesh.vertices
    # interleaved vertex data: x, y as int32, then three float32 value slots
    vdata = np.zeros(len(verts), dtype=[("pos", "<i4", 2), ("val", "<f4", 3)])
    vdata["pos"] = verts
    vdata["val"][:, :c] = mesh.values.reshape(len(verts), c)
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
        ctx.scissor = (0, 0, tw, th)  # no fragment work beyond the tile
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
        ctx.scissor = None
        for obj in (vao, ibo, fbo, rb_prim, rb_val):
            obj.release()
