"""Lossless float data: every valid sample decodes to the same binary32 bits.

Three routes, the cheapest first:

- **Exact steps** (`exact_step`): many float rasters are whole numbers times a step
  (an SRTM DEM as float, depths in millimetres as metres). When offset + scale * q,
  as ATM.md §4.4 decodes it, gives every valid sample's exact bits for whole q in
  0..65535, the file is an ordinary `sample_type` 2 file whose residual layer codes
  q exactly (§4.8 with E = 0): checked sample by sample before it is chosen.
- **Exact steps in 32 bits** (`sample_type` 6 with a STEP chunk, ATM.md §4.10.1):
  the same test with q up to 2^32 - 1, for steps no finer than the binary32 spacing of
  the largest value (centimetres over more than 655 m); the layer codes q.
- **Binary32 keys** (`sample_type` 6, ATM.md §4.10): otherwise each sample's bits are
  mapped to an unsigned 32-bit key that orders like the values (`keys`), and the
  residual layer codes the keys exactly in wide planes. -0.0, infinities, subnormals
  and NaNs of any payload are samples like any other; holes are the pixels whose bits
  equal the hole value's (`hole_bits`), which decode to those bits.

The stored mesh is in every route a `sample_type` 2 preview over the finite values.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from . import quantise
from .errors import OptionError, UnsupportedError

#: The residual layer's samples in `sample_type` 6: keys of binary32 bits, or whole
#: numbers of a STEP chunk's step (ATM.md §4.10.1).
KEY_STORAGE = np.dtype(np.uint32)
#: The largest whole number of steps a STEP chunk's layer holds.
WIDE_LEVELS = 0xFFFFFFFF
_SIGN = np.uint32(0x80000000)
#: At most this many candidate steps are tried (each on PROBE samples first, which
#: rejects a wrong one in microseconds; few distinct values leave many candidates).
STEP_TRIALS = 256
#: Candidates are first checked on this many samples spread over the image.
PROBE = 4096


def keys(values: np.ndarray) -> np.ndarray:
    """The order-preserving uint32 key of each binary32 (ATM.md §4.10): the bits with
    the sign bit set for a positive sign, all bits inverted for a negative one."""
    bits = np.ascontiguousarray(values, np.float32).view(np.uint32)
    return np.where(bits & _SIGN, ~bits, bits | _SIGN)


def floats(key: np.ndarray) -> np.ndarray:
    """The binary32 values of keys (the inverse of `keys`)."""
    k = np.asarray(key).astype(np.uint32)
    return np.ascontiguousarray(np.where(k & _SIGN, k ^ _SIGN, ~k)).view(np.float32)


def hole_bits(nodata: float) -> int:
    """The binary32 bits a `sample_type` 6 hole decodes to from the NDAT value
    (ATM.md §4.10): a NaN keeps its sign and the top 23 bits of its significand, so
    any binary32 NaN survives the trip through binary64; any other value is rounded
    to nearest, ties to even."""
    if math.isnan(nodata):
        b64 = struct.unpack("<Q", struct.pack("<d", nodata))[0]
        return int(((b64 >> 32) & 0x80000000) | 0x7F800000 | ((b64 >> 29) & 0x7FFFFF))
    return int(np.array(nodata, np.float32).view(np.uint32))


def nodata_of_bits(bits: int) -> float:
    """The binary64 NDAT value whose holes decode to these binary32 bits."""
    if bits & 0x7F800000 == 0x7F800000 and bits & 0x7FFFFF:
        b64 = ((bits & 0x80000000) << 32) | (0x7FF << 52) | ((bits & 0x7FFFFF) << 29)
        return struct.unpack("<d", struct.pack("<Q", b64))[0]
    return float(np.array(bits, np.uint32).view(np.float32))


def as_binary32(image: np.ndarray) -> np.ndarray:
    """float32 (or float16, widened exactly) as it is; float64 only when every
    sample is a binary32 value (NaNs aside), else UnsupportedError."""
    if image.dtype == np.float32:
        return image
    narrow = image.astype(np.float32)
    if image.dtype.itemsize > 4:
        wide = narrow.astype(image.dtype)
        lost = (wide != image) & ~np.isnan(image)
        if lost.any():
            where = tuple(int(i) for i in np.argwhere(lost)[0])
            raise UnsupportedError(
                f"lossless {image.dtype} data must hold binary32 values (.atm stores float32 exactly); "
                f"the sample at {where} is {float(image[where])!r}: convert to float32 first if that is acceptable"
            )
    return narrow


def common_nan(values: np.ndarray) -> int | None:
    """The bits of the most common NaN among `values` (binary32), None if none is."""
    bits = values.view(np.uint32)
    nan = bits[(bits & 0x7F800000 == 0x7F800000) & (bits & 0x7FFFFF != 0)]
    if not nan.size:
        return None
    found, counts = np.unique(nan, return_counts=True)
    return int(found[np.argmax(counts)])


def _decodes_to(offset: float, scale: float, q: np.ndarray) -> np.ndarray:
    """What ATM.md §4.4 decodes q to, as bits (the codec's own dequantise)."""
    return quantise.Quantiser(offset, scale).dequantise(q).view(np.uint32)


def _fits(values: np.ndarray, offset: float, scale: float, levels: int = quantise.LEVELS) -> np.ndarray | None:
    """The q (0..levels) that decode to exactly `values` (binary32) at this offset and
    scale, or None if some sample has none."""
    q = np.rint((values.astype(np.float64) - offset) / scale)
    if q.size and (q.min() < 0 or q.max() > levels):  # rint gives -0.0, not below 0, for a start just above
        return None
    q = q.astype(quantise.STORAGE if levels <= quantise.LEVELS else KEY_STORAGE)
    if not np.array_equal(_decodes_to(offset, scale, q), values.view(np.uint32)):
        return None
    return q


def _candidates(values: np.ndarray, levels: int) -> list[float]:
    """Steps worth trying, coarsest first: round numbers (1, 2 or 5 times a power of
    ten, powers of two) up to the smallest gap between the distinct values, and that
    gap itself."""
    distinct = np.unique(values.astype(np.float64))
    if len(distinct) < 2:
        return [1.0]
    gap = float(np.diff(distinct).min())
    span = float(distinct[-1] - distinct[0])
    finest = span / levels
    # binary32 rounding moves the gap between two values by up to a spacing of each
    slack = float(np.abs(distinct).max()) * 2.0**-22
    round_steps = {m * 10.0**k for k in range(-12, 13) for m in (1, 2, 5)} | {2.0**k for k in range(-40, 41)}
    steps = sorted((s for s in round_steps if finest * (1 - 1e-9) <= s <= gap + slack), reverse=True)
    if finest <= gap:
        steps.append(gap)
    return steps[:STEP_TRIALS]


def exact_step(values: np.ndarray, levels: int = quantise.LEVELS) -> tuple[float, float] | None:
    """(offset, scale) under which every one of `values` (binary32, the valid
    samples, none NaN or infinite) decodes exactly from a whole q in 0..levels, the
    coarsest such scale of those tried; None if there is none."""
    values = np.ascontiguousarray(values, np.float32).ravel()
    if not values.size:
        return None
    offset = float(values.min())
    if offset == 0:
        offset = 0.0  # -0.0 as the offset would still decode q = 0 to +0.0
    if quantise.F32_MAX < abs(offset):
        return None
    probe = values[:: max(1, len(values) // PROBE)]
    for scale in _candidates(values, levels):
        # the lowest value as binary32 lies off the grid of a decimal step (0.501 is
        # 0.50099998...): the grid's own point is tried first
        grid = math.floor(offset / scale) * scale
        grid = grid if grid <= offset else grid - scale  # no sample below the range's low end
        for start in dict.fromkeys((grid, offset)):
            if abs(start) + levels * scale > quantise.F32_MAX:
                continue
            if _fits(probe, start, scale, levels) is not None and _fits(values, start, scale, levels) is not None:
                return start + 0.0, scale
    return None


def preview_range(values: np.ndarray) -> tuple[float, float]:
    """A value range for the `sample_type` 6 preview mesh over the finite valid
    samples: the whole range if ATM.md §4.4 can quantise it, else the 0.1..99.9 %
    percentiles (the preview only shows the surface; the layer holds the values)."""
    finite = values[np.isfinite(values)].astype(np.float64)
    if not finite.size:
        return 0.0, 0.0
    for lo, hi in ((finite.min(), finite.max()), tuple(np.percentile(finite, [0.1, 99.9]))):
        try:
            quantise.plan(float(lo), float(hi))
        except OptionError:
            continue
        return float(lo), float(hi)
    return 0.0, 0.0


def check_steps(values: np.ndarray, q: np.ndarray, holes: np.ndarray, quant: quantise.Quantiser, row0: int) -> None:
    """Lossless with a precision: every valid sample must decode from its q to its own
    bits, else ATMError naming the first that does not (rows from image row row0)."""
    from .errors import ATMError

    exact = as_binary32(values).view(np.uint32)
    wrong = (_decodes_to(quant.offset, quant.scale, q) != exact) & ~holes
    if wrong.any():
        y, x = (int(i) for i in np.argwhere(wrong)[0])
        raise ATMError(
            f"lossless: the sample at row {row0 + y}, column {x} ({float(values[y, x])!r}) is not "
            f"{quant.offset!r} + a whole number of steps of {quant.scale!r} exactly; leave precision out "
            "to store the float bits as they are"
        )


def settle(image: np.ndarray, mask: np.ndarray | None, settings):
    """(binary32 image, settings) for a lossless encode of a whole float image, with
    the options of `options_for` set."""
    image = as_binary32(image)
    return image, settings.replace(**options_for(image, mask, settings.nodata, settings.value_range, settings.precision))


def options_for(image: np.ndarray, mask: np.ndarray | None, nodata, value_range, precision) -> dict:
    """The nodata, value_range and precision of a lossless encode of a whole binary32
    image: the exact steps of `exact_step` when every valid sample and every hole
    decode to their own bits through them, else binary32 keys (a value_range for the
    preview, precision None). Holes: `mask`, the nodata value, and without one the
    non-finite samples (exact steps) or the most common NaN's bits (keys, where the
    other non-finite samples are kept as samples). A precision given is kept: the
    stream encoder then checks every sample against it."""
    bits = image.view(np.uint32)
    masked = np.zeros(image.shape, bool) if mask is None else mask
    nodata = quantise.check_nodata(nodata)
    if precision is None:
        for levels in (quantise.LEVELS, WIDE_LEVELS):
            steps = _exact_steps(image, masked, nodata, levels)
            if steps is not None:
                return steps
    if nodata is None:
        nan = common_nan(image[~masked])
        nodata = math.nan if nan is None else nodata_of_bits(nan)
    holes = masked | (bits == hole_bits(nodata))
    if precision is not None:
        valid = image[~(holes | ~np.isfinite(image))]
        found = (float(valid.min()), float(valid.max())) if valid.size else (0.0, 0.0)
        return dict(nodata=nodata, value_range=value_range or found)
    return dict(nodata=nodata, value_range=value_range or preview_range(image[~holes]))


def _exact_steps(image: np.ndarray, masked: np.ndarray, nodata: float | None, levels: int) -> dict | None:
    """The settings of the exact-steps route (`settle`) in 16 bits (`sample_type` 2)
    or 32 (levels WIDE_LEVELS: `sample_type` 6 with a STEP chunk), None if it does
    not apply."""
    holes = masked | ~np.isfinite(image)
    if nodata is not None and not math.isnan(nodata):
        holes |= np.where(holes, False, image) == nodata  # NaNs out: a signalling one would raise
    found = exact_step(image[~holes], levels)
    if found is None:
        return None
    offset, scale = found
    largest = float(np.abs(image[~holes]).max(initial=0))
    if levels > quantise.LEVELS and scale < largest * 2.0**-23:
        # finer than the largest values' own spacing: their q would waste low bits that
        # the keys do not (the DEM resampled off its grid: 439,229 against 433,148 B)
        return None
    if nodata is None:
        unmasked = image[holes & ~masked]
        nan = common_nan(unmasked)
        nodata = quantise.hole_value([unmasked]) if nan is None else nodata_of_bits(nan)
    valid = image[~holes]
    top = float(valid.max()) if valid.size else offset
    # the steps of a wide search may still fit 16 bits, and wide_steps then writes
    # sample_type 2, whose holes follow its rule, not §4.10's
    sixteen = levels <= quantise.LEVELS or _sixteen_bits(offset, top, scale)
    # every hole not masked by the caller must decode to its own bits, as the
    # decoder fills it (sample_type 2: NumPy's binary64 -> binary32 conversion, which
    # quiets a signalling NaN; 6: ATM.md §4.10's bits h, which keep it)
    filled = np.empty(1, np.float32)
    with np.errstate(invalid="ignore"):
        filled[0] = nodata
    bits = int(filled.view(np.uint32)[0]) if sixteen else hole_bits(nodata)
    if (image[holes & ~masked].view(np.uint32) != bits).any():
        return None
    if sixteen:
        try:
            quantise.plan(offset, top, precision=scale)
        except OptionError:
            return None
    return dict(nodata=nodata, value_range=(offset, top), precision=scale)


def wide_steps(settings) -> quantise.Quantiser | None:
    """The STEP chunk's quantiser (ATM.md §4.10.1) of a lossless float encode whose
    precision needs more than 65,536 levels over its value range, else None."""
    if not (settings.lossless and settings.precision is not None and settings.value_range is not None):
        return None
    lo, hi = settings.value_range
    if _sixteen_bits(lo, hi, settings.precision):
        return None  # sample_type 2
    if abs(lo) + WIDE_LEVELS * settings.precision > quantise.F32_MAX or (hi - lo) / settings.precision > WIDE_LEVELS:
        raise OptionError(f"lossless: precision {settings.precision:g} needs more than 2^32 levels, or values "
                          "beyond float32's range, over the value range; leave it out to store the float bits")
    return quantise.Quantiser(float(lo), float(settings.precision), float(hi))


def _sixteen_bits(lo: float, hi: float, precision: float) -> bool:
    """Whether steps of `precision` over lo .. hi fit the 16-bit samples of
    sample_type 2 (quantise.plan's own test)."""
    return precision >= (hi - lo) / quantise.LEVELS * (1 - 1e-12)
