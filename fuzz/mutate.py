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
KNOWN_TYPES = [b"AHDR", b"MESH", b"AEND", b"tEXt", b"ZZZZ", b"mEta"]
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


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One structure-aware mutation of an .atm file."""
    parts = split(data)
    if parts is None or rng.random() < 0.05:
        return mutate_bytes(data, rng)
    head, chunks = parts
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
