"""A structure-aware mutator for .atm files.

Random bytes almost never get past the signature, the CRCs and zstd. This mutator
understands the container: it edits chunk lengths, types and order, and the fields of
the decompressed MESH payload (counts, coordinates, indices, samples), then usually
recompresses and fixes the CRCs, so that the decoder's validation is what gets tested.
"""

from __future__ import annotations

import random
import struct
import zlib

import zstandard

SIGNATURE = b"\x89ATM\r\n\x1a\n"
KNOWN_TYPES = [b"AHDR", b"MESH", b"AEND", b"tEXt", b"ZZZZ", b"mEta", b"RESD", b"STEP", b"HOLE", b"MASK"]
INTERESTING_U32 = [0, 1, 2, 3, 0x7F, 0xFF, 0x100, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF]


def split(data: bytes) -> tuple[bytes, list[list[bytes]]] | None:
    """(file header, [[type, payload], ...]) of a file whose chunk framing is intact."""
    if len(data) < 10:
        return None
    pos, chunks = 10, []
    while pos + 12 <= len(data):
        length, ctype = struct.unpack_from("<I4s", data, pos)
        if pos + 12 + length > len(data):
            break
        chunks.append([ctype, data[pos + 8 : pos + 8 + length]])
        pos += 12 + length
    return data[:10], chunks


def join(head: bytes, chunks: list[list[bytes]], rng: random.Random) -> bytes:
    out = [head]
    for ctype, payload in chunks:
        crc = zlib.crc32(ctype + payload)
        if rng.random() < 0.03:
            crc ^= 1 << rng.randrange(32)
        length = len(payload)
        if rng.random() < 0.03:
            length = rng.choice(INTERESTING_U32)
        out.append(struct.pack("<I4s", length, ctype) + payload + struct.pack("<I", crc))
    return b"".join(out)


def mutate_bytes(buf: bytes, rng: random.Random) -> bytes:
    """Generic edits: flip, set, insert, delete, overwrite with an interesting integer."""
    b = bytearray(buf)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(5)
        if op == 0 and b:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif op == 1 and b:
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif op == 2:
            i = rng.randrange(len(b) + 1)
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif op == 3 and b:
            i = rng.randrange(len(b))
            del b[i : i + rng.randint(1, 8)]
        elif len(b) >= 4:
            i = rng.randrange(len(b) - 3)
            b[i : i + 4] = struct.pack("<I", rng.choice(INTERESTING_U32))
    return bytes(b)


def mutate_mesh_payload(raw: bytes, rng: random.Random) -> bytes:
    """Edit the decompressed MESH payload: counts first (12 bytes), then anything."""
    b = bytearray(raw)
    if len(b) >= 12 and rng.random() < 0.4:
        field = rng.randrange(3)
        (count,) = struct.unpack_from("<I", b, 4 * field)
        new = rng.choice([count + 1, max(count - 1, 0), count * 2, rng.choice(INTERESTING_U32)])
        struct.pack_into("<I", b, 4 * field, new & 0xFFFFFFFF)
        return bytes(b)
    if len(b) >= 16 and rng.random() < 0.5:
        # an aligned u32 somewhere in the arrays: a coordinate or an index
        i = 12 + 4 * rng.randrange((len(b) - 12) // 4)
        (v,) = struct.unpack_from("<I", b, i)
        struct.pack_into("<I", b, i, rng.choice([v + 1, max(v - 1, 0), v ^ 0xFFFF, 0, rng.randrange(1 << 16)]) & 0xFFFFFFFF)
        return bytes(b)
    return mutate_bytes(bytes(b), rng)


def mutate_residual_payload(raw: bytes, rng: random.Random) -> bytes:
    """Edit a RESD payload (ATM.md §4.8): its fixed fields (y0, rows, predictor,
    channels, bound) or its range-coded bytes, which no CRC inside protects."""
    b = bytearray(raw)
    if len(b) >= 12 and rng.random() < 0.4:
        field = rng.randrange(5)
        at, fmt = [(0, "<I"), (4, "<I"), (8, "<B"), (9, "<B"), (10, "<H")][field]
        (v,) = struct.unpack_from(fmt, b, at)
        top = 0xFF if fmt == "<B" else 0xFFFF if fmt == "<H" else 0xFFFFFFFF
        struct.pack_into(fmt, b, at, rng.choice([v + 1, max(v - 1, 0), 0, top, rng.randrange(top + 1)]) & top)
        return bytes(b)
    if len(b) > 12 and rng.random() < 0.3:
        # cut the coded bytes short, or leave extra behind them
        return bytes(b[: rng.randrange(12, len(b))]) if rng.random() < 0.5 else bytes(b) + bytes(rng.randint(1, 8))
    return mutate_bytes(bytes(b), rng)


def mutate_hole_payload(raw: bytes, rng: random.Random) -> bytes:
    """Edit a HOLE payload (ATM.md §4.11): its fixed fields (y0, rows) or its
    range-coded bits, which no CRC inside protects."""
    b = bytearray(raw)
    if len(b) >= 8 and rng.random() < 0.4:
        at = rng.choice([0, 4])
        (v,) = struct.unpack_from("<I", b, at)
        struct.pack_into("<I", b, at, rng.choice([v + 1, max(v - 1, 0), 0, 1, 0xFFFFFFFF, rng.randrange(1 << 32)]) & 0xFFFFFFFF)
        return bytes(b)
    if len(b) > 8 and rng.random() < 0.3:
        # cut the coded bytes short, or leave extra behind them
        return bytes(b[: rng.randrange(8, len(b))]) if rng.random() < 0.5 else bytes(b) + bytes(rng.randint(1, 8))
    return mutate_bytes(bytes(b), rng)


def _frame(data: bytes) -> bytes:
    return zstandard.ZstdCompressor(level=1, write_content_size=True).compress(data)


def lie_about_size(frame: bytes, rng: random.Random) -> bytes:
    """The frame with its declared content size replaced (a decompression bomb's lie),
    where the size field is 4 or 8 bytes."""
    if len(frame) < 14 or frame[:4] != b"\x28\xb5\x2f\xfd" or frame[4] & 3:
        return frame
    fhd = frame[4]
    width = {2: 4, 3: 8}.get(fhd >> 6)
    if width is None:
        return frame
    at = 5 if fhd & 0x20 else 6
    size = rng.choice([len(frame) * 2000, 1 << 20, (1 << 31) - 1, 0xFFFFFFFF, rng.randrange(1 << 32)])
    return frame[:at] + (size % (1 << 8 * width)).to_bytes(width, "little") + frame[at + width :]


def hostile_metadata(rng: random.Random) -> bytes:
    """JSON text a meta chunk must not carry, or carry only within its limits."""
    k = rng.choice([10, 63, 64, 65, 1000, 100_000])
    return rng.choice([
        b'{"a": ' + b"[" * k + b"]" * k + b"}",
        b'{"a": ' + b'{"b": ' * k + b"1" + b"}" * k + b"}",
        b'{"a": "\\ud800"}', b'{"a": NaN}', b'{"a": Infinity}', b'{"a": 1e999}',
        b'{"a": 1, "a": 2}', b'{"a": "' + b"x" * rng.choice([1000, (1 << 20) - 9, 1 << 20]) + b'"}',
        b'{"a": ' + b"9" * 5000 + b"}", b"[]", b"\xff\xfe",
    ])


def _band(v: list[tuple[int, int]], width: int, rows: int, y0: int, rng: random.Random) -> bytes | None:
    """The MESH chunk payload of a Delaunay band with vertices v, or None."""
    import numpy as np

    from codec import meshcode
    from codec.errors import ATMError
    from codec.mesh import Mesh
    from codec.triangulate import triangulate
    from codec.format_spec import schema

    vertices = np.array(sorted(set(v), key=lambda p: (p[1], p[0])), np.int64)
    try:
        tris = triangulate(vertices)
        values = np.array([rng.randrange(256) for _ in range(len(vertices))], np.uint8)
        fields = meshcode.encode_band(y0, Mesh(vertices, values, tris, width, rows, []))
    except (ATMError, ValueError):
        return None
    return _frame(schema.MeshPayload.build(fields, sample_type=0, channels=1))


def hostile_file(rng: random.Random) -> bytes:
    """A whole file of a class the decoder must refuse or bound: an all-pixel mesh,
    many one-row bands, a wide image with huge triangles (for the GL differential)."""
    from codec.format_spec import schema

    kind = rng.randrange(3)
    if kind == 0:  # every pixel a vertex: zero gaps and samples
        width, height = rng.choice([(64, 64), (300, 200), (1024, 1024)])
        n = width * height
        fields = dict(
            y0=0, rows=height, vertex_count=n, triangle_count=2 * (width - 1) * (height - 1),
            polyline_count=0, polyline_index_count=0, connectivity=1, position_order=0,
            triangle_crc=rng.randrange(1 << 32), sample_step=1, polyline_lengths=b"", polyline_starts=b"",
            polyline_steps=b"", positions=bytes(n + 1), position_bits=b"", samples=bytes(n), triangles=b"",
        )
        bands = [_frame(schema.MeshPayload.build(fields, sample_type=0, channels=1))]
    elif kind == 1:  # many bands of one new row each
        width, height = rng.choice([2, 7, 64]), rng.randint(3, 100)
        bands = [_band([(0, 0), (width - 1, 0), (0, 1), (width - 1, 1)], width, 2, y0, rng) for y0 in range(height - 1)]
    else:  # wide or tall, a few vertices: triangles far larger than a GL tile
        across, length = rng.randint(2, 5), rng.choice([2049, 4097, 20000, 65536])
        width, height = (length, across) if rng.random() < 0.5 else (across, length)
        v = [(0, 0), (width - 1, 0), (0, height - 1), (width - 1, height - 1)]
        v += [(rng.randrange(width), rng.randrange(height)) for _ in range(rng.randint(0, 8))]
        bands = [_band(v, width, height, 0, rng)]
    if any(b is None for b in bands):
        return SIGNATURE + struct.pack("<H", 5)
    chunks = [[b"AHDR", struct.pack("<IIBB", width, height, 0, 1)]] + [[b"MESH", b] for b in bands] + [[b"AEND", b""]]
    return join(SIGNATURE + struct.pack("<H", schema.VERSION), chunks, random.Random(0))


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One structure-aware mutation of an .atm file."""
    parts = split(data)
    if parts is None or rng.random() < 0.05:
        return mutate_bytes(data, rng)
    head, chunks = parts
    choice = rng.random()
    if choice < 0.04:
        return hostile_file(rng)
    if choice < 0.12 and chunks:
        # the new classes: hostile metadata (one chunk, or many of up to 1 MB), a frame
        # that lies about its size
        op = rng.randrange(3)
        at = rng.randrange(1, len(chunks) + 1)
        if op == 0:
            chunks.insert(at, [b"meta", _frame(hostile_metadata(rng))])
        elif op == 1:
            big = _frame(b'{"k": "' + b"a" * rng.choice([1000, (1 << 20) - 9]) + b'"}')
            chunks[at:at] = [[b"meta", big]] * rng.choice([2, 20, 3000])
        else:
            i = rng.randrange(len(chunks))
            chunks[i][1] = lie_about_size(chunks[i][1], rng)
        return join(head, chunks, rng)
    choice = rng.random()
    if chunks and choice < 0.45:
        target = rng.randrange(len(chunks))
        ctype, payload = chunks[target]
        if ctype == b"MESH" and rng.random() < 0.9:
            try:
                # the mutator must not be the one to fall for a bomb
                size = zstandard.frame_content_size(payload)
                raw = zstandard.ZstdDecompressor().decompress(payload) if 0 <= size <= 1 << 20 else None
            except zstandard.ZstdError:
                raw = None
            if raw is not None:
                raw = mutate_mesh_payload(raw, rng)
                payload = zstandard.ZstdCompressor(level=1).compress(raw)
            else:
                payload = mutate_bytes(payload, rng)
        elif ctype == b"RESD" and rng.random() < 0.9:
            payload = mutate_residual_payload(payload, rng)
        elif ctype == b"HOLE" and rng.random() < 0.9:
            payload = mutate_hole_payload(payload, rng)
        elif ctype == b"AHDR" and len(payload) == 10 and rng.random() < 0.7:
            b = bytearray(payload)
            i = rng.choice([0, 4, 8, 9])
            if i < 8:
                struct.pack_into("<I", b, i, rng.choice(INTERESTING_U32 + [100_000, 3, 5, 64]))
            else:
                b[i] = rng.choice([0, 1, 2, 3, 4, 255])
            payload = bytes(b)
        else:
            payload = mutate_bytes(payload, rng)
        chunks[target] = [ctype, payload]
    elif chunks and choice < 0.6:
        i = rng.randrange(len(chunks))
        op = rng.randrange(4)
        if op == 0:
            del chunks[i]
        elif op == 1:
            chunks.insert(rng.randrange(len(chunks) + 1), list(chunks[i]))
        elif op == 2:
            j = rng.randrange(len(chunks))
            chunks[i], chunks[j] = chunks[j], chunks[i]
        else:
            chunks[i][0] = rng.choice(KNOWN_TYPES)
    elif choice < 0.7:
        chunks.insert(rng.randrange(len(chunks) + 1), [rng.choice(KNOWN_TYPES), mutate_bytes(b"", rng)])
    elif choice < 0.8:
        head = SIGNATURE + struct.pack("<H", rng.choice([0, 1, 1, 1, 2, 0xFFFF]))
    else:
        return mutate_bytes(join(head, chunks, rng), rng) if rng.random() < 0.3 else join(head, chunks, rng)[: rng.randrange(10, len(data) + 40)]
    return join(head, chunks, rng)
