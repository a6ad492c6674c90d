"""What the fuzzers run on each input: every public way of reading .atm bytes."""

from __future__ import annotations

import io

import numpy as np

import codec


def run_one(data: bytes) -> bool:
    """Read `data` as `codec.info`, `codec.StreamDecoder` and `codec.decode` do; only
    codec.ATMError may escape, and what decodes must agree with the header. Returns
    whether the whole file decoded."""
    try:
        codec.info(data)
    except codec.ATMError:
        pass
    rows_seen = 0
    bands = []
    try:
        dec = codec.StreamDecoder(io.BytesIO(data))
        for y0, rows in dec:
            if y0 != rows_seen or rows.shape[1:] != dec.shape[1:] or rows.dtype != dec.dtype:
                raise AssertionError(f"band at row {y0} of shape {rows.shape} after {rows_seen} rows")
            rows_seen += len(rows)
            bands.append(rows)
    except codec.ATMError:
        pass
    try:
        image = codec.decode(data)
    except codec.ATMError:
        return False
    info = codec.info(data)
    expected = (info["height"], info["width"]) + ((info["channels"],) if info["channels"] > 1 else ())
    # a gray file with an `axis` chunk decodes as (H, W, 1) (ATM.md §4.9)
    if image.shape not in (expected, expected + (1,) * (info["channels"] == 1)) or rows_seen != info["height"]:
        raise AssertionError(f"decoded shape {image.shape}, header says {expected}")
    if not isinstance(image, np.ndarray):
        raise AssertionError("decode did not return an array")
    # codec.decode renders small bands a group at a time: the pixels must be each band's
    if not np.array_equal(np.concatenate(bands), image, equal_nan=image.dtype.kind == "f"):
        raise AssertionError("bands rendered together differ from each band rendered alone")
    if max(image.shape[:2]) > GL_DIFFERENTIAL_SIDE and _gl_available():
        # wide and large images: triangles far beyond a GL tile (the differential target)
        if not np.array_equal(codec.decode(data, backend="gl"), image):
            raise AssertionError("the GL decoder differs from the CPU decoder")
    return True


#: Decoded images with a side longer than this are also decoded with GL and compared.
GL_DIFFERENTIAL_SIDE = 2048


def _gl_available() -> bool:
    from codec import decoder_gl

    return decoder_gl.available()
