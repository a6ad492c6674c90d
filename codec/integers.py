"""Signed integer samples (int8, int16, int32: most DEMs are int16) stored exactly.

The file keeps them as 16-bit unsigned samples q with a whole-number offset (a QUNT
chunk with scale 1, format_spec/ATM.md sections 4.1 and 4.4): value = offset + q. That
is exact whenever the valid samples span at most 65,536 consecutive values, which every
int8 and int16 image does; an int32 image that spans more is refused with the fix named.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from .errors import OptionError, UnsupportedError
from .quantise import LEVELS, Quantiser

#: AHDR sample_type code of each signed type (ATM.md section 4.1).
SAMPLE_TYPES: Mapping[np.dtype, int] = MappingProxyType({np.dtype(np.int8): 3, np.dtype(np.int16): 4, np.dtype(np.int32): 5})
DTYPES: Mapping[int, np.dtype] = MappingProxyType({code: dtype for dtype, code in SAMPLE_TYPES.items()})

def is_signed(dtype) -> bool:
    """Whether `dtype` is one of the signed integer types .atm stores."""
    return np.dtype(dtype) in SAMPLE_TYPES


def unsupported(dtype) -> UnsupportedError:
    """The error for an integer type .atm does not store, naming the fix."""
    return UnsupportedError(
        f"unsupported pixel type {np.dtype(dtype)}; .atm stores uint8, uint16, int8, int16, int32 and "
        "float samples: convert it with image.astype(np.int32) if its values span at most 65,536 "
        "consecutive integers (stored exactly), else image.astype(np.float32) (stored to a --precision)"
    )


def plan(lo: float, hi: float, dtype) -> Quantiser:
    """The quantiser (offset lo, scale 1) that stores whole numbers lo..hi exactly."""
    dtype = np.dtype(dtype)
    info = np.iinfo(dtype)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo or lo != int(lo) or hi != int(hi):
        raise OptionError(f"value range {lo!r} .. {hi!r} is not a range of whole numbers")
    if lo < info.min or hi > info.max:
        raise OptionError(f"value range {lo:g} .. {hi:g} lies outside {dtype}'s {info.min} .. {info.max}")
    if hi - lo > LEVELS:
        raise UnsupportedError(
            f"the {dtype} values span {int(lo):,} .. {int(hi):,}, {int(hi - lo) + 1:,} values; .atm stores "
            f"at most {LEVELS + 1:,} consecutive integers exactly. Convert the image to float32 "
            "(image.astype(np.float32)) to store it quantised with a --precision, or split its range"
        )
    return Quantiser(float(lo), 1.0, float(hi))


def default_range(dtype) -> tuple[float, float] | None:
    """The whole type's range where it fits 16 bits (int8, int16), else None: a stream
    of int32 rows needs the caller's value_range."""
    info = np.iinfo(np.dtype(dtype))
    return (float(info.min), float(info.max)) if info.max - info.min <= LEVELS else None


def restore(q: np.ndarray, quant: Quantiser, dtype) -> np.ndarray:
    """Decoded samples offset + q in `dtype`, exact (integer arithmetic), clipped to
    the type's range (ATM.md section 4.4)."""
    dtype = np.dtype(dtype)
    info = np.iinfo(dtype)
    values = q.astype(np.int64) + int(quant.offset)
    return np.clip(values, info.min, info.max).astype(dtype)


def check_quant(offset: float, scale: float) -> bool:
    """Whether a QUNT chunk's fields are valid for integer samples: scale exactly 1 and
    a whole-number offset within int32's range."""
    info = np.iinfo(np.int32)
    return scale == 1.0 and math.isfinite(offset) and offset == int(offset) and info.min <= offset <= info.max



def value_range(blocks, nodata: float | None = None) -> tuple[float, float]:
    """(lowest, highest) sample other than `nodata` over blocks of rows taken one at a
    time ((0, 0) if there is none): the offset and top of what the file stores."""
    lo, hi = math.inf, -math.inf
    for block in blocks:
        v = np.asarray(block)
        if nodata is not None:
            v = v[v != nodata]
        if v.size:
            lo, hi = min(lo, float(v.min())), max(hi, float(v.max()))
    return (lo, hi) if lo <= hi else (0.0, 0.0)
