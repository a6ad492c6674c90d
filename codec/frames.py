"""Zstandard frames as .atm stores them (format_spec/ATM.md §4.2 and §4.6-4.7): every
frame declares its decompressed size, which is checked against a limit before any
memory is allocated for it."""

from __future__ import annotations

import zstandard

from . import limits
from .errors import CorruptError, LimitError

#: Compression level of every frame the encoder writes.
ZSTD_LEVEL = 19


def compressor() -> zstandard.ZstdCompressor:
    """A compressor for the encoder's frames. zstandard's compressors are not safe to
    share between threads, so each call gets its own (making one costs about 20 us,
    little beside a level-19 frame)."""
    return zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True)


def compress(data: bytes) -> bytes:
    """One zstd frame holding `data`, its size declared."""
    return compressor().compress(data)


#: A part shorter than this shares its block with the next part (the last with the one
#: before): a block's own entropy tables cost more than such a part can save.
SMALL_PART = 64

#: zstd parameters tried for each MESH payload: a strategy and a minimum match length,
#: the rest as level 19 sets them for the payload's size. Level 19's own (btultra2,
#: matches of 3 bytes or more) spend short matches on the varint streams, whose literals
#: its entropy coder would code better: longer minimum matches give 0.5-4 % smaller
#: files on the corpus, while level 19's own still win on some small meshes (by 2 % on
#: the README's 320x240 scene at quality 80). The decoder is unaffected: every choice
#: is an ordinary frame.
PARAMETERS = (
    (zstandard.STRATEGY_BTULTRA2, 3),  # level 19's own
    (zstandard.STRATEGY_BTULTRA2, 6),
    (zstandard.STRATEGY_BTOPT, 4),
)


#: How a large field's trial is sampled: this many evenly spaced pieces of this many
#: bytes. On the position fields of SRTM float and synthetic DEMs at max_error 0.5-50
#: (10 encodes, fields of 90-640 kB) it chose the order the whole fields' frames choose
#: but in 4 close calls, which cost 10-111 bytes (at most 0.12 % of a file); 32 pieces
#: chose as they do every time but the two trials then took longer than the MESH frame
#: itself (0.7 s against 0.46 s on SRTM at max_error=2); 4 pieces of 16 KiB chose
#: wrongly on SRTM at 2 (718 bytes, 0.6 %).
TRIAL_PIECES, TRIAL_PIECE = 16, 4096


def trial_size(data: bytes) -> float:
    """About the size of `data`'s zstd frame, to choose between ways of writing a field:
    that of a level-19 frame of it, or for a field longer than TRIAL_PIECES pieces of
    TRIAL_PIECE bytes, of those pieces evenly spaced, scaled to the whole (two level-19
    trials of a 640 kB field took 0.5-0.8 s)."""
    sample = _sample(data)
    return len(compress(sample)) * len(data) / len(sample)


def _sample(data: bytes) -> bytes:
    """TRIAL_PIECES evenly spaced pieces of TRIAL_PIECE bytes of `data` (all of it if
    it is not longer)."""
    if len(data) <= TRIAL_PIECES * TRIAL_PIECE:
        return data
    step = (len(data) - TRIAL_PIECE) // (TRIAL_PIECES - 1)
    return b"".join(data[i * step : i * step + TRIAL_PIECE] for i in range(TRIAL_PIECES))


def _compressors(size: int, strategy: int | None = None) -> list[zstandard.ZstdCompressor]:
    """A compressor per entry of PARAMETERS, for a payload of `size` bytes; strategy:
    instead of each entry's own (its minimum match kept), for a quick trial."""
    return [
        zstandard.ZstdCompressor(
            compression_params=zstandard.ZstdCompressionParameters.from_level(
                ZSTD_LEVEL, source_size=size, write_content_size=True, strategy=own if strategy is None else strategy,
                min_match=min_match,
            )
        )
        for own, min_match in PARAMETERS
    ]


def _blocks(zc: zstandard.ZstdCompressor, parts: list[bytes], cuts: set[int]) -> bytes:
    """One frame holding the parts, a block ending after each part whose index is in
    `cuts`."""
    co = zc.compressobj(size=sum(len(p) for p in parts))
    out = []
    for i, part in enumerate(parts):
        out.append(co.compress(part))
        if i in cuts:
            out.append(co.flush(zstandard.COMPRESSOBJ_FLUSH_BLOCK))
    out.append(co.flush())
    return b"".join(out)


#: A payload of at least this many bytes is compressed twice, with LARGE's parameters
#: and blocks that merge small parts, and the smaller frame kept: a level-19 frame of
#: a float DEM's 1.6 MB mesh takes about 0.4 s, and the nine candidates took a quarter
#: of a max_error encode. On large payloads (corpus at quality 50/70, SRTM float and
#: synthetic DEMs at max_error 0.5-50, Kinect and TUM depth and SRTM float at E = 0.1-2 %
#: of the range, mesh only) the smaller of the two is the smallest of the nine or within
#: 0.69 % of it (median 0.00 %); either alone loses up to 5.7 % (level 19's own on the
#: DEMs, minimum match 6 on TUM's depth); a choice by a sample's frames up to 2.8 %.
#: Below this size the search costs a few milliseconds and gains up to 3 %.
SEARCH_BELOW = 1 << 16
#: The parameters (indices into PARAMETERS) tried from SEARCH_BELOW on.
LARGE = (0, 1)
#: From TRIAL_FROM bytes (below SEARCH_BELOW) fewer level-19 frames are made: the
#: optimal parser of btultra2/btopt is what a frame costs (a trial at a lower search
#: depth costs as much), and the nine took 6-9 ms of a 60 ms encode of a 512² photo at
#: 2.8 % vertices. Level 19's own parameters (PARAMETERS[0]: matches of 3 bytes, which
#: no quick strategy finds, 15-19 % smaller on RGB meshes) are made in both block
#: layouts; of the others (TRIED) a quick TRIAL_STRATEGY frame of each layout ranks
#: them and the first is made. On 50 payloads of 4-64 KiB (gray corpus at 1/2.8/6 %
#: vertices and quality 30-80, RGB at 256-768² and quality 40-80, range data meshed
#: and under max_error) the smallest of the three is 0.015 % larger in all than the
#: smallest of the nine, at most 0.20 % (coins at 2.8 %, 9 B); the quick frames alone
#: chose up to 19 % worse on RGB. Smaller payloads (a quick trial lost up to 4 % there)
#: keep the whole search, which costs little at their size.
TRIAL_FROM = 4096
TRIAL_STRATEGY = zstandard.STRATEGY_DFAST
TRIED = (1, 2)
# From TRIAL_FROM bytes on, level 19's own parameters are made in one layout, a block
# a part, not also in the merged one: on 43 payloads of 4-64 KiB (the
# profile_encode --hash set, the corpus at 6 % and quality 30/80, RGB at quality 40/80
# and 2.8 %, TUM and Kinect depth at 1/2.8 %, SRTM float at max_error 2) the other
# layout's frame never won (0 bytes moved), and it was a third of the frames' time
# (a 512² photo's ~1 ms of ~3.4). Of 13 more encodes (range data, RGB, 2048², 867,748
# bytes) one moved: camera at 2048² in 256-row bands, +12 bytes (0.015 %).


# `own` False (codec.meshcode.own_parameters_pay: a mesh with walls) leaves that frame
# out, half the level-19 work of such a payload (a 512² encode's 1.2-2.3 ms): on 28
# payloads of 5-55 kB with walls (the gray corpus at 1/2.8 %, the disparity map and
# camera at 6 %, RGB photos at 1/2.8 %, Kinect, TUM and SRTM at 1/2.8 %, 256² camera at
# quality 40-80 and coffee at 40) it won once, TUM depth at 2.8 % by 30 bytes (0.23 %);
# without walls (RGB at quality 40/60) it won all 5.
# Nor do such payloads get quick frames of TRIED's second parameters (btopt, matches of
# 4 bytes): on the 39 payloads of 4-64 kB with walls in 45 encodes (corpus at 1/2.8/6 %,
# Kinect, TUM, SRTM and float disparity at 1/2.8 %, RGB at 1/2.8 % and 256² q40/60,
# bands, 2048², max_error) the quick frames never ranked them first (0 bytes moved),
# and they were half the quick frames' time (0.4 ms of the disparity map's encode).
TRIED_WITHOUT_OWN = (1,)


def compress_parts(parts: list[bytes], own: bool = True) -> bytes:
    """One zstd frame holding the parts one after another: the smallest, over the
    parameter sets of PARAMETERS, of a plain frame, one that ends a block after each
    part, and one that does so except after (or, for the last, before) parts of fewer
    than SMALL_PART bytes (from TRIAL_FROM bytes on, level 19's own parameters in the
    block-a-part layout, unless `own` is False, and of the others only the one a quick
    trial ranks first; from
    SEARCH_BELOW bytes on, only the last layout, with LARGE's parameters). Each block has its own entropy tables, which suits parts
    whose numbers have different statistics (5-7 % smaller for a large mesh); a small
    mesh does better with shared tables. Ties go to the earlier candidate, so the
    choice, like each frame, depends on the parts (and `own`) alone."""
    whole = b"".join(parts)
    every = set(range(len(parts) - 1))
    merged = every - {i for i, p in enumerate(parts[:-1]) if len(p) < SMALL_PART}
    if parts and len(parts[-1]) < SMALL_PART:
        merged.discard(len(parts) - 2)
    if len(whole) >= SEARCH_BELOW:
        compressors = _compressors(len(whole))
        return min((_blocks(compressors[k], parts, merged) for k in LARGE), key=len)
    layouts = [None] + ([every] if len(parts) >= 2 else []) + ([merged] if len(parts) >= 2 and merged != every else [])
    full = _compressors(len(whole))
    if len(whole) >= TRIAL_FROM:
        # level 19's own parameters in its block layouts, and of the others the one
        # whose quick frame is smallest (ties to the earlier); the smallest of these
        quick = _compressors(len(whole), TRIAL_STRATEGY)
        tried = [(k, cuts) for k in (TRIED if own else TRIED_WITHOUT_OWN) for cuts in layouts]
        sizes = [len(_frame(quick[k], whole, parts, cuts)) for k, cuts in tried]
        k, cuts = tried[sizes.index(min(sizes))]
        ranked = _frame(full[k], whole, parts, cuts)
        if not own:
            return ranked
        # level 19's own parameters in the layout of a block a part (ONE_LAYOUT)
        return min([_frame(full[0], whole, parts, layouts[1] if len(layouts) > 1 else None), ranked], key=len)
    return min((_frame(zc, whole, parts, cuts) for zc in full for cuts in layouts), key=len)


def _frame(zc: zstandard.ZstdCompressor, whole: bytes, parts: list[bytes], cuts: set[int] | None) -> bytes:
    """A plain frame of `whole` (cuts None), or one of its parts with blocks ending
    after those in `cuts`."""
    return zc.compress(whole) if cuts is None else _blocks(zc, parts, cuts)


def declared_size(frame: bytes, what: str) -> int:
    """The decompressed size a zstd frame declares (nothing is decompressed)."""
    try:
        size = zstandard.frame_content_size(frame)
    except zstandard.ZstdError as exc:
        raise CorruptError(f"{what} is not a zstd frame: {exc}") from None
    if size < 0:
        raise CorruptError(f"{what}'s zstd frame does not declare its size")
    return size


def head(frame: bytes, n: int, what: str) -> bytes:
    """The first n bytes of a frame's data (or all, if fewer), decompressing no more
    than the blocks that hold them. In a decompressor of its own: a stream read left
    unfinished changes what a reused one says of a later damaged frame (a
    codec.Decoder's error would then depend on the files before)."""
    try:
        with zstandard.ZstdDecompressor().stream_reader(frame) as reader:
            return reader.read(n)
    except zstandard.ZstdError as exc:
        raise CorruptError(f"{what} does not decompress: {exc}") from None


def decompressor() -> zstandard.ZstdDecompressor:
    """A decompressor for one reader to own and reuse (not to share between threads)."""
    return zstandard.ZstdDecompressor()


def frame_length(frame: bytes, what: str) -> int:
    """The stored length of the zstd frame at the start of `frame`, from its header and
    block headers (RFC 8878 §3.1.1): python-zstandard decompresses the first frame and
    ignores what follows it, while ATM.md §4 makes a payload exactly one frame."""
    try:
        at = zstandard.frame_header_size(frame)
    except zstandard.ZstdError as exc:
        raise CorruptError(f"{what} is not a zstd frame: {exc}") from None
    checksum = 4 if frame[4] & 0x04 else 0  # Content_Checksum_flag of the descriptor
    while True:
        if at + 3 > len(frame):
            raise CorruptError(f"{what}'s zstd frame ends inside a block header")
        block = int.from_bytes(frame[at : at + 3], "little")
        kind, size = (block >> 1) & 3, block >> 3
        at += 3 + (1 if kind == 1 else size)  # an RLE block stores its one byte
        if block & 1:
            return at + checksum


def decompress(frame: bytes, limit: int, what: str, dctx: zstandard.ZstdDecompressor | None = None,
               *, one_frame: bool = False, size: int | None = None) -> bytes:
    """The data of one zstd frame that declares a size of at most `limit` bytes; dctx:
    the caller's own decompressor to reuse; one_frame: the caller has checked that the
    frame fills `frame` (frame_length), which is then not walked again; size: the
    frame's declared_size, when the caller has read it."""
    if size is None:
        size = declared_size(frame, what)
    if size > min(limit, limits.MAX_PAYLOAD_BYTES):
        raise LimitError(
            f"{what} would decompress to {size:,} bytes, more than its image can need "
            "(a decompression bomb?)"
        )
    try:
        data = (dctx or zstandard.ZstdDecompressor()).decompress(frame, max_output_size=max(size, 1))
    except zstandard.ZstdError as exc:
        raise CorruptError(f"{what} does not decompress: {exc}") from None
    if len(data) != size:
        raise CorruptError(f"{what} decompresses to {len(data)} bytes, not the {size} declared")
    end = len(frame) if one_frame else frame_length(frame, what)
    if end != len(frame):
        raise CorruptError(f"{what} has {len(frame) - end:,} bytes after its zstd frame (ATM.md §4: one frame)")
    return data
