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
    image,
    *,
    points: int | None = None,
    mesher: str | None = None,
    band_height: int | None = None,
    **options,
) -> bytes:
    """Encode an H x W (gray) or H x W x 3 (RGB) uint8/uint16 array as .atm bytes.

    points: target vertex count (within 10 %); default 2.8 % of the pixels.
    quality: 1..100, like JPEG's (an RMS bound; 100 is lossless); or
    max_rms / max_error: a bound on the decoded image's RMS / largest error, per
    channel, in sample units, guaranteed by refinement.
    mesher: "adaptive" (default: walls along discontinuities, curvature sampling,
    least-squares values) or "uniform" (the grid baseline); further options go to
    the mesher (see codec.mesher.adaptive.build).
    band_height: rows per band (default: about a megapixel per band); images are coded
    band by band so that StreamEncoder/StreamDecoder can work in bounded memory.
    """
    from . import encoder

    return encoder.encode(
        image,
        points=points,
        mesher=mesher or encoder.DEFAULT_MESHER,
        band_height=band_height,
        **options,
    )


def build_mesh(image, *, points: int | None = None, mesher: str | None = None, **options) -> Mesh:
    """Build the mesh `encode` would store, without packing it. Takes encode's size
    options (points, max_error, max_rms, quality) and its sample types (float and signed
    data give values in data units)."""
    from . import encoder, terrain

    if terrain.needs_encoder(image, options):
        return terrain.build_mesh(image, points=points, mesher=mesher, **options)
    return encoder.mesh(image, points=points, mesher=mesher or encoder.DEFAULT_MESHER, **options)


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
    vertices, triangles, constraints, bytes, nodata, metadata, and for float data its
    precision (the quantisation step; signed integers: offset). Read from the header and
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
