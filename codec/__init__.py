"""The .atm image codec: images as adaptive triangular meshes with explicit walls.

    import codec
    data = codec.encode(image, points=4000)   # bytes
    image2 = codec.decode(data)               # same shape and dtype
    m = codec.build_mesh(image)               # the mesh itself: vertices, triangles, ...

Heavy modules (OpenCV, triangle, OpenGL) load on first use, not at import.
"""

from __future__ import annotations

import io
import os
from typing import NoReturn

import numpy as np

from .errors import (
    ATMError,
    BackendError,
    CorruptError,
    FormatError,
    LimitError,
    OptionError,
    TruncatedError,
    UnsupportedError,
)
from .mesh import Mesh


def __getattr__(name: str):
    # the streaming classes load their dependencies on first use, not at import
    if name in ("StreamEncoder", "StreamDecoder"):
        from . import stream

        return getattr(stream, name)
    raise AttributeError(f"module 'codec' has no attribute {name!r}")

__version__ = "0.1.0"


def encode(
    image: np.ndarray,
    *,
    points: int | None = None,
    quality: int | None = None,
    max_rms: float | None = None,
    max_error: float | None = None,
    band_height: int | None = None,
    mesher: str = "adaptive",
    value_step: int | str = "auto",
    nodata: float | None = None,
    value_range: tuple[float, float] | None = None,
    precision: float | None = None,
    metadata: dict | None = None,
    effort: int | None = None,
    values: str | None = None,
    segment_length: int | None = None,
    segment_error: float | None = None,
    tiles: tuple[int, int] | None = None,
    per_tile: tuple[int, int] | None = None,
    canny: tuple[float, float] | None = None,
    edge_share: float | None = None,
    region_share: float | None = None,
    mask: np.ndarray | None = None,
    **unknown: NoReturn,
) -> bytes:
    """Encode an image as .atm bytes; the same image and options give the same bytes.

    image: H x W (gray) or H x W x 3 (RGB) uint8/uint16, or H x W float (stored as
    16-bit levels; NaN and infinite values are holes). mask: H x W booleans, True where
    the image has no data (integer images: nodata defaults to 0).

    Size: `points` (target vertex count, within 10 %; default 2.8 % of the pixels), or
    a bound that refinement guarantees on the decoded image, per channel: `quality`
    (1..100, like JPEG's: an RMS bound, 100 lossless), `max_rms`, `max_error` (sample
    units; float data: data units). The other options and their defaults:
    codec.settings.Settings, which checks them all (OptionError names a bad one; an
    unknown one is refused with the list of valid ones).
    """
    from . import encoder
    from .settings import Settings

    if unknown:
        Settings.from_options(also=("mask",), **unknown)  # raises, listing the valid options
    settings = Settings.from_options(
        points=points, quality=quality, max_rms=max_rms, max_error=max_error, band_height=band_height,
        mesher=mesher, value_step=value_step, nodata=nodata, value_range=value_range, precision=precision,
        metadata=metadata, effort=effort, values=values, segment_length=segment_length,
        segment_error=segment_error, tiles=tiles, per_tile=per_tile, canny=canny, edge_share=edge_share,
        region_share=region_share,
    )
    return encoder.encode(image, settings, mask)


def build_mesh(image: np.ndarray, *, points: int | None = None, mesher: str = "adaptive", **options) -> Mesh:
    """The mesh the mesher makes of a whole image in one piece: points as for `encode`,
    and the mesher's options (codec.settings.mesher_option_names). With a size bound
    (max_error, max_rms, quality) or samples the file stores with an offset or scale
    (float, signed), it is the mesh `encode` stores, its values in data units."""
    from . import encoder, terrain
    from .settings import Settings, mesher_option_names

    if terrain.needs_encoder(image, options):
        return terrain.build_mesh(image, points=points, mesher=mesher, **options)

    allowed = mesher_option_names(mesher) if isinstance(mesher, str) else ()
    other = sorted(set(options) - set(allowed))
    if other:
        raise OptionError(
            f"build_mesh takes points, mesher and the mesher's options ({', '.join(allowed) or 'none'}), "
            f"not {', '.join(other)}"
        )
    return encoder.build_mesh(image, Settings.from_options(points=points, mesher=mesher, **options))


def decode(data: bytes, *, backend: str = "cpu") -> np.ndarray:
    """Decode .atm bytes to an array of the encoded shape and dtype (float32 for float
    data; hole pixels hold the file's nodata value, NaN for float data).

    backend: "cpu" (exact integer scanline decoder) or "gl" (OpenGL through EGL; the
    same pixels, BackendError where no GL context can be made).
    """
    import io

    from .stream import decode_all

    return decode_all(io.BytesIO(_as_bytes(data)), backend=backend)[0]


def decode_mesh(data: bytes) -> Mesh:
    """Parse .atm bytes into one validated Mesh of the whole image (bands merged)."""
    from . import container
    from .stream import merge_bands

    return merge_bands(container.unpack(_as_bytes(data))[1])


def info(data: bytes) -> dict:
    """Header and mesh statistics of .atm bytes: width, height, dtype, channels, bands,
    vertices, triangles, constraints, bytes, nodata, metadata. Read from the header and
    each band's count fields (checksums and limits checked, no mesh decoded)."""
    from . import container

    data = _as_bytes(data)
    reader = container.Reader(io.BytesIO(data))
    counts = container.summarise(reader)
    header = reader.header
    return {
        "version": header.version,
        "width": header.width,
        "height": header.height,
        "dtype": str(header.dtype),
        "channels": header.channels,
        "bands": counts.bands,
        "vertices": counts.vertices,
        "triangles": counts.triangles,
        "constraints": counts.polylines,
        "bytes": len(data),
        "nodata": header.nodata,
        "metadata": header.metadata or {},
        **_sample_mapping(header),
    }


def _sample_mapping(header) -> dict:
    """How stored 16-bit samples map to values: float data's step (its precision) and
    lowest value, signed integers' offset."""
    from .integers import is_signed

    q = header.quant
    if q is None:
        return {}
    if is_signed(header.dtype):
        return {"offset": int(q.offset)}
    return {"precision": q.scale, "offset": q.offset}


def read(path: str | os.PathLike, *, backend: str = "cpu", metadata: bool = False):
    """Read and decode an .atm file; with metadata=True, return (image, metadata dict)."""
    from .stream import decode_all

    try:
        f = open(path, "rb")
    except OSError as exc:
        raise ATMError(f"cannot read {path}: {exc.strerror}") from None
    with f:
        image, meta = decode_all(f, backend=backend)
    return (image, meta) if metadata else image


def write(path: str | os.PathLike, image, *, force: bool = False, **options) -> None:
    """Encode `image` and write it to `path` atomically (options as for `encode`).
    A name with an image extension (x.png, x.tif, ...) is refused unless force=True:
    .atm bytes there would be taken for that image format."""
    from .files import atomic_write, refuse_image_name

    if not force:
        refuse_image_name(path)
    atomic_write(path, encode(image, **options))


def _as_bytes(data) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    raise ATMError(f"expected .atm bytes, got {type(data).__name__}")


__all__ = [
    "ATMError",
    "BackendError",
    "CorruptError",
    "FormatError",
    "LimitError",
    "Mesh",
    "OptionError",
    "StreamDecoder",
    "StreamEncoder",
    "TruncatedError",
    "UnsupportedError",
    "decode",
    "build_mesh",
    "decode_mesh",
    "encode",
    "info",
    "read",
    "write",
]
