"""Whole images: an array in, .atm bytes (or the mesh alone) out, through the same
band pipeline as codec.StreamEncoder (codec.pipeline)."""

from __future__ import annotations

import io
import math

import numpy as np

from . import container, integers, lossless_float, quantise
from .errors import OptionError
from .image import as_image
from .mesh import Mesh
from .mesher import builder
from .pipeline import default_points
from .settings import Settings


def build_mesh(image, settings: Settings) -> Mesh:
    """Mesh a whole image (H x W gray or H x W x 3 RGB, uint8 or uint16) in one piece
    with the settings' mesher and its options (the band pipeline's other stages do
    not run: no quantisation, no refinement to a bound)."""
    img = as_image(image)
    height, width = img.shape[:2]
    points = default_points(width, height) if settings.points is None else settings.points
    return builder(settings.mesher)(img, min(points, width * height), **settings.mesher_options()).mesh


#: Encodes at most this many layer bounds when `max_rms` sets a residual layer's bound.
RMS_SEARCH = 6


def encode(image, settings: Settings, mask=None) -> bytes:
    """Encode an image as .atm bytes, band by band; same image and settings give the
    same bytes. mask: H x W booleans, True where the image has no data."""
    if settings.residual == "auto":
        # the mesh alone is kept on a tie: it is then within the bound too
        mesh = encode(image, settings.replace(residual=False), mask)
        layered = encode(image, settings.replace(residual=True), mask)
        return layered if len(layered) < len(mesh) else mesh
    if settings.residual and settings.max_rms is not None and settings.max_error is None:
        return _layer_under_rms(image, settings, mask)
    return _encode(image, settings, mask)


def _layer_under_rms(image, settings: Settings, mask) -> bytes:
    """A residual layer whose decoded RMS is within max_rms, measured: the layer's
    bound E starts at max_rms (every sample within E, so the RMS is too) and widens
    while the decoded RMS stays within max_rms, since the RMS of a layer of bound E
    is well under E (about E / sqrt(3) on noisy data, less on smooth data). The
    fewest bytes among the encodes that meet max_rms are kept; the first always does."""
    from .stream import decode_all

    target = float(settings.max_rms)
    img = np.asarray(image)
    whole = img.dtype.kind in "uib"
    valid = np.ones(img.shape[:2], bool)
    if img.dtype.kind == "f":
        valid &= np.isfinite(img) if img.ndim == 2 else np.isfinite(img).all(axis=-1)
    if mask is not None:
        valid &= ~np.asarray(mask, bool)
    if settings.nodata is not None and not np.isnan(settings.nodata):
        valid &= (img != settings.nodata) if img.ndim == 2 else (img != settings.nodata).any(axis=-1)

    def rms(data: bytes) -> float:
        decoded, _ = decode_all(io.BytesIO(data))
        diff = decoded.astype(np.float64).reshape(valid.shape + (-1,))[valid] - \
            img.astype(np.float64).reshape(valid.shape + (-1,))[valid]
        return float(np.sqrt((diff**2).mean(axis=0)).max()) if diff.size else 0.0

    best = _encode(image, settings, mask)
    got = rms(best)
    if got <= 0:
        got = target / 4  # exact at this bound: try a wider one
    met, missed = target, None  # the largest max_error known to meet target, the least known not to
    for _ in range(RMS_SEARCH - 1):
        bound = met * min(target / got, 4.0) if missed is None else (met + missed) / 2
        if whole:
            # integer samples: the layer's bound is floor(max_error), so step by whole levels
            bound = float(max(math.floor(bound), math.floor(met) + 1))
            if missed is not None and bound >= missed:
                break
        elif bound <= met * 1.001 or missed is not None and missed - met < max(1e-9, 0.02 * met):
            break
        data = _encode(image, settings.replace(max_rms=None, max_error=bound), mask)
        got = rms(data)
        if got <= target:
            met = bound
            if len(data) < len(best):
                best = data
        else:
            missed = bound
    return best


def _encode(image, settings: Settings, mask=None) -> bytes:
    from .stream import StreamEncoder

    img = as_image(image, allow_nan=True)
    axis = img.ndim == 2 and np.ndim(image) == 3  # H x W x 1, kept in the file (ATM.md §4.9)
    height, width = img.shape[:2]
    holes = None
    if mask is not None:
        holes = np.asarray(mask, dtype=bool)
        if holes.shape != (height, width):
            raise OptionError(f"mask must have shape {(height, width)}, not {holes.shape}")
        if img.dtype.kind != "f" and settings.nodata is None:
            settings = settings.replace(nodata=0)
    if img.dtype.kind == "f" and settings.lossless:
        img, settings = lossless_float.settle(img, holes, settings)
    if img.dtype.kind == "f":
        # the header carries nodata and the quantisation: both come from the data here
        if settings.nodata is None:
            hidden = ~np.isfinite(img) if holes is None else ~np.isfinite(img) | holes
            settings = settings.replace(nodata=quantise.hole_value([img[hidden]]))
        if settings.value_range is None:
            nodata = quantise.check_nodata(settings.nodata)
            valid = img if holes is None else img[~holes]
            settings = settings.replace(value_range=quantise.data_range([valid], nodata))
    elif integers.is_signed(img.dtype) and settings.value_range is None:
        valid = img if holes is None else img[~holes]
        settings = settings.replace(value_range=integers.value_range([valid], settings.nodata))
    out = io.BytesIO()
    enc = StreamEncoder(
        out, width, height, dtype=img.dtype, channels=1 if img.ndim == 2 else img.shape[2], settings=settings,
        channel_axis=axis,
    )
    enc.write(img, holes=holes)
    enc.close()
    return out.getvalue()


def pack(m: Mesh) -> bytes:
    """Encode an existing mesh (validated first) as .atm bytes."""
    return container.pack(m)
