"""How an error bound is met: the residual layer (ATM.md §4.8) or the mesh alone, and
the layer's bound E under `max_rms`.

The choice is a rule, not a second encode. `max_error` and `max_rms` get the layer
unless `residual=False`: measured with `benchmarks/range.py`'s images and the corpus
(mesh-only bytes ÷ layer bytes, max_error at 0.1, 0.5, 2 and 5 % of the value range),
the layer is smaller on every one, by 1.07-5.9×: kinect 1.30-2.35, tum 1.67-2.01,
SRTM float 1.46-5.89, corpus disparity 1.36-1.43, camera/coins/moon/text 1.62-3.37,
synthetic range scenes 1.07-4.36 (16-bit) and 1.32-2.32 (8-bit), piecewise-planar
steps 1.60-2.60, a 16-bit plane 1.02; the mesh won only on a constant image (164
against 207 bytes). The layer's encode was also 10-60× quicker. The mesh alone stays
for those who use the mesh itself (`atm mesh`, terrain tiles, codec.build_mesh):
beside a layer the stored mesh is a light preview, not within the bound.

Under `max_rms` the layer's bound E is widened from the first band's samples in one
pass, for each predictor: with MED a stored sample x decodes to
min(floor((x + E) / S) · S, M), S = 2E + 1 (ATM.md §4.8.1), so its RMS at any E is
computed from the samples alone; interpolation (§4.8.5) quantises around its
predictions, so its RMS is measured by coding and decoding the first band's layer at
a few bounds (a bisection; the mesh is made once). The rows the stream has not seen
yet are counted at the worst error E each, so the bound holds on the whole image
(exactly the widest E when the first band is the whole image, as it is up to about a
megapixel). The first band takes the predictor and E that code it in fewer bytes;
later bands may use either, since their samples are counted at E.
"""

from __future__ import annotations

import math

import numpy as np

from . import residual

#: The most layer bounds tried under max_rms (spread evenly over the candidates).
CANDIDATES = 256
#: Candidates go up to this multiple of max_rms: uniform errors over -E..E have an RMS
#: of about E / sqrt(3), and data on few levels can have less.
WIDEST = 4.0


def decoded_error(values: np.ndarray, error: int, top: int) -> np.ndarray:
    """The layer's error (decoded - stored) of stored samples `values` at bound E = error
    (ATM.md §4.8.1), as float64."""
    step = 2 * error + 1
    decoded = np.minimum((values + error) // step * step, top)
    return (decoded - values).astype(np.float64)


def rms_bound(band: np.ndarray, holes: np.ndarray | None, channels: int, max_rms: float, top: int,
              rest: int, cap: int | None = None) -> int:
    """The widest layer bound E (stored units) whose decoded RMS, per channel, is within
    `max_rms` on the image: `band` (rows x W or rows x W x C stored samples, the image's
    first rows; `holes` rows x W booleans or None) measured exactly, and `rest` more
    pixels not yet seen at the worst error E each. `cap`: a bound E may not exceed
    (max_error's, when both are given). At least floor(max_rms), which holds whatever
    the samples."""
    low = min(int(math.floor(max_rms)), top)
    high = min(top, max(low, int(math.floor(WIDEST * max_rms))))
    if cap is not None:
        low, high = min(low, cap), min(high, cap)
    samples = band.reshape(band.shape[0], band.shape[1], channels)
    if holes is not None:
        samples = samples[~holes]
    samples = samples.reshape(-1, channels).astype(np.int64)
    seen = len(samples)
    if seen + rest == 0 or high <= low:
        return low
    # each channel's distinct values and their counts: the error depends on the value alone
    counted = [np.unique(samples[:, c], return_counts=True) for c in range(channels)]
    candidates = np.unique(np.linspace(low, high, min(CANDIDATES, high - low + 1)).astype(np.int64))
    best = low
    for e in candidates.tolist():
        worst = 0.0
        for values, counts in counted:
            squared = float((decoded_error(values, e, top) ** 2 * counts).sum())
            worst = max(worst, (squared + rest * float(e) ** 2) / (seen + rest))
        if worst <= max_rms**2 * (1 - 1e-9):  # a margin for the rounding of a measured RMS
            best = max(best, e)
    return best


#: Bisection steps for interpolation's widest bound under max_rms.
PROBES = 7


def _squared(decoded: np.ndarray, stored: np.ndarray, valid: np.ndarray, channels: int) -> np.ndarray:
    d = (decoded.astype(np.float64).reshape(stored.shape) - stored)[valid]
    return (d**2).sum(axis=0)


def layer_under_rms(rows: np.ndarray, holes: np.ndarray | None, channels: int, storage: np.dtype,
                    max_rms: float, rest: int, cap: int | None = None) -> tuple[int, int]:
    """(E, predictor) for the first band's layer under `max_rms` (stored units): `rows`
    are the stored samples the band's RESD chunk codes (holes: rows x W booleans or
    None) and `rest` the image's pixels after them, counted at error E. The widest E
    each predictor meets max_rms with, then the one whose chunk is shorter."""
    top = int(np.iinfo(storage).max)
    width = rows.shape[1]
    valid = np.ones(rows.shape[:2], bool) if holes is None else ~holes
    seen = int(valid.sum())
    stored = rows.astype(np.float64).reshape(rows.shape[:2] + (channels,))
    med = rms_bound(rows, holes, channels, max_rms, top, rest, cap)
    floor = min(int(math.floor(max_rms)), top if cap is None else min(top, cap))

    def coded(error: int, predictor: int) -> bytes:
        return residual.ResidualEncoder(width, channels, storage, error, (predictor,)).band(0, rows, holes)

    def meets(error: int) -> bytes | None:
        data = coded(error, residual.INTERPOLATION)
        decoded = residual.ResidualDecoder(width, channels, storage).band(data, 0, len(rows), holes, "probe")
        squared = _squared(decoded, stored, valid, channels)
        total = (squared + rest * float(error) ** 2) / max(seen + rest, 1)
        return data if float(total.max()) <= max_rms**2 * (1 - 1e-9) else None

    # interpolation: every sample within floor(max_rms) meets it; bisect above that
    low, high = floor, min(top, max(floor, int(math.floor(WIDEST * max_rms))))
    if cap is not None:
        high = min(high, cap)
    interp = coded(low, residual.INTERPOLATION)
    for _ in range(PROBES):
        if high <= low:
            break
        mid = (low + high + 1) // 2
        data = meets(mid)
        if data is None:
            high = mid - 1
        else:
            low, interp = mid, data
    return (med, residual.MED) if len(coded(med, residual.MED)) <= len(interp) else (low, residual.INTERPOLATION)
