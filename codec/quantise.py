"""Float samples (e.g. elevations in metres) as 16-bit integers with a scale and offset.

value = offset + scale * q, q in 0..65535. The quantisation error, at most scale / 2
plus float32 rounding, is part of every error bound the user states in data units:
`integer_bounds` turns those into bounds on q that refinement then guarantees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import ATMError, OptionError

LEVELS = 65535
STORAGE = np.dtype(np.uint16)


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
        return max(abs(self.offset), abs(hi) + self.scale) * 2.0**-24

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
                    "give a smaller precision"
                )
        if max_rms is not None:
            rms_q = (max_rms - quantisation_rms - self.ulp()) / self.scale
            if rms_q < 0:
                raise OptionError(
                    f"max_rms {max_rms:g} is below the quantisation error ({quantisation_rms:g}); "
                    "give a smaller precision"
                )
        return rms_q, err_q


def plan(lo: float, hi: float, precision: float | None = None) -> Quantiser:
    """A quantiser for values in lo..hi: step `precision` if given (it must fit 65,536
    levels), otherwise the finest step that does."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise OptionError(f"value range {lo!r} .. {hi!r} is not a finite range")
    span = hi - lo
    # a constant image is exact at any step; a tiny one keeps every bound reachable
    finest = span / LEVELS if span > 0 else max(abs(lo), 1.0) * 2.0**-30
    if precision is None:
        return Quantiser(float(lo), float(finest), float(hi))
    if isinstance(precision, bool) or not isinstance(precision, (int, float)) or not precision > 0:
        raise OptionError(f"precision must be a number > 0, not {precision!r}")
    if precision < finest * (1 - 1e-12):
        raise OptionError(
            f"precision {precision:g} needs {span / precision:,.0f} levels for the range "
            f"{lo:g} .. {hi:g}; at most {LEVELS + 1:,} fit: use a precision of {finest:.3g} or more"
        )
    return Quantiser(float(lo), float(precision), float(hi))
