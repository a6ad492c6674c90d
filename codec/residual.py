"""The residual layer (ATM.md §4.8): a band's pixels coded exactly on a grid of step
2E + 1, so that every valid decoded sample is within E of the original (E = 0:
lossless), by construction rather than by refinement.

Each band's RESD chunk codes the rows that band emits (all but its last row, which the
next band emits; all of them in the band that ends the image), with the predictor that
codes it in fewer bytes: MED (as LOCO-I and JPEG-LS) on the levels (x + E) // (2E + 1)
of its decoded causal neighbours, or a hierarchical interpolation (as SZ3) whose
residuals are quantised with step 2E + 1. The residuals go through an adaptive binary
range coder in contexts of neighbouring residuals and the local gradient
(codec._residual). The adaptive state carries from band to band, so a stream holds one
band and the row above it. Holes are skipped: the MASK chunk already gives them exactly. The mesh stays
in the file as what users render; decoders need not render it when this layer is
there, so the CPU and GL backends give the same pixels by construction.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from .errors import CorruptError, OptionError, UnsupportedError
from .native import _residual

#: The chunk's type: critical (an upper-case first letter), as a decoder that skipped
#: it would give the mesh's coarse pixels where the file promises exact ones.
CHUNK = b"RESD"
#: y0, rows, predictor, channels, E (in stored sample units).
FIXED = struct.Struct("<IIBBH")
#: Predictor codes: MED on the levels (ATM.md §4.8.3), hierarchical interpolation
#: (§4.8.5, what smooth data such as elevations favour at coarse bounds).
MED = 0
INTERPOLATION = 1
PREDICTORS = (MED, INTERPOLATION)


#: Vertex density of the mesh stored beside a residual layer, when `points` is not
#: given: the mesh predicts nothing there (benchmarks/range_study.py measured the mesh
#: as a predictor not paying on real range data), so it is a light preview, about a
#: vertex per 64 x 64 pixels. Measured at E = 2 % (tum, kinect, disparity, srtm): the
#: mesh takes 711/715/810/537 bytes at 0.001 and 268/269/293/203 at 0.00025, 2-8 %
#: of the files' totals saved.
PREVIEW_DENSITY = 0.00025


def layer_bound(settings, plan) -> int | None:
    """The bound E in stored sample units if an image with these settings (and this
    pipeline.Plan of them) gets a residual layer, else None: `lossless` (E = 0), or
    `max_error` and/or `max_rms` when settings.layered (float data: the bound left after
    the 16-bit quantisation). Every sample within E gives an RMS within E too, so
    `max_rms` gets E = floor(max_rms) here; the StreamEncoder then widens E from the
    first band's samples (codec.representation)."""
    if settings.lossless:
        # float data: exact on q (precision given: codec.lossless_float's exact steps)
        # or on binary32 keys (exact_floats)
        return 0
    if settings.residual == "auto":
        raise OptionError(
            "residual='auto' compares two encodes of the whole image: give it to codec.encode, "
            "or choose residual=True or False for a stream"
        )
    bounds = [b for b in (plan.bound.max_error, plan.bound.max_rms) if b is not None]
    if not settings.layered or not bounds:
        return None
    return min(int(math.floor(min(bounds))), _top(plan.storage))


def exact_floats(settings, plan) -> bool:
    """Whether the image's layer codes 32-bit samples (`sample_type` 6, ATM.md §4.10:
    binary32 keys, or whole numbers of a STEP chunk's step, which the stream encoder
    takes out of the precision first): lossless float data without a precision (with
    one that 16 bits hold, every sample must be a whole number of steps from the
    range's low end, checked as it is written)."""
    return bool(settings.lossless and plan.dtype.kind == "f" and settings.precision is None)


def mesh_settings(settings, width: int, height: int):
    """The settings of the mesh stored beside a residual layer: no bound of its own
    (the layer meets it), `points` as given or a light preview."""
    points = settings.points or max(4, round(PREVIEW_DENSITY * width * height))
    return settings.replace(lossless=False, residual=False, max_error=None, max_rms=None, points=points)


def covered_rows(mesh_rows: int, last: bool) -> int:
    """How many of a band's rows its residual chunk codes: the rows it emits."""
    return mesh_rows if last else mesh_rows - 1


def step_of(error: int) -> int:
    """The grid step of bound E: the widest that keeps every sample within E."""
    return 2 * error + 1


def _top(storage: np.dtype) -> int:
    return int(np.iinfo(storage).max)


class ResidualEncoder:
    """Codes the residual chunks of one image, band after band (it keeps the adaptive
    state and the last row from one band to the next)."""

    def __init__(self, width: int, channels: int, storage: np.dtype, error: int, predictors: tuple[int, ...] = PREDICTORS):
        storage = np.dtype(storage)
        self.predictors = predictors  # MED alone: its decoded samples depend on E alone (codec.representation)
        if not 0 <= error <= min(_top(storage), 65535) or storage.itemsize > 2 and error:
            raise ValueError(f"a residual bound of {error} does not fit {storage} samples")
        self.width, self.channels, self.storage, self.error = width, channels, storage, int(error)
        self._planes = [_residual.Plane(width, storage.itemsize > 2) for _ in range(channels)]

    def band(self, y0: int, rows: np.ndarray, holes: np.ndarray | None) -> bytes:
        """The RESD payload of image rows y0 .. y0 + len(rows) - 1 (stored samples,
        rows x W or rows x W x C; holes: rows x W booleans or None), with whichever
        predictor codes the band in fewer bytes."""
        n = len(rows)
        samples = rows.astype(np.int64).reshape(n, self.width, self.channels)
        planes = [np.ascontiguousarray(samples[..., c]) for c in range(self.channels)]
        mask = np.zeros((n, self.width), np.uint8) if holes is None else np.ascontiguousarray(holes, np.uint8)
        best = None
        for predictor in self.predictors:
            states = [p.copy() for p in self._planes]
            coded = _residual.encode(states, predictor, planes, mask, self.error, _top(self.storage))
            if best is None or len(coded) < len(best[1]):
                best = (predictor, coded, states)
        predictor, coded, self._planes = best
        return FIXED.pack(y0, n, predictor, self.channels, self.error) + coded


class ResidualDecoder:
    """Decodes the residual chunks of one image, band after band."""

    def __init__(self, width: int, channels: int, storage: np.dtype):
        self.width, self.channels, self.storage = width, channels, np.dtype(storage)
        self._planes = [_residual.Plane(width, self.storage.itemsize > 2) for _ in range(channels)]
        self._error: int | None = None

    def band(self, payload: bytes, y0: int, rows: int, holes: np.ndarray | None, where: str) -> np.ndarray:
        """The stored samples (rows x W, or rows x W x C) of a RESD payload that must
        code `rows` rows from row y0; every field is checked before the kernel runs."""
        if len(payload) < FIXED.size:
            raise CorruptError(f"{where} has {len(payload)} bytes, fewer than its {FIXED.size} fixed ones")
        got_y0, got_rows, predictor, channels, error = FIXED.unpack_from(payload)
        if got_y0 != y0 or got_rows != rows:
            raise CorruptError(f"{where} codes {got_rows} rows from row {got_y0}; its band emits {rows} from row {y0}")
        if predictor not in PREDICTORS:
            raise UnsupportedError(f"{where} uses predictor {predictor}; this codec knows {PREDICTORS}")
        if channels != self.channels:
            raise CorruptError(f"{where} codes {channels} channels; the image has {self.channels}")
        if error > _top(self.storage):
            raise CorruptError(f"{where} has bound {error}, beyond the samples' range 0..{_top(self.storage)}")
        if error and self.storage.itemsize > 2:
            raise CorruptError(f"{where} has bound {error}; exact float samples (sample_type 6) have bound 0")
        if self._error is not None and error != self._error:
            raise CorruptError(f"{where} has bound {error}; the image's earlier bands have {self._error}")
        self._error = error
        mask = np.zeros((rows, self.width), np.uint8) if holes is None else np.ascontiguousarray(holes[:rows], np.uint8)
        if mask.shape != (rows, self.width):
            raise CorruptError(f"{where}: the band's mask covers {mask.shape[0]} rows, not {rows}")
        status, planes = _residual.decode(self._planes, predictor, np.frombuffer(payload, np.uint8, offset=FIXED.size),
                                          mask, error, _top(self.storage))
        codes = _residual.Status
        if status != codes.RESIDUAL_OK:
            why = {
                codes.RESIDUAL_RANGE: "decodes a sample outside the samples' range",
                codes.RESIDUAL_OVERRUN: "ends before its coded samples do",
                codes.RESIDUAL_TRAILING: "has bytes after its coded samples",
            }.get(status, f"cannot be decoded (status {int(status)})")
            raise CorruptError(f"{where} {why}")
        samples = planes[0] if self.channels == 1 else np.stack(planes, axis=-1)
        return samples.astype(self.storage)
