"""Whole images: an array in, .atm bytes (or the mesh alone) out, through the same
band pipeline as codec.StreamEncoder (codec.pipeline)."""

from __future__ import annotations

import io

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


def encode(image, settings: Settings, mask=None) -> bytes:
    """Encode an image as .atm bytes, band by band; same image and settings give the
    same bytes. mask: H x W booleans, True where the image has no data. A bound is met
    by the residual layer unless residual=False (codec.representation), in one encode;
    only residual='auto' encodes twice, to keep the smaller."""
    if settings.residual == "auto":
        # the mesh alone is kept on a tie: it is then within the bound too
        mesh = _encode(image, settings.replace(residual=False), mask)
        layered = _encode(image, settings.replace(residual=True), mask)
        return layered if len(layered) < len(mesh) else mesh
    return _encode(image, settings, mask)


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
