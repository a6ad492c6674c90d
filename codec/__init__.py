"""The .atm image codec: images as adaptive triangular meshes with explicit walls.

    import codec
    data = codec.encode(image, points=4000)   # bytes
    image2 = codec.decode(data)               # same shape and dtype
    m = codec.build_mesh(image)               # the mesh itself: vertices, triangles, ...

Heavy modules (OpenCV, triangle, OpenGL) load on first use, not at import.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
from typing import BinaryIO, NoReturn, Union

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
from .buffers import as_bytes as _as_bytes
from .mesh import Mesh

#: What decode, check, info and decode_mesh take: any object with the buffer protocol.
Buffer = Union[bytes, bytearray, memoryview, np.ndarray, mmap.mmap]


def __getattr__(name: str):
    # the streaming classes load their dependencies on first use, not at import
    if name in ("StreamEncoder", "StreamDecoder"):
        from . import stream

        return getattr(stream, name)
    if name == "Decoder":
        from .decoder import Decoder

        return Decoder
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
    lossless: bool = False,
    residual: bool | str | None = None,
    mask: np.ndarray | None = None,
    **unknown: NoReturn,
) -> bytes:
    """Encode an image as .atm bytes; the same image and options give the same bytes.

    image: H x W (gray) or H x W x 3 (RGB) uint8/uint16, or H x W float (stored as
    16-bit levels; NaN and infinite values are holes). mask: H x W booleans, True where
    the image has no data (integer images: nodata defaults to 0).

    Size: `points` (target vertex count, within 10 %; default 2.8 % of the pixels), or
    a bound that refinement guarantees on the decoded image, per channel: `quality`
    (1..100 on JPEG's scale: an RMS bound at about JPEG's error, 100 lossless), `max_rms`, `max_error` (sample
    units; float data: data units). On float data `max_error` chooses the quantisation
    step (about 2 max_error, each level kept exactly by the mesh); `precision` overrides
    it. `lossless=True`, `max_error` and `max_rms` are met by a residual layer
    (ATM.md §4.8) that holds the bound on every valid sample by construction, with the
    fewest bytes (codec.representation has the measurements), beside a light mesh (a
    preview, not within the bound; with `residual=True`, `points` sets its size); under
    `max_rms` the layer's bound is the widest whose RMS, computed from the samples, is
    within it. Lossless float data keeps every binary32 bit (codec.lossless_float: 16-bit
    steps where the values allow, else ATM.md §4.10's binary32 keys). `residual=False`
    meets the bound with the mesh alone, for those who use
    the stored mesh itself (`atm mesh`, terrain tiles; codec.build_mesh always does);
    `residual="auto"` encodes both and keeps the smaller. The other options and their defaults:
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
        region_share=region_share, lossless=lossless, residual=residual,
    )
    return encoder.encode(image, settings, mask)


def build_mesh(image: np.ndarray, *, points: int | None = None, mesher: str = "adaptive", **options) -> Mesh:
    """The mesh the mesher makes of a whole image in one piece: points as for `encode`,
    and the mesher's options (codec.settings.mesher_option_names). With a size bound
    (max_error, max_rms, quality) or samples the file stores with an offset or scale
    (float, signed), it is the mesh `encode(..., residual=False)` stores (the bound met
    by the mesh itself), its values in data units."""
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


def decode(data: Buffer, *, out: np.ndarray | None = None, backend: str = "cpu") -> np.ndarray:
    """Decode .atm data to an array of the encoded shape and dtype (float32 for float
    data; hole pixels hold the file's nodata value, NaN for float data).

    data: any buffer (bytes, bytearray, memoryview, a numpy uint8 array, an mmap).
    out: an array to fill in place and return, as imagecodecs' decoders take: of the
    decoded dtype and shape; for a gray image (H, W) or (H, W, 1) either way. Without
    `out`, a gray image encoded as (H, W, 1) comes back (H, W, 1) (its file has an `axis`
    chunk, ATM.md §4.9), one encoded as (H, W) comes back (H, W).
    backend: "cpu" (exact integer scanline decoder) or "gl" (OpenGL through EGL; the
    same pixels, BackendError where no GL context can be made).
    Decoding many files: codec.Decoder (one per thread) reuses its working memory.
    """
    from .stream import StreamDecoder, decode_into

    dec = StreamDecoder(io.BytesIO(_as_bytes(data)), backend=backend)
    return decode_into(dec, out)


def check(data: Buffer) -> bool:
    """Whether `data` (any buffer, as for `decode`) starts with the .atm signature."""
    from .format_spec.schema import SIGNATURE

    return _as_bytes(data, len(SIGNATURE)) == SIGNATURE


def decode_mesh(data: Buffer) -> Mesh:
    """Parse .atm bytes into one validated Mesh of the whole image (bands merged). In a
    file with a residual layer (info's `residual`, the default under max_error/max_rms)
    it is a light preview, not within the bound: encode with residual=False for a mesh
    that is."""
    from . import container
    from .stream import merge_bands

    return merge_bands(container.unpack(_as_bytes(data))[1])


def info(data: Buffer) -> dict:
    """Header and mesh statistics of .atm bytes: width, height, dtype, channels, bands,
    vertices, triangles, constraints, bytes, nodata, metadata, residual (the residual
    layer's bound in stored sample units, 0 for lossless; None without a layer). Read from the header and
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
        # the residual layer's bound in stored sample units (0: lossless), None without one
        "residual": counts.residual,
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
    if header.exact:
        # binary32 samples kept exactly (ATM.md §4.10); precision is the preview mesh's
        # step, exact_step the STEP chunk's (§4.10.1; None: binary32 keys)
        steps = header.steps
        return {"precision": q.scale, "offset": q.offset, "exact_float": True,
                "exact_step": None if steps is None else steps.scale,
                "exact_offset": None if steps is None else steps.offset}
    return {"precision": q.scale, "offset": q.offset}


def read(source: str | os.PathLike | BinaryIO, *, out: np.ndarray | None = None, backend: str = "cpu", metadata: bool = False):
    """Read and decode an .atm file: a path, or a binary file object (read from where it
    is). out and backend as for `decode`; with metadata=True, return (image, metadata dict)."""
    from .stream import StreamDecoder, decode_into

    if isinstance(source, (bytes, bytearray, memoryview)) and check(source):
        raise ATMError("codec.read takes a path or a binary file object; for .atm bytes in memory use codec.decode(data)")
    if isinstance(source, (str, bytes, os.PathLike)):
        name = os.fsdecode(source)
        try:
            f = open(source, "rb")
        except OSError as exc:
            raise ATMError(f"cannot read {name}: {exc.strerror}") from None
        except ValueError as exc:  # a NUL in the name
            raise ATMError(f"cannot read {name!r}: {exc}") from None
    elif callable(getattr(source, "read", None)):
        name = getattr(source, "name", None) or "the file object"
        if isinstance(source, io.TextIOBase):
            raise ATMError(f"{name} is open in text mode; open it with open(path, 'rb')")
        f = contextlib.nullcontext(source)
    else:
        raise ATMError(
            f"codec.read takes a path or a binary file object, not {type(source).__name__}; "
            "for .atm bytes in memory use codec.decode(data)"
        )
    with f as fileobj:
        try:
            dec = StreamDecoder(fileobj, backend=backend)
            image = decode_into(dec, out)
        except OSError as exc:
            if isinstance(exc, ATMError):
                raise
            raise ATMError(f"cannot read {name}: {exc.strerror or exc}") from None
    return (image, dec.metadata) if metadata else image


def write(path: str | os.PathLike, image, *, force: bool = False, **options) -> None:
    """Encode `image` and write it to `path` atomically (options as for `encode`).
    A name with an image extension (x.png, x.tif, ...) is refused unless force=True:
    .atm bytes there would be taken for that image format."""
    from .files import atomic_write, refuse_image_name

    if not force:
        refuse_image_name(path)
    atomic_write(path, encode(image, **options))


__all__ = [
    "ATMError",
    "BackendError",
    "CorruptError",
    "Decoder",
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
    "check",
    "decode_mesh",
    "encode",
    "info",
    "read",
    "write",
]
