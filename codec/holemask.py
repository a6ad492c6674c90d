"""A band's hole mask in a `HOLE` chunk (ATM.md §4.11): each pixel's bit coded in raster
order by the residual layer's binary range coder, in contexts of twelve neighbouring
bits (codec._mask), as JBIG codes bilevel images.

Sensor depth maps and disparity maps have ragged holes (dropouts along every edge),
whose run lengths zstd codes poorly: there the mask took 12-58 % of the file at
max_error of 0.1-2 % of the range (kinect, tum, the corpus disparity map), and this
coding halves it. DEM voids are few compact blobs, whose runs cost little: the writer
keeps whichever of `MASK` (§4.6) and `HOLE` is shorter for each band.
"""

from __future__ import annotations

import struct

import numpy as np

from .errors import CorruptError
from .native import _mask

#: The chunk's type: critical (an upper-case first letter), as the MASK it stands for.
CHUNK = b"HOLE"
#: y0, rows (the band's, as in MASK).
FIXED = struct.Struct("<II")


def encode(y0: int, holes: np.ndarray) -> bytes:
    """The HOLE payload of a band from row y0 (holes: rows x W booleans)."""
    return FIXED.pack(y0, len(holes)) + _mask.encode(np.ascontiguousarray(holes, np.uint8))


def decode(payload: bytes, where: str, y0: int, width: int, height: int) -> np.ndarray:
    """The rows x W hole mask of a HOLE payload for the band that starts at row y0 of a
    width x height image; CorruptError naming `where` for anything wrong, each field
    checked before the kernel runs."""
    if len(payload) < FIXED.size:
        raise CorruptError(f"{where} has {len(payload)} bytes, fewer than its {FIXED.size} fixed ones")
    got_y0, rows = FIXED.unpack_from(payload)
    if got_y0 != y0 or rows < min(2, height) or got_y0 + rows > height:
        raise CorruptError(f"{where} covers rows {got_y0}..{got_y0 + rows - 1}, not a band from row {y0}")
    status, holes = _mask.decode(np.frombuffer(payload, np.uint8, offset=FIXED.size), rows, width)
    if status != _mask.Status.MASK_OK:
        why = {
            _mask.Status.MASK_OVERRUN: "ends before its coded pixels do",
            _mask.Status.MASK_TRAILING: "has bytes after its coded pixels",
        }.get(status, f"cannot be decoded (status {int(status)})")
        raise CorruptError(f"{where} {why}")
    return holes
