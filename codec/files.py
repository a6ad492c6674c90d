"""Files: atomic writes, and images in the formats OpenCV reads and writes."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np

from .errors import ATMError, UnsupportedError

#: Extensions of the image files `atm encode` reads (OpenCV's formats, TIFF through
#: tifffile, .npy): batch mode picks these out of a directory, so that it takes every
#: file a single-file encode takes (.pfm is Middlebury's disparity format).
READABLE = (
    ".png", ".pgm", ".ppm", ".pnm", ".pbm", ".pam", ".pfm", ".tif", ".tiff", ".jpg", ".jpeg",
    ".jpe", ".jp2", ".bmp", ".dib", ".webp", ".gif", ".sr", ".ras", ".avif", ".npy",
)  # fmt: skip

#: Extensions an image can be written as, by OpenCV.
WRITABLE = (".png", ".pgm", ".ppm", ".pnm", ".tif", ".tiff")


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file to write `path` with: it replaces `path` only when the block
    finishes without error; otherwise it is deleted and `path` is left as it was."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        # mkstemp makes the file private; give it the mode a plain open() would have
        try:
            mode = os.stat(path).st_mode & 0o7777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` so that `path` is either untouched or complete."""
    with atomic_open(path) as f:
        f.write(data)


def decode_image(data: bytes, name: str = "input") -> np.ndarray:
    """Decode image-file bytes (any format OpenCV reads, or .npy) to gray or RGB."""
    if data[:6] == b"\x93NUMPY":
        import io

        try:
            return np.load(io.BytesIO(data), allow_pickle=False)
        except Exception as exc:  # numpy raises several types for a bad .npy
            raise ATMError(f"{name}: not a readable .npy array: {exc}") from None
    from . import geotiff

    if geotiff.is_tiff(data):
        # tifffile reads the compressions GDAL writes (ZSTD, LZW, ...) and knows the
        # GeoTIFF tags that OpenCV warns about
        return geotiff.read(data, name).image
    import cv2

    buf = np.frombuffer(data, dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if len(buf) else None
    if image is None:
        raise ATMError(f"{name}: not an image OpenCV can read")
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    return image


def encode_image(image: np.ndarray, ext: str) -> bytes:
    """Encode an image as PNG, PGM/PPM or TIFF bytes (chosen by `ext`)."""
    import cv2

    ext = ext.lower()
    if ext not in WRITABLE:
        raise UnsupportedError(
            f"cannot write {ext or 'files without an extension'}; use one of {', '.join(WRITABLE)}"
        )
    if image.dtype.kind == "f" and ext not in (".tif", ".tiff"):
        # OpenCV would quietly cut float samples to 8 bits
        raise UnsupportedError(f"float data cannot be written as {ext}; use .tif or .npy")
    if ext in (".tif", ".tiff"):
        from . import geotiff

        return geotiff.write(image)
    if ext in (".pgm", ".ppm", ".pnm"):
        ext = ".pgm" if image.ndim == 2 else ".ppm"
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(ext, image)
    if not ok:
        raise ATMError(f"OpenCV could not encode the image as {ext}")
    return buf.tobytes()


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file (any format OpenCV reads, or .npy)."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ATMError(f"cannot read {path}: {exc.strerror}") from None
    return decode_image(data, str(path))


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an image atomically in the format its extension names."""
    atomic_write(path, encode_image(image, Path(path).suffix))
