"""The `atm` codec for zarr format 3 arrays, as their serializer (array -> bytes).

    import zarr
    from codec.zarr3 import ATM
    z = zarr.create_array(store, shape=dem.shape, chunks=(1024, 1024), dtype=dem.dtype,
                          serializer=ATM(max_error=0.5), compressors=None)

The array metadata names it `numcodecs.atm` (zarr's name for a numcodecs codec); the
`zarr.codecs` entry point lets zarr open such arrays without an import. The settings
are those of codec.numcodecs.ATM, which does the work.
"""

from __future__ import annotations

from zarr.codecs.numcodecs._codecs import _NumcodecsArrayBytesCodec


class ATM(_NumcodecsArrayBytesCodec, codec_name="atm"):
    """codec.numcodecs.ATM as a zarr 3 array-to-bytes codec (points, quality,
    max_error, max_rms, lossless, nodata, precision)."""
