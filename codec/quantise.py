"""Float samples (e.g. elevations in metres) as 16-bit integers with a scale and offset.

value = offset + scale * q, q in 0..65535. The quantisation error, at most scale / 2
plus float32 rounding, is part of every error bound the user states in data units:
`integer_bounds` turns those into bounds on q that refinement then guarantees.

What the format can carry is checked here, before anything is written: every level must
be a finite float32 (ATM.md §4.4: |offset| + 65535 scale <= the largest float32), and a
value range taken from the data must not be stretched by one extreme value (typically an
unflagged nodata value such as GDAL's -3.4e38) so far that all other values fall into a
single level. The fix named is to pass that value as nodata.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .errors import ATMError, OptionError

LEVELS = 65535
STORAGE = np.dtype(np.uint16)
#: The largest finite float32: no decoded value, and no nodata value, may exceed it.
F32_MAX = float(np.finfo(np.float32).max)
#: Where float32 rounding starts to give infinity (F32_MAX plus half its spacing).
F32_ROUNDS_TO_INF = 2.0**128 - 2.0**103
#: Half the spacing of float32's subnormals: the rounding error of a decoded value near 0.
F32_HALF_TINY = 2.0**-150


@dataclass(frozen=True)
class Quantiser:
    """offset + scale * q; `top` is the largest value the encoder accepts (the declared
    range's upper end; a decoder, which needs no bound, may use the largest q's)."""

    offset: float
    scale: float
    top: float | None = None

    def quantise(self, values: np.ndarray) -> np.ndarray:
        hi = self.top if self.top is not None else self.offset + self.scale * LEVELS
        v = values.astype(np.float64)
        if v.size and (v.min() < self.offset or v.max() > hi):
            raise ATMError(f"a value lies outside the declared range {self.offset:g} .. {hi:g}")
        return np.rint((v - self.offset) / self.scale).astype(STORAGE)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        return (self.offset + self.scale * q.astype(np.float64)).astype(np.float32)

    def ulp(self) -> float:
        """The largest float32 rounding error of a decoded value."""
        hi = self.top if self.top is not None else self.offset + self.scale * LEVELS
        return max(abs(self.offset) * 2.0**-24, (abs(hi) + self.scale) * 2.0**-24, F32_HALF_TINY)

    def integer_bounds(self, max_rms: float | None, max_error: float | None,
                       quantisation_rms: float) -> tuple[float | None, float | None]:
        """Bounds in q units such that the decoded floats meet the bounds in data units:
        |f - decoded| <= |f - (offset + scale q)| + scale |q - q'| + float32 rounding."""
        rms_q = err_q = None
        if max_error is not None:
            err_q = math.floor((max_error - self.scale / 2 - self.ulp()) / self.scale)
            if err_q < 0:
                raise OptionError(
                    f"max_error {max_error:g} is finer than the quantisation step {self.scale:g} allows; "
                    + self._finer()
                )
        if max_rms is not None:
            rms_q = (max_rms - quantisation_rms - self.ulp()) / self.scale
            if rms_q < 0:
                raise OptionError(
                    f"max_rms {max_rms:g} is below the quantisation error ({quantisation_rms:g}); "
                    + self._finer()
                )
        return rms_q, err_q

    def _finer(self) -> str:
        """How to get a finer step: a smaller precision, unless it is already the finest
        that 65,536 levels over the value range allow."""
        if self.top is None or self.scale * LEVELS > (self.top - self.offset) * (1 + 1e-9):
            return "give a smaller precision"
        return (
            f"that is the finest step for the value range {self.offset:g} .. {self.top:g}: narrow "
            "the range (if its end is a value that marks missing data, pass it as nodata)"
        )


def step_for_error(lo: float, hi: float, max_error: float, slack: int) -> float | None:
    """The quantisation step that leaves the mesh `slack` levels of a float image's
    max_error (values lo..hi): the widest step s with floor((max_error - s/2 -
    rounding) / s) = slack, so that the mesh's bound in levels is `slack` (0: every
    level exact, as a step of 2 max_error). None if 65,536 levels of that step cannot
    span lo..hi (then the finest step is the best there is)."""
    # float32 rounding of the decoded values, bounded from above for any step up to
    # 2 max_error (Quantiser.ulp with the largest top)
    rounding = max(abs(lo), abs(hi) + 2 * max_error) * 2.0**-24 * 1.001 + F32_HALF_TINY
    step = (max_error - rounding) / (slack + 0.5)
    if not step > 0 or step * LEVELS < (hi - lo) or abs(lo) + LEVELS * step > F32_MAX:
        return None
    return step


def plan(lo: float, hi: float, precision: float | None = None) -> Quantiser:
    """A quantiser for values in lo..hi: step `precision` if given (it must fit 65,536
    levels), otherwise the finest step that does. Refused (OptionError) where the levels
    would leave float32's range, which the format forbids."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise OptionError(f"value range {lo!r} .. {hi!r} is not a finite range")
    span = hi - lo
    if precision is None:
        # a constant image is exact at any step; a tiny one keeps every bound reachable
        step = span / LEVELS if span > 0 else min(max(abs(lo), 1.0) * 2.0**-30, (F32_MAX - abs(lo)) / LEVELS)
    else:
        if isinstance(precision, bool) or not isinstance(precision, numbers.Real) or not precision > 0:
            raise OptionError(f"precision must be a number > 0, not {precision!r}")
        finest = span / LEVELS
        if precision < finest * (1 - 1e-12):
            raise OptionError(
                f"precision {precision:g} needs {span / precision:,.0f} levels for the range "
                f"{lo:g} .. {hi:g}; at most {LEVELS + 1:,} fit: use a precision of {finest:.3g} or more"
            )
        step = float(precision)
    top = abs(lo) + LEVELS * step
    if step > 0 and top <= F32_MAX:
        return Quantiser(float(lo), float(step), float(hi))
    if precision is not None and abs(lo) + span <= F32_MAX:
        raise OptionError(
            f"precision {precision:g} is too coarse: the {LEVELS + 1:,} levels from {lo:g} would reach "
            f"{top:.9g}, beyond the largest float32 ({F32_MAX:.9g}); give a precision of at most "
            f"{(F32_MAX - abs(lo)) / LEVELS:.3g}"
        )
    extreme = lo if abs(lo) >= abs(hi) else hi
    if abs(extreme) >= F32_ROUNDS_TO_INF:
        raise OptionError(
            f"the value {extreme:g} is beyond float32's range, which .atm decodes to; if it "
            "marks missing data, set those samples to NaN (holes), otherwise scale the data"
        )
    cause = (
        f"the values {lo:g} .. {hi:g} need levels up to {top:.9g}"
        if step > 0
        else f"the value {lo:.9g} leaves no room for a level step below float32's largest"
    )
    raise OptionError(
        f"{cause}, beyond the largest float32 ({F32_MAX:.9g}) that .atm can store; if {extreme:g} "
        f"marks missing data, pass it as nodata (--nodata {shortest(extreme)}), otherwise narrow the range"
    )


def shortest(x: float) -> str:
    """`x` in the fewest digits that give it back, as float32 where it is one (a value
    from float32 data, to be typed as --nodata)."""
    if abs(x) > F32_MAX:
        return repr(float(x))
    return str(np.float32(x)) if float(np.float32(x)) == x else repr(float(x))


def check_nodata(nodata) -> float | None:
    """A float image's nodata value as stored (ATM.md §4.5): NaN, ±infinity or a value
    float32 can hold, since hole pixels decode to it as float32."""
    if nodata is None:
        return None
    if isinstance(nodata, bool) or not isinstance(nodata, numbers.Real):
        raise OptionError(f"nodata must be a number, not {nodata!r}")
    value = float(nodata)
    if math.isfinite(value) and abs(value) > F32_MAX:
        if abs(value) >= F32_ROUNDS_TO_INF:
            raise OptionError(f"nodata {value:g} is beyond float32's range, which decoded float data has")
        value = math.copysign(F32_MAX, value)  # as typed from float32's shortest form, 3.4028235e+38
    return value


def hole_value(blocks: Iterable[np.ndarray]) -> float:
    """What hole pixels decode to when no nodata value is given, from the values of the
    holes (non-finite samples and masked ones) in any number of pieces: +inf or -inf when
    every hole holds that value, so that it comes back as it was; otherwise NaN (a file
    has one nodata value)."""
    seen = None
    for at in blocks:
        if not at.size:
            continue
        first = float(at.flat[0])
        if not math.isinf(first) or not (at == first).all() or seen not in (None, first):
            return math.nan
        seen = first
    return math.nan if seen is None else seen


def data_range(blocks: Iterable[np.ndarray], nodata: float | None = None) -> tuple[float, float]:
    """(lowest, highest) finite sample other than `nodata`, over blocks of rows taken one
    at a time ((0, 0) if there is none), checked to be storable: refused (OptionError)
    if it exceeds float32 or if one extreme value stretches it so far that all the other
    values would decode to one level, as an unflagged nodata value such as -3.4e38 does."""
    lo, lo2, hi, hi2 = math.inf, math.inf, -math.inf, -math.inf  # lo2: the next value above lo
    for block in blocks:
        v = np.asarray(block)
        v = v[np.isfinite(v)]
        if nodata is not None and not math.isnan(nodata):
            v = v[v != nodata]
        if not v.size:
            continue
        bmin, bmax = float(v.min()), float(v.max())
        above, below = v[v > bmin], v[v < bmax]
        low = sorted({lo, lo2, bmin, float(above.min()) if above.size else math.inf})
        high = sorted({hi, hi2, bmax, float(below.max()) if below.size else -math.inf}, reverse=True)
        lo, lo2 = low[0], low[1] if len(low) > 1 else math.inf
        hi, hi2 = high[0], high[1] if len(high) > 1 else -math.inf
    if lo > hi:
        return 0.0, 0.0
    q = plan(lo, hi)
    for extreme, rest in ((lo, (lo2, hi)), (hi, (lo, hi2))):
        if rest[0] < rest[1] and q.quantise(np.array(rest))[0] == q.quantise(np.array(rest))[1]:
            raise OptionError(
                f"the value {extreme:g} stretches the value range to {lo:g} .. {hi:g}, so that all other "
                f"values ({rest[0]:g} .. {rest[1]:g}) fall within one quantisation step ({q.scale:.3g}) "
                f"and would decode as one value; if {extreme:g} marks missing data, pass it as nodata "
                f"(--nodata {shortest(extreme)}), otherwise give value_range and precision yourself"
            )
    return lo, hi
