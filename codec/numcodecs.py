"""A numcodecs codec (id `atm`): zarr arrays whose chunks are .atm images.

    import zarr
    from codec.numcodecs import ATM
    z = zarr.create_array(store, shape=dem.shape, chunks=(1024, 1024), dtype=dem.dtype,
                          zarr_format=2, compressors=ATM(max_error=0.5))

Registered through the `numcodecs.codecs` entry point, so `numcodecs.get_codec({"id":
"atm", ...})` and zarr (format 2 arrays) find it without an import. Each chunk must be
a 2-D image (or H x W x 3 RGB) of a type .atm stores; float chunks are quantised to 16
bits per chunk (their own value range), so bounds are in data units.
"""

from __future__ import annotations

import numpy as np
from numcodecs.abc import Codec
from numcodecs.compat import ensure_bytes, ndarray_copy

from .errors import OptionError, UnsupportedError


class ATM(Codec):
    """The .atm codec for numcodecs: lossy (`points`, `quality`) or bounded
    (`max_error`, `max_rms`, in sample or data units), or `lossless` (every sample
    exact: integers, and float chunks to their binary32 bits, ATM.md §4.10). `nodata`: samples equal to it are
    holes, kept exactly (NaN always is, in float data). `precision`: float data's
    quantisation step (default: the finest 16 bits allow over each chunk)."""

    codec_id = "atm"

    def __init__(
        self,
        points: int | None = None,
        quality: int | None = None,
        max_error: float | None = None,
        max_rms: float | None = None,
        lossless: bool = False,
        nodata: float | None = None,
        precision: float | None = None,
    ):
        given = [n for n, v in (("points", points), ("quality", quality), ("max_error", max_error), ("max_rms", max_rms)) if v is not None]
        if lossless and given:
            raise OptionError(f"lossless leaves no room for {', '.join(given)}")
        self.points = points
        self.quality = quality
        self.max_error = max_error
        self.max_rms = max_rms
        self.lossless = bool(lossless)
        self.nodata = nodata
        self.precision = precision

    def _options(self, chunk: np.ndarray) -> dict:
        options = {
            k: v
            for k, v in (("points", self.points), ("quality", self.quality), ("max_error", self.max_error),
                         ("max_rms", self.max_rms), ("nodata", self.nodata), ("precision", self.precision))
            if v is not None
        }
        if self.lossless:
            options["lossless"] = True  # the residual layer: exact, and far fewer bytes than a mesh
        if chunk.dtype.kind == "f" and self.nodata is not None and np.isnan(self.nodata):
            del options["nodata"]  # NaN is float data's nodata already
        return options

    def encode(self, buf) -> bytes:
        """The .atm bytes of one chunk (an ndarray: zarr hands chunks over as arrays)."""
        import codec

        chunk = np.asarray(buf)  # an H x W x 1 chunk keeps its axis (ATM.md §4.9)
        if chunk.ndim != 2 and not (chunk.ndim == 3 and chunk.shape[2] in (1, 3)):
            raise UnsupportedError(
                f"the atm codec stores 2-D chunks (or H x W x 3 RGB), not shape {chunk.shape}: "
                "give the array chunks like (1, rows, cols) squeezed to 2-D, e.g. chunk per band"
            )
        return codec.encode(np.ascontiguousarray(chunk), **self._options(chunk))

    def decode(self, buf, out=None) -> np.ndarray:
        """The chunk's samples (into `out` when given, as numcodecs asks)."""
        import codec

        image = codec.decode(ensure_bytes(buf))
        if out is not None:
            return ndarray_copy(image, out)
        return image
