"""Images as streams of rows for the CLI: binary PGM/PPM and .npy are read and written
row by row; other formats (PNG, TIFF, ...) go through OpenCV whole, in memory."""

from __future__ import annotations

from dataclasses import dataclass
from typing import BinaryIO, Callable, Iterable, Iterator

import numpy as np

from codec import geotiff, integers, lossless_float, quantise
from codec.errors import ATMError, UnsupportedError
from codec.files import decode_image, npy_header
from . import signals

#: Rows handed to the encoder at a time when reading a stream.
BLOCK_ROWS = 64


@dataclass
class RowSource:
    """An image's size and type, and its rows in blocks, top to bottom."""

    width: int
    height: int
    dtype: np.dtype
    channels: int
    blocks: Iterator[np.ndarray]
    #: float or signed integer data read from a file (not standard input): the same
    #: rows again, so that what the header needs can be found before the rows are streamed
    scan: Callable[[], Iterable[np.ndarray]] | None = None
    #: the source's own nodata value and metadata (a GeoTIFF's GDAL_NODATA and
    #: georeferencing), used unless the user gives their own
    nodata: float | None = None
    metadata: dict | None = None

    def float_options(self, options: dict) -> dict:
        """Float data: `options` with a value_range and a nodata value taken from the
        rows where not given and the rows can be scanned first (quantise.data_range,
        quantise.hole_value); otherwise `options` as they are."""
        if self.scan is None:
            return options
        if options.get("lossless") and options.get("precision") is None:
            # exact steps or binary32 keys: decided on all the samples at once
            image = lossless_float.as_binary32(np.concatenate([b.reshape(-1, self.width) for b in self.scan()]))
            return dict(options, **lossless_float.options_for(
                image, None, options.get("nodata"), options.get("value_range"), None))
        out = dict(options)
        nodata = quantise.check_nodata(options.get("nodata"))
        holes: list[np.ndarray] = []

        def blocks() -> Iterator[np.ndarray]:
            for block in self.scan():
                if nodata is None:
                    holes.append(np.unique(block[~np.isfinite(block)]))  # NaN, -inf, +inf at most
                yield block

        if "value_range" not in options:
            out["value_range"] = quantise.data_range(blocks(), nodata)
        elif nodata is None:
            for _ in blocks():
                pass
        if nodata is None:
            out["nodata"] = quantise.hole_value(holes)
        return out


def _read_exact(f: BinaryIO, n: int, name: str) -> bytes:
    data = f.read(n)
    if len(data) != n:
        raise ATMError(f"{name}: the image data ends early")
    return data


def _pnm_token(f: BinaryIO, head: bytearray) -> bytes:
    """The next whitespace-separated header token, skipping # comments."""
    token = b""
    while True:
        c = f.read(1)
        head += c
        if not c:
            return token
        if c == b"#":
            while c not in (b"\n", b"\r", b""):
                c = f.read(1)
                head += c
            continue
        if c.isspace():
            if token:
                return token
            continue
        token += c


def _pnm_source(f: BinaryIO, magic: bytes, name: str) -> RowSource:
    head = bytearray(magic)
    try:
        width, height, maxval = (int(_pnm_token(f, head)) for _ in range(3))
    except ValueError:
        raise ATMError(f"{name}: malformed PGM/PPM header") from None
    if width < 1 or height < 1 or not 0 < maxval < 65536:
        raise ATMError(f"{name}: PGM/PPM header declares {width}x{height}, maxval {maxval}")
    channels = 1 if magic == b"P5" else 3
    wire = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
    dtype = np.dtype(np.uint16) if maxval > 255 else np.dtype(np.uint8)
    row_shape = (width,) if channels == 1 else (width, 3)
    row_bytes = width * channels * wire.itemsize

    def blocks() -> Iterator[np.ndarray]:
        for y in range(0, height, BLOCK_ROWS):
            n = min(BLOCK_ROWS, height - y)
            data = _read_exact(f, n * row_bytes, name)
            yield np.frombuffer(data, wire).reshape((n,) + row_shape).astype(dtype)

    return RowSource(width, height, dtype, channels, blocks())


def _npy_source(f: BinaryIO, name: str, path: str | None) -> RowSource:
    if path is not None:
        try:
            array = np.load(path, mmap_mode="r", allow_pickle=False)  # pages in as rows are read
        except (ValueError, SyntaxError, EOFError) as exc:
            # a header that lies about the data's size, or one cut short
            raise ATMError(f"{name}: not a readable .npy array: {exc}") from None
        shape, dtype = array.shape, array.dtype
    else:
        try:
            shape, fortran, dtype = npy_header(f)
        except (ValueError, SyntaxError) as exc:
            raise ATMError(f"{name}: not a readable .npy array: {exc}") from None
        if fortran:
            raise UnsupportedError(f"{name}: Fortran-ordered .npy cannot be streamed")
        array = None
    if len(shape) not in (2, 3) or 0 in shape:
        raise ATMError(f"{name}: array of shape {shape} is not an image")
    height, width = shape[:2]
    channels = 1 if len(shape) == 2 else shape[2]
    row_items = int(np.prod(shape[1:]))

    def blocks() -> Iterator[np.ndarray]:
        for y in range(0, height, BLOCK_ROWS):
            n = min(BLOCK_ROWS, height - y)
            if array is not None:
                yield np.ascontiguousarray(array[y : y + n], dtype.newbyteorder("="))
            else:
                data = _read_exact(f, n * row_items * dtype.itemsize, name)
                yield np.frombuffer(data, dtype).reshape((n,) + tuple(shape[1:])).astype(dtype.newbyteorder("="))

    def scan() -> Iterator[np.ndarray]:
        return (array[y : y + BLOCK_ROWS] for y in range(0, height, BLOCK_ROWS))

    scannable = array is not None and (np.dtype(dtype).kind == "f" or integers.is_signed(dtype))
    return RowSource(width, height, np.dtype(dtype).newbyteorder("="), channels, blocks(), scan if scannable else None)


def open_rows(name: str) -> RowSource:
    """Open an image file (or - for standard input) as rows."""
    if name == "-":
        f, path = signals.standard_input(), None
    else:
        try:
            f, path = open(name, "rb"), name
        except OSError as exc:
            raise ATMError(f"cannot read {name}: {exc.strerror}") from None
    magic = f.read(2)
    if magic in (b"P5", b"P6"):
        return _pnm_source(f, magic, name)
    if magic == b"\x93N":
        if path is not None:
            f.close()
        else:
            f = _Prefixed(magic, f)
        return _npy_source(f, name, path)
    data = magic + f.read()
    if path is not None:
        f.close()
    raster = geotiff.read(data, name) if geotiff.is_tiff(data) else None
    image = raster.image if raster is not None else decode_image(data, name)  # read whole
    if image.ndim not in (2, 3):
        raise ATMError(f"{name}: not a 2-D image")
    h, w = image.shape[:2]
    channels = 1 if image.ndim == 2 else image.shape[2]
    scan = (lambda: [image]) if image.dtype.kind == "f" or integers.is_signed(image.dtype) else None
    return RowSource(
        w, h, image.dtype, channels, iter([image]), scan,
        raster.nodata if raster is not None else None,
        raster.metadata if raster is not None else None,
    )


class _Prefixed:
    """A stream with bytes already read put back in front."""

    def __init__(self, prefix: bytes, stream: BinaryIO):
        self._prefix = prefix
        self._stream = stream

    def read(self, n: int = -1) -> bytes:
        head, self._prefix = (self._prefix, b"") if n < 0 or n >= len(self._prefix) else (self._prefix[:n], self._prefix[n:])
        if n < 0:
            return head + self._stream.read()
        return head + (self._stream.read(n - len(head)) if n > len(head) else b"")


def pnm_header(width: int, height: int, dtype: np.dtype, channels: int) -> bytes:
    maxval = 255 if dtype == np.uint8 else 65535
    return f"{'P5' if channels == 1 else 'P6'}\n{width} {height}\n{maxval}\n".encode()


def pnm_rows(rows: np.ndarray) -> bytes:
    """Rows as PNM sample bytes (16-bit samples are big-endian in PNM)."""
    return rows.astype(rows.dtype.newbyteorder(">")).tobytes() if rows.dtype.itemsize > 1 else rows.tobytes()
