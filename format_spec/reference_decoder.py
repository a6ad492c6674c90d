"""An independent decoder of the `.atm` format, written from ATM.md alone.

It shares no code with the `codec` package and uses no triangulation library: it
builds the constrained Delaunay triangulation of implicit-connectivity bands itself
with exact integer predicates (Python ints), so that ATM.md can be checked to be
implementable by a stranger. It is plain and slow on purpose: readable first.

    decode(data: bytes) -> numpy.ndarray   # the image, as codec.decode returns it
    read(data: bytes) -> (Header, [Band])  # the checked bands: vertices, walls, triangles
    delaunay(xs, ys, segments)             # the triangulation of §4.2.5 alone

Anything but a valid file raises DecodeError (UnsupportedError for a version or a
reserved value it does not implement). Standalone: ``python reference_decoder.py
in.atm out.npy``. Section numbers (§) refer to ATM.md.
"""

from __future__ import annotations

import math
import os
import struct
import sys
import zlib

import numpy as np
import zstandard

SIGNATURE = b"\x89ATM\r\n\x1a\n"
# Version 6 keeps version 5's bytes but defines the implicit triangulation (§4.2.5);
# a version-5 file decoded by the new rule could give other pixels, so it is refused (§7).
VERSION = 6

# §8: the limits this decoder applies before allocating.
MAX_SIDE = 1 << 20
MAX_PIXELS = 1 << 28
MAX_CHUNK = (1 << 31) - 1
MAX_IMAGE_BYTES = 1 << 30


def frame_limit(payload: bytes) -> int:
    """§8: the most a MESH or MASK frame may declare for its stored length S."""
    return (1 << 20) + 1024 * len(payload)


def rebuilt_limit(payload: bytes) -> int:
    """§8: the most vertices of a connectivity-1 band stored in S bytes."""
    return (1 << 16) + 64 * len(payload)


class DecodeError(Exception):
    """The input is not a valid `.atm` file (the reason is in the message)."""


class UnsupportedError(DecodeError):
    """A valid-looking file this decoder does not implement (e.g. another version)."""


# ----------------------------------------------------------------------------
# Bytes


class Reader:
    """Reads little-endian fields from a byte string, refusing to read past its end."""

    def __init__(self, data: bytes, what: str) -> None:
        self.data, self.pos, self.what = data, 0, what

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise DecodeError(f"{self.what}: truncated (wanted {n} bytes at offset {self.pos})")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u8(self) -> int:
        return self.take(1)[0]

    def u16(self) -> int:
        return struct.unpack("<H", self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack("<I", self.take(4))[0]

    def varints(self, n: int, name: str) -> list[int]:
        """§4.2.1: a u32 byte count, then exactly `n` LEB128 numbers of at most 5 bytes."""
        raw = self.take(self.u32())
        if len(raw) < n:  # every number takes at least one byte
            raise DecodeError(f"{self.what}: {name} holds fewer than {n} numbers")
        out, value, shift, length = [], 0, 0, 0
        for byte in raw:
            value |= (byte & 0x7F) << shift
            shift += 7
            length += 1
            if byte & 0x80:
                if length == 5:
                    raise DecodeError(f"{self.what}: {name} has a number longer than 5 bytes")
                continue
            out.append(value)
            value, shift, length = 0, 0, 0
        if length or len(out) != n:
            raise DecodeError(f"{self.what}: {name} holds {len(out)} whole numbers, not {n}")
        return out

    def end(self) -> None:
        if self.pos != len(self.data):
            raise DecodeError(f"{self.what}: {len(self.data) - self.pos} bytes after the last field")


def unzigzag(n: int) -> int:
    """§4.2.1: 0, 1, 2, 3, ... -> 0, -1, 1, -2, ..."""
    return (n >> 1) if n % 2 == 0 else -((n + 1) >> 1)


def decompress(payload: bytes, limit: int, what: str) -> bytes:
    """§4: one Zstandard frame that declares its size, refused above `limit` before any
    output is made."""
    try:
        declared = zstandard.get_frame_parameters(payload).content_size
    except zstandard.ZstdError as exc:
        raise DecodeError(f"{what}: not a Zstandard frame ({exc})") from None
    if declared == zstandard.CONTENTSIZE_UNKNOWN:
        raise DecodeError(f"{what}: the Zstandard frame does not declare its size")
    if declared > limit:
        raise DecodeError(f"{what}: declares {declared} bytes, more than the {limit} the image can need")
    try:
        # The one-shot call writes into a buffer of the declared size, so it cannot
        # grow past it; the stream object then tells whether anything follows the frame.
        out = zstandard.ZstdDecompressor().decompress(payload)
        stream = zstandard.ZstdDecompressor().decompressobj()
        stream.decompress(payload)
    except zstandard.ZstdError as exc:
        raise DecodeError(f"{what}: bad Zstandard frame ({exc})") from None
    if len(out) != declared:
        raise DecodeError(f"{what}: decompressed to {len(out)} bytes, not the declared {declared}")
    if stream.unused_data:
        raise DecodeError(f"{what}: {len(stream.unused_data)} bytes after the Zstandard frame")
    return out


def read_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """§3, §4: the (type, payload) of every chunk up to and including AEND."""
    if data[:8] != SIGNATURE:
        raise DecodeError("not an .atm file (bad signature)")
    if len(data) < 10:
        raise DecodeError("truncated before the version")
    version = struct.unpack_from("<H", data, 8)[0]
    if version != VERSION:
        raise UnsupportedError(f"unsupported version {version}: this decoder reads version {VERSION} only")
    out, pos = [], 10
    while True:
        if pos + 8 > len(data):
            raise DecodeError("truncated: the file ends before its AEND chunk")
        length, kind = struct.unpack_from("<I4s", data, pos)
        if length > MAX_CHUNK:
            raise DecodeError(f"chunk at offset {pos} claims {length} bytes (at most 2^31 - 1)")
        if not all(65 <= c <= 90 or 97 <= c <= 122 for c in kind):
            raise DecodeError(f"chunk at offset {pos} has a type that is not four ASCII letters: {kind!r}")
        end = pos + 8 + length
        if end + 4 > len(data):
            raise DecodeError(f"truncated inside the {kind.decode()} chunk at offset {pos}")
        payload = data[pos + 8 : end]
        (crc,) = struct.unpack_from("<I", data, end)
        if zlib.crc32(kind + payload) != crc:
            raise DecodeError(f"{kind.decode()} chunk at offset {pos}: CRC mismatch")
        out.append((kind, payload))
        pos = end + 4
        if kind == b"AEND":
            return out  # §3: bytes after AEND are not part of the file


# ----------------------------------------------------------------------------
# Hilbert curve (§4.2.2)


def hilbert_side(width: int, rows: int) -> int:
    """The smallest power of two at least `width` and at least `rows`."""
    n = 1
    while n < width or n < rows:
        n *= 2
    return n


def hilbert_distance(n: int, x: int, y: int) -> int:
    """§4.2.2's d(x, y), transcribed."""
    d = 0
    s = n // 2
    while s >= 1:
        rx = 1 if x & s else 0
        ry = 1 if y & s else 0
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:
            if rx == 1:
                x, y = n - 1 - x, n - 1 - y
            x, y = y, x
        s //= 2
    return d


def hilbert_point(n: int, d: int) -> tuple[int, int]:
    """The inverse of hilbert_distance: the point at distance d along the curve."""
    x = y = 0
    s = 1
    while s < n:
        rx = 1 & (d // 2)
        ry = 1 & (d ^ rx)
        if ry == 0:  # undo the forward step's reflection and swap, at this scale
            if rx == 1:
                x, y = s - 1 - x, s - 1 - y
            x, y = y, x
        x += s * rx
        y += s * ry
        d //= 4
        s *= 2
    return x, y


# ----------------------------------------------------------------------------
# Exact predicates and the constrained Delaunay triangulation (§4.2.5)


class Triangulation:
    """A triangulation of integer points kept as a map from each directed edge (u, v)
    to the third corner w of the triangle (u, v, w) on its left; every triangle is
    stored with doubled area D > 0."""

    def __init__(self, xs: list[int], ys: list[int]) -> None:
        self.x, self.y = xs, ys
        self.apex: dict[tuple[int, int], int] = {}
        self.anchor: list[int] = [-1] * len(xs)  # a neighbour of each vertex, to start walks
        self.fixed: set[tuple[int, int]] = set()  # constrained edges, (smaller, larger)
        self.last = -1  # a vertex of a recent triangle, where point location starts

    def first(self, *vertices: int) -> int:
        """The vertex first in raster order (smallest y, then x): the one whose lift
        has the largest perturbation (§4.2.5, priority)."""
        return min(vertices, key=lambda v: (self.y[v], self.x[v]))

    # predicates (exact: Python ints have no overflow)

    def orient(self, a: int, b: int, c: int) -> int:
        """Doubled signed area of (a, b, c): > 0 when c is left of a -> b."""
        x, y = self.x, self.y
        return (x[b] - x[a]) * (y[c] - y[a]) - (x[c] - x[a]) * (y[b] - y[a])

    def incircle(self, a: int, b: int, c: int, d: int) -> int:
        """> 0 when d is inside the circle through a, b, c (taken with D > 0), < 0 when
        outside, 0 when the four are cocircular. Up to 85 bits for the format's largest
        bands (§4.2.5): Python ints, never floats."""
        x, y = self.x, self.y
        adx, ady = x[a] - x[d], y[a] - y[d]
        bdx, bdy = x[b] - x[d], y[b] - y[d]
        cdx, cdy = x[c] - x[d], y[c] - y[d]
        return ((adx * adx + ady * ady) * (bdx * cdy - cdx * bdy)
                + (bdx * bdx + bdy * bdy) * (cdx * ady - adx * cdy)
                + (cdx * cdx + cdy * cdy) * (adx * bdy - bdx * ady))

    def is_locally_delaunay(self, a: int, b: int) -> bool:
        """Whether edge a-b, between triangles (a, b, c) and (b, a, d), stays under the
        perturbed rule: kept iff d is outside the circle of (a, b, c); when the four
        are cocircular, the diagonal kept is the one that does not touch the corner
        first in raster order (raising that corner's lift takes it off the lower hull)."""
        c, d = self.apex[(a, b)], self.apex[(b, a)]
        det = self.incircle(a, b, c, d)
        if det != 0:
            return det < 0
        return self.first(a, b, c, d) not in (a, b)

    # elementary changes

    def add(self, a: int, b: int, c: int) -> None:
        self.apex[(a, b)] = c
        self.apex[(b, c)] = a
        self.apex[(c, a)] = b
        self.anchor[a], self.anchor[b], self.anchor[c] = b, c, a
        self.last = a

    def remove(self, a: int, b: int, c: int) -> None:
        del self.apex[(a, b)], self.apex[(b, c)], self.apex[(c, a)]

    def flip(self, a: int, b: int) -> list[tuple[int, int]]:
        """Replace triangles (a, b, c), (b, a, d) by (a, d, c), (d, b, c); returns the
        quadrilateral's sides, whose status may have changed."""
        c, d = self.apex[(a, b)], self.apex[(b, a)]
        self.remove(a, b, c)
        self.remove(b, a, d)
        self.add(a, d, c)
        self.add(d, b, c)
        return [(a, d), (d, b), (b, c), (c, a)]

    def legalize(self, edges: list[tuple[int, int]]) -> None:
        """Lawson's flips: until no edge of the stack (nor any edge a flip touches) is
        an unconstrained interior edge that breaks the rule. Under the perturbation no
        four lifted points are coplanar, so each flip lowers the lifted surface and the
        flips end, at the unique triangulation in which every such edge is kept."""
        stack = list(edges)
        while stack:
            a, b = stack.pop()
            if (a, b) not in self.apex or (b, a) not in self.apex:
                continue  # a border edge, or one already flipped away
            if (min(a, b), max(a, b)) in self.fixed or self.is_locally_delaunay(a, b):
                continue
            stack.extend(self.flip(a, b))

    # point insertion

    def locate(self, p: int) -> tuple[int, int, int]:
        """A triangle (a, b, c) that contains point p (boundary included), by walking
        from a recent triangle towards p (it terminates on a Delaunay triangulation)."""
        a = self.last
        b = self.anchor[a]
        while True:
            c = self.apex[(a, b)]
            if self.orient(a, b, p) < 0:
                a, b = b, a
            elif self.orient(b, c, p) < 0:
                a, b = c, b
            elif self.orient(c, a, p) < 0:
                a, b = a, c
            else:
                return a, b, c

    def insert(self, p: int) -> None:
        a, b, c = self.locate(p)
        for u, v in ((a, b), (b, c), (c, a)):
            if self.orient(u, v, p) == 0:
                self.split_edge(u, v, p)
                return
        self.remove(a, b, c)
        self.add(a, b, p)
        self.add(b, c, p)
        self.add(c, a, p)
        self.legalize([(a, b), (b, c), (c, a)])

    def split_edge(self, a: int, b: int, p: int) -> None:
        """Insert p, which lies inside edge a-b."""
        c = self.apex[(a, b)]
        self.remove(a, b, c)
        self.add(a, p, c)
        self.add(p, b, c)
        sides = [(b, c), (c, a)]
        if (b, a) in self.apex:
            d = self.apex[(b, a)]
            self.remove(b, a, d)
            self.add(b, p, d)
            self.add(p, a, d)
            sides += [(a, d), (d, b)]
        self.legalize(sides)

    # segment insertion

    def around(self, a: int) -> list[tuple[int, int]]:
        """The triangles (a, v, w) at vertex a, as (v, w) pairs."""
        out = []
        start = v = self.anchor[a]
        while (a, v) in self.apex:  # turn counter-clockwise
            w = self.apex[(a, v)]
            out.append((v, w))
            v = w
            if v == start:
                return out
        v = start
        while (v, a) in self.apex:  # reached the border: turn clockwise from the start
            u = self.apex[(v, a)]
            out.append((u, v))
            v = u
        return out

    def on_segment_error(self, a: int, b: int, v: int) -> DecodeError:
        return DecodeError(
            f"wall segment ({self.x[a]}, {self.y[a]})-({self.x[b]}, {self.y[b]}) passes through "
            f"vertex ({self.x[v]}, {self.y[v]}), so it cannot be a triangle edge (§4.2.3, constraint 6)")

    def insert_segment(self, a: int, b: int) -> None:
        """Make a-b an edge that no flip removes: remove the triangles it crosses and
        triangulate the two holes it leaves on either side."""
        key = (min(a, b), max(a, b))
        if (a, b) in self.apex or (b, a) in self.apex:
            self.fixed.add(key)
            return
        x, y = self.x, self.y

        def ahead(v: int) -> bool:  # v lies on the ray from a through b
            return self.orient(a, b, v) == 0 and (x[v] - x[a]) * (x[b] - x[a]) + (y[v] - y[a]) * (y[b] - y[a]) > 0

        for v, w in self.around(a):
            if ahead(v) or ahead(w):
                raise self.on_segment_error(a, b, v if ahead(v) else w)
            if self.orient(a, v, b) > 0 and self.orient(a, w, b) < 0:
                right, left = v, w
                break
        else:
            raise DecodeError(f"wall segment from vertex {a} leaves the band")
        crossed = [(a, right, left)]
        right_chain, left_chain = [right], [left]
        while True:
            if (min(left, right), max(left, right)) in self.fixed:
                raise DecodeError(
                    f"wall segments cross: ({x[a]}, {y[a]})-({x[b]}, {y[b]}) and "
                    f"({x[left]}, {y[left]})-({x[right]}, {y[right]}) (§4.2.3, constraint 6)")
            v = self.apex[(left, right)]
            crossed.append((left, right, v))
            if v == b:
                break
            side = self.orient(a, b, v)
            if side == 0:
                raise self.on_segment_error(a, b, v)
            if side > 0:
                left = v
                left_chain.append(v)
            else:
                right = v
                right_chain.append(v)
        for t in crossed:
            self.remove(*t)
        new: list[tuple[int, int, int]] = []
        self.fill(a, b, left_chain, new)
        self.fill(b, a, right_chain[::-1], new)
        self.fixed.add(key)
        self.legalize([e for t in new for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))])

    def fill(self, u: int, v: int, chain: list[int], new: list[tuple[int, int, int]]) -> None:
        """Triangulate the polygon u, chain..., v (the chain left of u -> v, in order
        from u to v): the chain vertex whose circle with u and v holds no other one
        (under the perturbed rule) makes a triangle with u-v, and the two polygons
        beside it are filled the same way."""
        todo = [(u, v, chain)]
        while todo:
            u, v, chain = todo.pop()
            if not chain:
                continue
            best = chain[0]
            for c in chain[1:]:
                det = self.incircle(u, v, best, c)
                if det > 0 or (det == 0 and self.first(best, c) == c):
                    best = c
            i = chain.index(best)
            self.add(u, v, best)
            new.append((u, v, best))
            todo.append((u, best, chain[:i]))
            todo.append((best, v, chain[i + 1 :]))

    def triangles(self) -> list[tuple[int, int, int]]:
        """Each triangle once, rotated to start with its smallest index, sorted: the
        canonical list of §4.2.3."""
        return sorted((a, b, c) for (a, b), c in self.apex.items() if a < b and a < c)


def delaunay(xs: list[int], ys: list[int], segments: list[tuple[int, int]],
             order: list[int] | None = None) -> list[tuple[int, int, int]]:
    """The triangulation of §4.2.5: the constrained Delaunay triangulation of the
    integer points (xs[i], ys[i]) with `segments` (index pairs) as constraints, made
    unique by the perturbation in raster order; the canonical triangle list (§4.2.3).

    The points' convex hull must be their bounding box (a valid band's is its
    rectangle). They are inserted in `order` (default: along a Hilbert curve, which
    keeps each walk short); any order, and any order of the segments, gives the same
    triangles."""
    box = (min(xs), max(xs), min(ys), max(ys))
    if box[0] == box[1] or box[2] == box[3]:
        raise DecodeError("MESH: the vertices of a two-dimensional band lie on one line")
    where = {(x, y): i for i, (x, y) in enumerate(zip(xs, ys))}
    corners = [(box[0], box[2]), (box[1], box[2]), (box[0], box[3]), (box[1], box[3])]
    missing = [c for c in corners if c not in where]
    if missing:
        # The hull is then smaller than the box, so no tiling of the band (constraint 4).
        raise DecodeError(f"MESH: no vertex at corner(s) {missing}: the triangles cannot tile the band")
    tl, tr, bl, br = (where[c] for c in corners)
    if order is None:
        n = hilbert_side(box[1] - box[0] + 1, box[3] - box[2] + 1)
        order = sorted(range(len(xs)), key=lambda i: hilbert_distance(n, xs[i] - box[0], ys[i] - box[2]))
    t = Triangulation(xs, ys)
    t.add(tl, tr, br)
    t.add(tl, br, bl)
    t.legalize([(tl, br)])
    for p in order:
        if p not in (tl, tr, bl, br):
            t.insert(p)
    for a, b in segments:
        t.insert_segment(a, b)
    # Every flip above was decided by the rule itself; this last pass checks that no
    # free edge is left breaking it (it flips nothing when all is well).
    t.legalize(list(t.apex))
    return t.triangles()


# ----------------------------------------------------------------------------
# Chunks


#: §4.1, §4.4: sample types 3, 4, 5 are signed integers of these types, stored as
#: 16-bit samples plus QUNT's whole-number offset.
SIGNED = {3: np.int8, 4: np.int16, 5: np.int32}


class Header:
    """What AHDR, QUNT and NDAT say about the image."""

    def __init__(self, width: int, height: int, sample_type: int, channels: int) -> None:
        self.width, self.height, self.sample_type, self.channels = width, height, sample_type, channels
        self.offset, self.scale = 0.0, 1.0
        self.nodata: float | None = None
        self.channel_axis = False  # an `axis` chunk: gray decodes as height x width x 1 (§4.9)
        self.step: tuple[float, float] | None = None  # a STEP chunk's offset and scale (§4.10.1)

    @property
    def top(self) -> int:
        """The largest sample value of the mesh."""
        return 255 if self.sample_type == 0 else 65535

    @property
    def layer_top(self) -> int:
        """The largest sample value of the residual layer: binary32 keys for
        sample_type 6 (§4.10)."""
        return 2**32 - 1 if self.sample_type == 6 else self.top


def parse_header(payload: bytes) -> Header:
    """§4.1."""
    if len(payload) != 10:
        raise DecodeError(f"AHDR payload is {len(payload)} bytes, not 10")
    width, height, sample_type, channels = struct.unpack("<IIBB", payload)
    if width < 1 or height < 1:
        raise DecodeError(f"image size {width}x{height}: both sides must be at least 1")
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise DecodeError(f"image size {width}x{height} is over the limits (sides <= 2^20, pixels <= 2^28)")
    if sample_type not in (0, 1, 2, *SIGNED, 6):
        raise UnsupportedError(f"sample_type {sample_type} is reserved")
    if channels not in (1, 3):
        raise UnsupportedError(f"{channels} channels: only 1 (gray) and 3 (RGB) are defined")
    if sample_type >= 2 and channels != 1:
        raise DecodeError(f"sample_type {sample_type} has 1 channel, not {channels}")
    sample_bytes = {0: 1, 1: 2, 2: 4, 3: 1, 4: 2, 5: 4, 6: 4}[sample_type]
    if width * height * channels * sample_bytes > MAX_IMAGE_BYTES:
        raise DecodeError(f"the decoded {width}x{height} image would take more than 2^30 bytes (§8)")
    return Header(width, height, sample_type, channels)


def parse_quantisation(payload: bytes, header: Header) -> None:
    """§4.4."""
    if len(payload) != 16:
        raise DecodeError(f"QUNT payload is {len(payload)} bytes, not 16")
    offset, scale = struct.unpack("<dd", payload)
    if header.sample_type in SIGNED:
        if not (scale == 1.0 and math.isfinite(offset) and offset == int(offset) and -(2**31) <= offset < 2**31):
            raise DecodeError(f"QUNT offset {offset} / scale {scale}: integer samples need scale 1 and a whole int32 offset")
        header.offset, header.scale = offset, scale
        return
    if not (math.isfinite(offset) and math.isfinite(scale) and scale > 0):
        raise DecodeError(f"QUNT offset {offset} / scale {scale}: both must be finite, the scale > 0")
    if abs(offset) + 65535 * scale > float(np.finfo(np.float32).max):
        raise DecodeError("QUNT: offset and scale reach values beyond binary32's range")
    header.offset, header.scale = offset, scale


def parse_step(payload: bytes, header: Header) -> None:
    """§4.10.1."""
    if len(payload) != 16:
        raise DecodeError(f"STEP payload is {len(payload)} bytes, not 16")
    offset, scale = struct.unpack("<dd", payload)
    if not (math.isfinite(offset) and math.isfinite(scale) and scale > 0):
        raise DecodeError(f"STEP offset {offset} / scale {scale}: both must be finite, the scale > 0")
    if abs(offset) + (2**32 - 1) * scale > float(np.finfo(np.float32).max):
        raise DecodeError("STEP: offset and scale reach values beyond binary32's range")
    header.step = (offset, scale)


def parse_nodata(payload: bytes, header: Header) -> None:
    """§4.5."""
    if len(payload) != 8:
        raise DecodeError(f"NDAT payload is {len(payload)} bytes, not 8")
    (value,) = struct.unpack("<d", payload)
    if header.sample_type in (2, 6):
        # NaN, +inf, -inf or a finite binary32 value
        if not (math.isnan(value) or math.isinf(value) or abs(value) <= float(np.finfo(np.float32).max)):
            raise DecodeError(f"NDAT value {value} is outside binary32's range")
        (bits,) = struct.unpack("<Q", payload)
        if header.sample_type == 6 and math.isnan(value) and not (bits >> 29) & 0x7FFFFF:
            raise DecodeError("NDAT: a NaN whose top 23 significand bits are 0 has no binary32 form (§4.10)")
    elif header.sample_type in SIGNED:
        info = np.iinfo(SIGNED[header.sample_type])
        if not (math.isfinite(value) and value == int(value) and info.min <= value <= info.max):
            raise DecodeError(f"NDAT value {value} is not a whole number within {info.min}..{info.max}")
    elif not (math.isfinite(value) and value == int(value) and 0 <= value <= header.top):
        raise DecodeError(f"NDAT value {value} is not a whole number within 0..{header.top}")
    header.nodata = value


def parse_mask(data: bytes, header: Header) -> tuple[int, int, np.ndarray]:
    """§4.6: (y0, rows, holes) with holes a rows x width bool array."""
    r = Reader(data, "MASK")
    y0, rows, count = r.u32(), r.u32(), r.u32()
    width = header.width
    if rows < 1 or y0 + rows > header.height:
        raise DecodeError(f"MASK: rows {y0}..{y0 + rows - 1} in an image of {header.height} rows")
    if count > width * rows + 1:
        raise DecodeError(f"MASK: {count} runs in a band of {width * rows} pixels")
    runs = r.varints(count, "runs")
    r.end()
    if any(n == 0 for n in runs[1:]):
        raise DecodeError("MASK: a run after the first is empty")
    if sum(runs) != width * rows:
        raise DecodeError(f"MASK: the runs cover {sum(runs)} pixels, not {width * rows}")
    flat = np.zeros(width * rows, bool)
    pos = 0
    for i, n in enumerate(runs):
        flat[pos : pos + n] = i % 2 == 1  # runs alternate: data first, then holes
        pos += n
    return y0, rows, flat.reshape(rows, width)


# ----------------------------------------------------------------------------
# MESH (§4.2)


class Band:
    """One MESH chunk's band: vertices by index, polylines as index lists, the sample
    order of §4.2.2, the residuals along it and the triangles."""

    def __init__(self, y0: int, rows: int) -> None:
        self.y0, self.rows = y0, rows
        self.xs: list[int] = []
        self.ys: list[int] = []
        self.polylines: list[list[int]] = []
        self.sequence: list[int] = []
        self.residuals: list[int] = []
        self.triangles: list[tuple[int, int, int]] = []
        self.values = np.zeros((0, 1), np.int64)
        self.holes: np.ndarray | None = None
        self.base_step = 1
        self.listed = False  # connectivity 0: the triangles were stored, not built
        self.residual: bytes | None = None  # the band's RESD payload (§4.8)


def quadrant(a: int, b: int) -> int:
    """§4.2.2's q(a, b) of a non-zero step."""
    if a > 0 and b >= 0:
        return 0
    if a <= 0 and b > 0:
        return 1
    if a < 0 and b <= 0:
        return 2
    return 3


def turn(a: int, b: int, quarters: int) -> tuple[int, int]:
    for _ in range(quarters % 4):
        a, b = -b, a
    return a, b


def mesh_payload_limit(header: Header) -> int:
    """§8: the largest MESH payload the header's image can need, s being the bytes of
    a stored sample (1 for sample_type 0, else 2)."""
    pixels = header.width * header.height
    vertices, triangles = pixels + 16, 2 * pixels + 16
    s = 1 if header.sample_type == 0 else 2
    return min(65 + (35 + s * header.channels) * vertices + 15 * triangles, 1 << 31)


def mesh_count_limit(n_vertices: int, n_triangles: int, n_polylines: int, n_indices: int, channels: int) -> int:
    """§8: the most bytes a MESH payload with these counts can hold."""
    return (32 + 28 + 5 * (2 * n_polylines + 2 * n_indices + n_vertices + 1) + (24 * n_vertices + 7) // 8
            + 5 * n_vertices * channels + 15 * n_triangles)


def read_polylines(r: Reader, count: int, indices: int, width: int, rows: int) -> list[list[int]]:
    """§4.2.2: each polyline as the pixel indices k = y*width + x of its vertices, from
    its start pixel and its turned steps."""
    lengths = r.varints(count, "polyline_lengths")
    if any(n < 2 for n in lengths) or sum(lengths) != indices:
        raise DecodeError("MESH: polyline lengths must each be >= 2 and sum to polyline_index_count")
    starts = r.varints(count, "polyline_starts")
    steps = r.varints(2 * (indices - count), "polyline_steps")
    lines: list[list[int]] = []
    k, s = 0, 0
    for length, start in zip(lengths, starts):
        k += unzigzag(start)
        if not 0 <= k < width * rows:
            raise DecodeError(f"MESH: polyline start pixel {k} is outside the band")
        x, y = k % width, k // width
        line, turned = [k], 0
        for _ in range(length - 1):
            u, v = unzigzag(steps[s]), unzigzag(steps[s + 1])
            s += 2
            if u == 0 and v == 0:
                raise DecodeError("MESH: a polyline step is (0, 0)")
            # step i is the stored pair turned by the quadrants of the pairs before it
            dx, dy = turn(u, v, turned)
            turned += quadrant(u, v)
            if abs(dx) >= width or abs(dy) >= rows:
                raise DecodeError(f"MESH: polyline step ({dx}, {dy}) is longer than the band")
            x, y = x + dx, y + dy
            if not (0 <= x < width and 0 <= y < rows):
                raise DecodeError(f"MESH: a polyline leaves the band at ({x}, {y})")
            line.append(y * width + x)
        lines.append(line)
    return lines


def read_free_vertices(r: Reader, count: int, order: int, width: int, rows: int) -> list[tuple[int, int]]:
    """§4.2.2: the (pixel index, Hilbert distance) of the vertices on no polyline, from
    their keys' gaps, each split into a varint high part and b raw low bits."""
    high = r.varints(count + 1, "positions")
    bits, high = high[0], high[1:]
    if bits > 24:
        raise DecodeError(f"MESH: {bits} low bits per gap (at most 24)")
    packed = r.take(r.u32())
    if len(packed) != (count * bits + 7) // 8:
        raise DecodeError(f"MESH: position_bits holds {len(packed)} bytes, not {(count * bits + 7) // 8}")
    stream = "".join(f"{byte:08b}" for byte in packed)  # most significant bit first
    if "1" in stream[count * bits :]:
        raise DecodeError("MESH: a padding bit of position_bits is 1")
    n = hilbert_side(width, rows)
    free: list[tuple[int, int]] = []
    key = -1
    for i, h in enumerate(high):
        low = int(stream[i * bits : (i + 1) * bits] or "0", 2)
        key += (h << bits) + low + 1
        if order == 0:
            if key >= width * rows:
                raise DecodeError(f"MESH: vertex key {key} is outside the band")
            free.append((key, hilbert_distance(n, key % width, key // width)))
        else:
            if key >= n * n:
                raise DecodeError(f"MESH: Hilbert distance {key} is beyond the curve")
            x, y = hilbert_point(n, key)
            if x >= width or y >= rows:
                raise DecodeError(f"MESH: Hilbert distance {key} is the point ({x}, {y}), outside the band")
            free.append((y * width + x, key))
    return free


def parse_mesh(data: bytes, header: Header, y0_expected: int, rebuilt: int) -> Band:
    """The fields of a MESH payload, the vertices and polylines they define, and the
    listed triangles if any (§4.2.1, §4.2.2)."""
    width = header.width
    r = Reader(data, "MESH")
    y0, rows, n_vertices, n_triangles = r.u32(), r.u32(), r.u32(), r.u32()
    n_polylines, n_indices = r.u32(), r.u32()
    connectivity, position_order = r.u8(), r.u8()
    triangle_crc, base_step = r.u32(), r.u16()
    if y0 != y0_expected:
        raise DecodeError(f"MESH: band starts on row {y0}, expected {y0_expected}")
    if header.height == 1:
        if rows != 1:
            raise DecodeError(f"MESH: {rows} rows in an image one row high")
    elif rows < 2 or y0 + rows > header.height:
        raise DecodeError(f"MESH: band of rows {y0}..{y0 + rows - 1} in an image of {header.height} rows")
    pixels = width * rows  # §8: the counts' limits are per band
    if not 1 <= n_vertices <= pixels:
        raise DecodeError(f"MESH: {n_vertices} vertices in a band of {pixels} pixels")
    if n_triangles > 2 * pixels + 16:
        raise DecodeError(f"MESH: {n_triangles} triangles is over the limit")
    if n_indices > 2 * (pixels + 16) or n_polylines > n_indices:
        raise DecodeError(f"MESH: {n_polylines} polylines of {n_indices} indices is over the limit")
    if len(data) > mesh_count_limit(n_vertices, n_triangles, n_polylines, n_indices, header.channels):
        raise DecodeError(f"MESH: {len(data)} bytes is more than its counts can use")
    if connectivity not in (0, 1):
        raise UnsupportedError(f"MESH: connectivity {connectivity} is reserved")
    if connectivity == 1 and n_vertices > rebuilt:
        raise DecodeError(f"MESH: {n_vertices} vertices to triangulate from so few stored bytes (§8)")
    if position_order not in (0, 1):
        raise UnsupportedError(f"MESH: position_order {position_order} is reserved")
    if base_step < 1:
        raise DecodeError("MESH: sample_step is 0")

    pixel_lines = read_polylines(r, n_polylines, n_indices, width, rows)
    on_lines = {k for line in pixel_lines for k in line}
    n_free = n_vertices - len(on_lines)
    if n_free < 0:
        raise DecodeError(f"MESH: the polylines visit {len(on_lines)} pixels, more than the {n_vertices} vertices")
    free = read_free_vertices(r, n_free, position_order, width, rows)
    for k, _ in free:
        if k in on_lines:
            raise DecodeError(f"MESH: free vertex ({k % width}, {k // width}) is on a polyline")

    # Number the vertices by pixel index; the sample order (§4.2.2).
    pixel_ids = sorted(on_lines | {k for k, _ in free})
    index = {k: i for i, k in enumerate(pixel_ids)}
    band = Band(y0, rows)
    band.base_step = base_step
    band.listed = connectivity == 0
    band.xs = [k % width for k in pixel_ids]
    band.ys = [k // width for k in pixel_ids]
    band.polylines = [[index[k] for k in line] for line in pixel_lines]
    seen: set[int] = set()
    for line in band.polylines:
        for i in line:
            if i not in seen:
                seen.add(i)
                band.sequence.append(i)
    band.sequence += [index[k] for _, k in sorted((d, k) for k, d in free)]

    band.residuals = [unzigzag(z) for z in r.varints(header.channels * n_vertices, "samples")]
    listed = r.varints(3 * n_triangles if connectivity == 0 else 0, "triangles")
    r.end()

    band.triangles = band_triangles(band, width, connectivity, listed, n_triangles, triangle_crc)
    return band


def band_triangles(band: Band, width: int, connectivity: int, listed: list[int], count: int,
                   crc: int) -> list[tuple[int, int, int]]:
    """§4.2.3: the band's triangles (none in a band one pixel wide or high), checked."""
    if width == 1 or band.rows == 1:
        if count:
            raise DecodeError(f"MESH: {count} triangles in a band one pixel wide or high")
        if crc != zlib.crc32(b""):
            raise DecodeError("MESH: triangle_crc does not match the empty triangle list")
        positions = band.ys if width == 1 else band.xs
        if positions[0] != 0 or positions[-1] != max(width, band.rows) - 1:
            raise DecodeError("MESH: a one-pixel band needs a vertex at each end (§4.2.3, constraint 5)")
        # Constraint 6 on a line: a wall segment joins neighbours, no vertex between.
        for line in band.polylines:
            for a, b in zip(line, line[1:]):
                if abs(a - b) != 1:
                    raise DecodeError(f"MESH: wall segment ({a}, {b}) skips a vertex of the line (constraint 6)")
        return []
    if connectivity == 0:
        triangles = listed_triangles(listed, band, width, band.rows)
        ys = band.ys
        extent = sum(max(ys[a], ys[b], ys[c]) - min(ys[a], ys[b], ys[c]) + 1 for a, b, c in triangles)
        if extent > 4 * width * band.rows + (1 << 20):
            raise DecodeError(f"MESH: the triangles span {extent} rows in all, over §8's limit")
    else:
        triangles = implicit_triangles(band)
    check_triangles(band.xs, band.ys, triangles, width, band.rows, count, crc)
    return triangles


def listed_triangles(numbers: list[int], band: Band, width: int, rows: int) -> list[tuple[int, int, int]]:
    """§4.2.3, connectivity 0: the stored canonical list, checked to tile the band."""
    n = len(band.xs)
    out, a = [], 0
    for t in range(0, len(numbers), 3):
        a += numbers[t]
        b, c = a + 1 + numbers[t + 1], a + 1 + numbers[t + 2]
        if max(a, b, c) >= n:
            raise DecodeError(f"MESH: triangle ({a}, {b}, {c}) names a vertex beyond the {n} there are")
        out.append((a, b, c))
    if out != sorted(out):
        raise DecodeError("MESH: listed triangles are not in canonical order")
    xs, ys = band.xs, band.ys
    directed: set[tuple[int, int]] = set()
    for a, b, c in out:
        if (xs[b] - xs[a]) * (ys[c] - ys[a]) - (xs[c] - xs[a]) * (ys[b] - ys[a]) <= 0:
            raise DecodeError(f"MESH: triangle ({a}, {b}, {c}) has doubled area <= 0 (constraint 3)")
        for e in ((a, b), (b, c), (c, a)):
            if e in directed:
                raise DecodeError(f"MESH: two triangles share the directed edge {e}: they overlap (constraint 4.2)")
            directed.add(e)
    for i, j in directed:
        if (j, i) not in directed and not (
            xs[i] == xs[j] == 0 or xs[i] == xs[j] == width - 1 or ys[i] == ys[j] == 0 or ys[i] == ys[j] == rows - 1
        ):
            raise DecodeError(f"MESH: edge ({i}, {j}) has a triangle on one side only but is not on the border (constraint 4.3)")
    edges = {(min(e), max(e)) for e in directed}
    for line in band.polylines:
        for a, b in zip(line, line[1:]):
            if (min(a, b), max(a, b)) not in edges:
                raise DecodeError(f"MESH: wall segment ({a}, {b}) is not a triangle edge (constraint 6)")
    return out


def implicit_triangles(band: Band) -> list[tuple[int, int, int]]:
    """§4.2.3, connectivity 1: the triangulation of §4.2.5, which the decoder builds."""
    segments = [(a, b) for line in band.polylines for a, b in zip(line, line[1:])]
    return delaunay(band.xs, band.ys, segments)


def check_triangles(xs: list[int], ys: list[int], tris: list[tuple[int, int, int]], width: int, rows: int,
                    count: int, crc: int) -> None:
    """§4.2.3: the count, the CRC of the canonical list, the area sum (constraint 4.1)
    and §8's bound on the triangles' total row extent."""
    if len(tris) != count:
        raise DecodeError(f"MESH: {len(tris)} triangles where triangle_count says {count}")
    flat = [i for t in tris for i in t]
    if zlib.crc32(struct.pack(f"<{len(flat)}I", *flat)) != crc:
        raise DecodeError("MESH: the triangles do not match triangle_crc")
    area = sum((xs[b] - xs[a]) * (ys[c] - ys[a]) - (xs[c] - xs[a]) * (ys[b] - ys[a]) for a, b, c in tris)
    if count < 1 or area != 2 * (width - 1) * (rows - 1):
        raise DecodeError("MESH: the triangles do not tile the band (constraint 4.1)")
    extent = sum(max(ys[a], ys[b], ys[c]) - min(ys[a], ys[b], ys[c]) + 1 for a, b, c in tris)
    if extent > 4 * width * rows + (1 << 20):
        raise DecodeError("MESH: the triangles' total row extent is over the limit (§8)")


# ----------------------------------------------------------------------------
# Samples (§4.2.4)


def vertex_steps(band: Band, base: int) -> list[int]:
    """Each vertex's step s_i."""
    n = len(band.xs)
    if base == 1:
        steps = [1] * n
    else:
        xs, ys = band.xs, band.ys
        fan = [0] * n
        for a, b, c in band.triangles:
            d = (xs[b] - xs[a]) * (ys[c] - ys[a]) - (xs[c] - xs[a]) * (ys[b] - ys[a])
            fan[a] += d
            fan[b] += d
            fan[c] += d
        positive = [A for A in fan if A > 0]
        steps = [base] * n
        if positive:
            mean = sum(positive) / len(positive)  # int / int: one correctly rounded division
            for i, A in enumerate(fan):
                if A > 0:
                    f = min(max(math.sqrt(mean / A), 0.25), 4.0)
                    steps[i] = min(max(round(base * f), 1), 65535)  # round(): ties to even
    if band.y0 > 0:
        for i, y in enumerate(band.ys):
            if y == 0:
                steps[i] = 1
    return steps


def sample_values(band: Band, header: Header) -> np.ndarray:
    """The N x C samples, rebuilt along the sequence from each place's parent."""
    n, channels, top = len(band.xs), header.channels, header.top
    place = [0] * n
    for j, i in enumerate(band.sequence):
        place[i] = j
    # p(j): of the vertices sharing a triangle with the j-th and earlier in the
    # sequence, the latest; without one, the place just before.
    latest = [-1] * n
    for t in band.triangles:
        for i in t:
            for k in t:
                if place[i] > place[k] > latest[place[i]]:
                    latest[place[i]] = place[k]
    parent = [p if p >= 0 else j - 1 for j, p in enumerate(latest)]
    steps = vertex_steps(band, band.base_step)
    values = [[0] * channels for _ in range(n)]  # by place in the sequence
    for j, i in enumerate(band.sequence):
        for ch in range(channels):
            r = band.residuals[j * channels + ch]
            if abs(r) > top:
                raise DecodeError(f"MESH: sample residual {r} is beyond the sample range")
            v = (values[parent[j]][ch] if j > 0 else 0) + steps[i] * r
            if not 0 <= v <= top:
                raise DecodeError(f"MESH: sample {v} is outside 0..{top}")
            values[j][ch] = v
    out = np.zeros((n, channels), np.int64)
    for j, i in enumerate(band.sequence):
        out[i] = values[j]
    return out


# ----------------------------------------------------------------------------
# Rendering (§5)


def render_band(band: Band, values: np.ndarray, width: int, rows: int) -> np.ndarray:
    """The band's rows x width x C samples."""
    channels = values.shape[1]
    out = np.zeros((rows, width, channels), np.int64)
    if width == 1 or rows == 1:
        along = band.ys if width == 1 else band.xs
        line = out[:, 0] if width == 1 else out[0]
        order = sorted(range(len(along)), key=lambda i: along[i])
        line[along[order[0]]] = values[order[0]]
        for i, j in zip(order, order[1:]):
            a, b = along[i], along[j]
            p = np.arange(a, b + 1)[:, None]
            line[a : b + 1] = (2 * (values[i] * (b - p) + values[j] * (p - a)) + (b - a)) // (2 * (b - a))
        return out
    xs, ys = band.xs, band.ys
    for i0, i1, i2 in band.triangles:
        x0, y0, x1, y1, x2, y2 = xs[i0], ys[i0], xs[i1], ys[i1], xs[i2], ys[i2]
        d = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        gy, gx = np.mgrid[min(y0, y1, y2) : max(y0, y1, y2) + 1, min(x0, x1, x2) : max(x0, x1, x2) + 1]
        w0 = (x2 - x1) * (gy - y1) - (y2 - y1) * (gx - x1)
        w1 = (x0 - x2) * (gy - y2) - (y0 - y2) * (gx - x2)
        w2 = (x1 - x0) * (gy - y0) - (y1 - y0) * (gx - x0)
        inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        w0, w1, w2 = w0[inside][:, None], w1[inside][:, None], w2[inside][:, None]
        total = w0 * values[i0] + w1 * values[i1] + w2 * values[i2]
        # Pixels on an edge shared by two triangles get the same value from either.
        out[gy[inside], gx[inside]] = (2 * total + d) // (2 * d)
    return out


# ----------------------------------------------------------------------------
# The file


def read(data: bytes) -> tuple[Header, list[Band]]:
    """Parse and check a whole file: its header and its bands, each with triangles,
    samples (`values`, N x C) and hole mask (`holes`, rows x width, or None)."""
    chunks = read_chunks(bytes(data))
    if chunks[0][0] != b"AHDR":
        raise DecodeError(f"the first chunk is {chunks[0][0].decode()}, not AHDR")
    header = parse_header(chunks[0][1])
    bands: list[Band] = []
    expect_qunt, have_ndat, mask, complete = header.sample_type >= 2, False, None, False
    resd = None
    for at, (kind, payload) in enumerate(chunks[1:], start=1):
        name = kind.decode()
        # §4: QUNT follows AHDR directly, with no chunk at all between, ancillary or not.
        if expect_qunt and kind != b"QUNT":
            raise DecodeError(f"{name} where QUNT must follow AHDR directly (sample_type {header.sample_type})")
        if kind == b"axis":  # §4.9: empty, once, before the first band, gray images only
            if payload or header.channel_axis or header.channels != 1 or bands or mask is not None:
                raise DecodeError("axis chunk: it is empty and comes once, before the bands, in a gray image")
            header.channel_axis = True
            continue
        if kind[0] & 0x20:  # other ancillary chunks (lower-case first letter): none needed here
            continue
        if kind == b"QUNT":
            if not expect_qunt:
                raise DecodeError("QUNT chunk out of place (only directly after AHDR, for sample_type 2 to 6)")
            parse_quantisation(payload, header)
            expect_qunt = False
        elif kind == b"STEP":  # §4.10.1: directly after QUNT, sample_type 6 only
            if header.sample_type != 6 or chunks[at - 1][0] != b"QUNT":
                raise DecodeError("STEP chunk out of place (only directly after QUNT, for sample_type 6)")
            parse_step(payload, header)
        elif kind == b"NDAT":
            if have_ndat or bands or mask is not None:
                raise DecodeError("NDAT chunk out of place (once, before the first band)")
            parse_nodata(payload, header)
            have_ndat = True
        elif kind in (b"MASK", b"HOLE"):  # §4.6, §4.11: the same mask, coded two ways
            if not have_ndat:
                raise DecodeError(f"{name} chunk without NDAT")
            if mask is not None:
                raise DecodeError("two MASK or HOLE chunks before one MESH")
            if kind == b"MASK":
                limit = min(16 + 5 * (header.width * header.height + 1), frame_limit(payload))
                mask = parse_mask(decompress(payload, limit, "MASK"), header)
            else:
                mask = parse_hole(payload, header)
        elif kind == b"RESD":  # §4.8: kept for the MESH chunk that follows
            if resd is not None or (have_ndat and mask is None):
                raise DecodeError("RESD chunk out of place (after its band's MASK, before its MESH)")
            resd = payload
        elif kind == b"MESH":
            if bands and (bands[0].residual is None) != (resd is None):
                raise DecodeError("a residual layer covers every band or none")
            if header.sample_type == 6 and resd is None:
                raise DecodeError("sample_type 6: every band needs its RESD chunk (§4.10)")
            if complete:
                raise DecodeError("a MESH chunk after the band that ends on the last row")
            if have_ndat and mask is None:
                raise DecodeError("a MESH chunk without its MASK")
            y0 = bands[-1].y0 + bands[-1].rows - 1 if bands else 0
            limit = min(mesh_payload_limit(header), frame_limit(payload))
            band = parse_mesh(decompress(payload, limit, "MESH"), header, y0, rebuilt_limit(payload))
            if mask is not None:
                if mask[:2] != (band.y0, band.rows):
                    raise DecodeError(f"MASK is for rows {mask[0]}+{mask[1]}, its MESH for {band.y0}+{band.rows}")
                band.holes = mask[2]
                if bands and not np.array_equal(band.holes[0], bands[-1].holes[-1]):
                    raise DecodeError(f"MASK: row {band.y0}, shared by two bands, has two different masks")
                mask = None
            band.values = sample_values(band, header)
            band.residual, resd = resd, None
            bands.append(band)
            complete = band.y0 + band.rows == header.height
        elif kind == b"AEND":
            if payload:
                raise DecodeError("AEND chunk is not empty")
            if not complete or mask is not None or resd is not None:
                raise DecodeError(f"AEND before the bands reach the last row ({header.height - 1})")
        elif kind == b"AHDR":
            raise DecodeError("a second AHDR chunk")
        else:
            raise UnsupportedError(f"unknown critical chunk {name}")
    return header, bands


def decode(data: bytes) -> np.ndarray:
    """Decode `.atm` bytes to the image: height x width (gray; height x width x 1 when
    the file has an `axis` chunk) or height x width x 3 (RGB); uint8, uint16, int8/int16/int32, or float32 for real-valued samples; hole pixels hold the
    NDAT value. Raises DecodeError (UnsupportedError) on anything else."""
    header, bands = read(data)
    image = np.zeros((header.height, header.width, header.channels), np.int64)
    holes = np.zeros((header.height, header.width), bool)
    for band in bands:  # the row two bands share is decoded from the later one (§5)
        image[band.y0 : band.y0 + band.rows] = render_band(band, band.values, header.width, band.rows)
        if band.holes is not None:
            holes[band.y0 : band.y0 + band.rows] = band.holes
    if bands and bands[0].residual is not None:
        image = decode_residual_layer(header, bands)
    return to_samples(image, holes, header)


def to_samples(image: np.ndarray, holes: np.ndarray, header: Header) -> np.ndarray:
    """The decoded integers in the header's sample type, holes filled with NDAT."""
    if header.sample_type == 6:
        # §4.10: keys back to binary32 bits; holes get NDAT's bits, payload and all
        keys = image.astype(np.uint64)
        if header.step is not None:  # §4.10.1: whole numbers of a step, not keys
            offset, scale = header.step
            bits = (offset + scale * image.astype(np.float64)).astype(np.float32).view(np.uint32)
        else:
            bits = np.where(keys >> 31, keys ^ 0x80000000, ~keys & 0xFFFFFFFF).astype(np.uint32)
        if header.nodata is not None:
            bits[holes] = binary32_bits(header.nodata)
        out = bits.view(np.float32)
        return out[:, :, 0] if not header.channel_axis else out
    if header.sample_type == 2:
        out = (header.offset + header.scale * image.astype(np.float64)).astype(np.float32)
    elif header.sample_type in SIGNED:
        info = np.iinfo(SIGNED[header.sample_type])
        out = np.clip(image + int(header.offset), info.min, info.max).astype(SIGNED[header.sample_type])
    else:
        out = image.astype(np.uint8 if header.sample_type == 0 else np.uint16)
    if header.nodata is not None:
        out[holes] = header.nodata
    return out[:, :, 0] if header.channels == 1 and not header.channel_axis else out


# ---------------------------------------------------------------- §4.8 the residual layer


class RangeDecoder:
    """§4.8.2: LZMA's binary range decoder with 16-bit probabilities."""

    def __init__(self, data: bytes) -> None:
        self.data, self.at, self.range = data, 0, 0xFFFFFFFF
        self.code = 0
        for _ in range(4):
            self.code = (self.code << 8) | self.byte()

    def byte(self) -> int:
        if self.at >= len(self.data):
            raise DecodeError("RESD: the coded bytes end early")
        self.at += 1
        return self.data[self.at - 1]

    def bit(self, model: list[int] | None) -> int:
        """A bit with model [p, p', n] (updated), or a raw bit (None)."""
        p = 32768 if model is None else (model[0] + model[1]) >> 1
        bound = (self.range >> 16) * p
        if self.code < bound:
            self.range, bit = bound, 0
        else:
            self.code, self.range, bit = self.code - bound, self.range - bound, 1
        while self.range < 1 << 24:
            self.range = (self.range << 8) & 0xFFFFFFFF
            self.code = ((self.code << 8) | self.byte()) & 0xFFFFFFFF
        if model is not None:
            s = min((model[2] + 2).bit_length() - 1, 8)
            f = min(s, 4)
            model[0] = model[0] - (model[0] >> f) if bit else model[0] + ((65536 - model[0]) >> f)
            model[1] = model[1] - (model[1] >> s) if bit else model[1] + ((65536 - model[1]) >> s)
            model[2] = min(model[2] + 1, 255)
        return bit


def residual_bucket(v: int) -> int:
    """§4.8.3: 0, then 1, 2, 3-4, 5-8, ... up to 11."""
    return 0 if v == 0 else min(1 + (v - 1).bit_length(), 11)


def sign(v: int) -> int:
    return (v > 0) - (v < 0)


def binary32_bits(value: float) -> int:
    """§4.10: the bits a hole decodes to from the NDAT value."""
    (bits,) = struct.unpack("<Q", struct.pack("<d", value))
    if math.isnan(value):
        return ((bits >> 32) & 0x80000000) | 0x7F800000 | ((bits >> 29) & 0x7FFFFF)
    return struct.unpack("<I", struct.pack("<f", value))[0]  # rounded to nearest, ties to even


def read_residual(rc: RangeDecoder, nodes: list[list[int]], sign_model: list[int]) -> int:
    """§4.8.4: a unary token, its sign and raw low bits (39 nodes, or 71 in a plane
    of binary32 keys, §4.10)."""
    t = 0
    while t < len(nodes) and rc.bit(nodes[t]):
        t += 1
    negative = t > 0 and rc.bit(sign_model)
    if t < 16:
        m = t
    else:
        b = 5 + (t - 16) // 2
        m = (1 << (b - 1)) | (((t - 16) & 1) << (b - 2))
        for k in range(b - 3, -1, -1):
            m |= rc.bit(None) << k
    return -m if negative else m


class ResidualPlane:
    """One channel's models and last coded row (levels and residuals), kept from band
    to band (§4.8.1)."""

    def __init__(self, width: int, nodes: int = 39) -> None:
        self.tokens = [[[32768, 32768, 0] for _ in range(nodes)] for _ in range(3888)]
        self.interp_tokens = [[[32768, 32768, 0] for _ in range(nodes)] for _ in range(32)]
        self.interp_signs = [[32768, 32768, 0] for _ in range(32)]
        self.signs = [[32768, 32768, 0] for _ in range(9)]
        self.above: list[int] | None = None  # None: the image's first row comes next
        self.above_residuals = [0] * width

    def decode_rows(self, rc: RangeDecoder, rows: int, width: int, holes: np.ndarray, top_level: int) -> list[list[int]]:
        out = []
        for y in range(rows):
            up, up_r = self.above, self.above_residuals
            cur, res = [0] * width, [0] * width
            for x in range(width):
                if holes[y, x]:
                    cur[x] = cur[x - 1] if x > 0 else (up[x] if up is not None else 0)
                    continue
                if up is not None:
                    n = up[x]
                    ne = up[x + 1] if x + 1 < width else n
                    w, nw = (cur[x - 1], up[x - 1]) if x > 0 else (n, n)
                elif x > 0:
                    w = n = nw = ne = cur[x - 1]
                else:
                    w = n = nw = ne = 0
                lo, hi = min(w, n), max(w, n)
                pred = lo if nw >= hi else hi if nw <= lo else w + n - nw
                g = abs(ne - n) + abs(n - nw) + abs(nw - w)
                signs = 9 * (sign(ne - n) + 1) + 3 * (sign(n - nw) + 1) + sign(nw - w) + 1
                rw = res[x - 1] if x > 0 else 0
                rn = up_r[x] if up is not None else 0
                rnw = up_r[x - 1] if up is not None and x > 0 else 0
                rne = up_r[x + 1] if up is not None and x + 1 < width else 0
                activity = abs(rw) + abs(rn) + (abs(rnw) + abs(rne)) // 2
                nodes = self.tokens[324 * residual_bucket(activity) + 12 * signs + residual_bucket(g)]
                r = read_residual(rc, nodes, self.signs[3 * (sign(rw) + 1) + sign(rn) + 1])
                level = pred + r
                if not 0 <= level <= top_level:
                    raise DecodeError(f"RESD: level {level} outside 0..{top_level}")
                cur[x], res[x] = level, r
            out.append(cur)
            self.above, self.above_residuals = cur, res
        return out

    def interpolate(self, rc: RangeDecoder, rows: int, width: int, holes: np.ndarray, e: int, top: int) -> list[list[int]]:
        """§4.8.5: the band's samples by hierarchical interpolation, then the MED state
        its last row leaves."""
        v = [[0] * width for _ in range(rows)]
        step = 2 * e + 1

        def visit(y: int, x: int, pred: int, t: int) -> None:
            if holes[y, x]:
                v[y][x] = pred
                return
            q = read_residual(rc, self.interp_tokens[min(t, 31)], self.interp_signs[min(t, 31)])
            v[y][x] = min(max(pred + q * step, 0), top)

        s = 1
        while 2 * s < max(rows, width):
            s *= 2
        prev = (top + 1) // 2
        for y in range(0, rows, s):
            for x in range(0, width, s):
                visit(y, x, prev, 0)
                prev = v[y][x]
        t = 1
        while s > 1:
            k = s // 2
            for y in range(0, rows, s):
                for x in range(k, width, s):
                    visit(y, x, (v[y][x - k] + v[y][x + k]) // 2 if x + k < width else v[y][x - k], t)
            for y in range(k, rows, s):
                for x in range(0, width, k):
                    visit(y, x, (v[y - k][x] + v[y + k][x]) // 2 if y + k < rows else v[y - k][x], t + 1)
            s, t = k, t + 2
        above = list(self.above) if self.above is not None else [0] * width
        for x in range(width):
            if not holes[rows - 1, x]:
                above[x] = (v[rows - 1][x] + e) // step
            elif x > 0:
                above[x] = above[x - 1]
        self.above, self.above_residuals = above, [0] * width
        return v


def decode_residual_layer(header: Header, bands: list[Band]) -> np.ndarray:
    """§4.8: the image's samples (height x width x channels, before §4.4's mapping)
    from every band's RESD chunk."""
    width, channels, top = header.width, header.channels, header.layer_top
    image = np.zeros((header.height, width, channels), np.int64)
    planes = [ResidualPlane(width, 71 if header.sample_type == 6 else 39) for _ in range(channels)]
    bound = None
    for band in bands:
        payload = band.residual
        if len(payload) < 12:
            raise DecodeError("RESD: shorter than its fixed fields")
        y0, rows, predictor, count, e = struct.unpack_from("<IIBBH", payload)
        emitted = band.rows if band.y0 + band.rows == header.height else band.rows - 1
        if (y0, rows) != (band.y0, emitted):
            raise DecodeError(f"RESD: {rows} rows from {y0}, its band emits {emitted} from {band.y0}")
        if predictor not in (0, 1):
            raise UnsupportedError(f"RESD: predictor {predictor}")
        if count != channels or e > top or (bound is not None and e != bound) or (e and header.sample_type == 6):
            raise DecodeError("RESD: channels or bound do not match the image")
        bound = e
        step = 2 * e + 1
        holes = band.holes if band.holes is not None else np.zeros((band.rows, width), bool)
        rc = RangeDecoder(payload[12:])
        for c, plane in enumerate(planes):
            if rows == 0:
                continue
            if predictor == 1:
                image[y0 : y0 + rows, :, c] = np.array(plane.interpolate(rc, rows, width, holes, e, top), np.int64)
                continue
            levels = plane.decode_rows(rc, rows, width, holes, (top + e) // step)
            image[y0 : y0 + rows, :, c] = np.minimum(np.array(levels, np.int64).reshape(rows, width) * step, top)
        if rc.at != len(rc.data):
            raise DecodeError("RESD: bytes left over after the coded samples")
    return image


def main(argv: list[str]) -> int:
    """`reference_decoder.py in.atm out.npy`: the decoded image as a NumPy file."""
    if len(argv) != 3:
        print("usage: reference_decoder.py in.atm out.npy", file=sys.stderr)
        return 2
    source, target = argv[1], argv[2]
    try:
        if os.path.exists(target) and os.path.samefile(source, target):
            raise DecodeError("the output would overwrite the input")
        with open(source, "rb") as f:
            image = decode(f.read())
        # Written beside the target and renamed over it, so that an interrupted run
        # leaves no half-written file under the name asked for.
        partial = f"{target}.partial-{os.getpid()}"
        try:
            with open(partial, "wb") as f:
                np.save(f, image)
            os.replace(partial, target)
        finally:
            if os.path.exists(partial):
                os.remove(partial)
    except (OSError, DecodeError) as exc:
        print(f"reference_decoder: {source}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))


# ---------------------------------------------------------------- §4.11 the HOLE chunk


def parse_hole(data: bytes, header: Header) -> tuple[int, int, np.ndarray]:
    """§4.11: (y0, rows, holes) with holes a rows x width bool array, each pixel's bit
    range-decoded (§4.8.2) with the model its twelve-pixel context picks."""
    r = Reader(data, "HOLE")
    y0, rows = r.u32(), r.u32()
    width = header.width
    if rows < 1 or y0 + rows > header.height:
        raise DecodeError(f"HOLE: rows {y0}..{y0 + rows - 1} in an image of {header.height} rows")
    coded = data[8:]
    try:
        rc = RangeDecoder(coded)
        models = [[32768, 32768, 0] for _ in range(4096)]
        m = np.zeros((rows, width), bool)

        def bit(x: int, y: int) -> int:
            return int(0 <= x < width and y >= 0 and m[y, x])

        for y in range(rows):
            for x in range(width):
                c = (bit(x - 1, y) | bit(x - 2, y) << 1 | bit(x - 3, y) << 2 | bit(x - 4, y) << 3
                     | bit(x - 2, y - 1) << 4 | bit(x - 1, y - 1) << 5 | bit(x, y - 1) << 6
                     | bit(x + 1, y - 1) << 7 | bit(x + 2, y - 1) << 8
                     | bit(x - 1, y - 2) << 9 | bit(x, y - 2) << 10 | bit(x + 1, y - 2) << 11)
                m[y, x] = rc.bit(models[c])
    except DecodeError as exc:
        raise DecodeError(f"HOLE: {exc}") from None
    if rc.at != len(coded):
        raise DecodeError(f"HOLE: {len(coded) - rc.at} coded bytes left after the last pixel")
    return y0, rows, m
