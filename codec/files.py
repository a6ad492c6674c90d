"""Files: safe writes, and images in the formats OpenCV reads and writes.

`atomic_open` writes a regular file so that its path holds either the old file or the
whole new one. On Linux the new data goes to an unnamed file (O_TMPFILE) that gets its
name only when it is complete, so even SIGKILL leaves nothing behind; elsewhere a hidden
named temporary is used and removed on any exception (the `atm` command turns SIGTERM
into one). Devices and FIFOs are not replaced but written through, and a symbolic link
keeps pointing where it did: its target is what gets replaced.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import os
import secrets
import stat
import struct
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np

from . import limits
from .errors import ATMError, OptionError, UnsupportedError

#: Extensions of the image files `atm encode` reads (OpenCV's formats, TIFF through
#: tifffile, .npy): batch mode picks these out of a directory, so that it takes every
#: file a single-file encode takes (.pfm is Middlebury's disparity format).
READABLE = (
    ".png", ".pgm", ".ppm", ".pnm", ".pbm", ".pam", ".pfm", ".tif", ".tiff", ".jpg", ".jpeg",
    ".jpe", ".jp2", ".bmp", ".dib", ".webp", ".gif", ".sr", ".ras", ".avif", ".npy",
)  # fmt: skip

#: Extensions an image can be written as, by OpenCV.
WRITABLE = (".png", ".pgm", ".ppm", ".pnm", ".tif", ".tiff")
#: Extensions of the image files the codec reads (batch mode picks these out of a folder).
IMAGE_SUFFIXES = frozenset(READABLE)
#: Extensions that name an image or raster format: .atm bytes written under one of
#: these would be taken for that format (and may replace the user's original).
IMAGE_NAMES = IMAGE_SUFFIXES | {
    ".jfif", ".exr", ".hdr", ".heic", ".heif", ".jxl", ".dng", ".raw", ".npz", ".img",
    ".asc", ".dem", ".flt",
}  # fmt: skip

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: O_TMPFILE where the platform has it (Linux); None selects named temporaries.
UNNAMED = getattr(os, "O_TMPFILE", None)
# where O_TMPFILE exists but this file system lacks it, open() fails with one of these
_NO_TMPFILE = frozenset({errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL})
_AT_FDCWD, _AT_EMPTY_PATH = -100, 0x1000
# linkat() of an unnamed file refused outright (no privilege, no /proc, a sandbox)
_CANNOT_LINK = frozenset({errno.EPERM, errno.EACCES, errno.ENOENT, errno.EXDEV, errno.ENOSYS, errno.EOPNOTSUPP, errno.EINVAL})


class WriteError(ATMError, OSError):
    """An output file cannot be written (a missing folder, a full disk, no permission).
    Also an OSError, so that callers that catch the file system's errors catch it."""

    def __init__(self, message: str, code: int | None = None, name: str | None = None):
        super().__init__(message)
        self.errno = code
        self.path = name



def check_png_size(data: bytes) -> None:
    """LimitError if `data` is a PNG whose header declares more pixels than codec.limits
    allows: checked before any reader decodes (or allocates for) it."""
    if data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR" and len(data) >= 24:
        limits.check_image_size(*struct.unpack(">II", data[16:24]))

def write_error(name: str, exc: OSError) -> WriteError:
    """A WriteError naming the user's path (never a temporary file's) and the cause."""
    reason = exc.strerror or str(exc)
    folder = os.path.dirname(os.path.abspath(name))
    if exc.errno == errno.ENOENT and not os.path.isdir(folder):
        reason = f"the folder {folder} does not exist"
    return WriteError(f"cannot write {name}: {reason}", exc.errno, name)


class _Output:
    """Writes to a file descriptor through a buffer of its own, so that a failed write
    is raised once, naming the user's path, and never retried when the file closes."""

    BUFFER = 1 << 20

    def __init__(self, fd: int, name: str):
        self._fd = fd
        self._pending = bytearray()
        self.name = name

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        if len(self._pending) + len(view) < self.BUFFER:
            self._pending += view
        else:  # a large piece goes straight out, not copied into the buffer first
            self.flush()
            self._write_all(view)
        return len(view)

    def flush(self) -> None:
        try:
            self._write_all(self._pending)
        finally:
            self._pending.clear()

    def _write_all(self, data) -> None:
        with memoryview(data) as view:
            done = 0
            try:
                while done < len(view):
                    done += os.write(self._fd, view[done:])
            except OSError as exc:
                raise write_error(self.name, exc) from None

    def fileno(self) -> int:
        return self._fd


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file to write `path` with. A regular file (or a new one) is replaced
    only when the block finishes without error, keeping the old file's permissions;
    otherwise `path` is left as it was and nothing else remains. A device or FIFO is
    written straight through; a symbolic link's target is replaced, not the link.
    Failures raise WriteError naming `path`."""
    name = os.fsdecode(os.fspath(path))
    if not name:
        raise WriteError("the output file name is empty", errno.ENOENT)
    if name.endswith(os.sep):
        raise WriteError(f"cannot write {name}: a file name cannot end with {os.sep}", errno.EISDIR, name)
    try:
        st = os.stat(name)  # through any links, as the kernel resolves them
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise write_error(name, exc) from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise WriteError(f"cannot write {name}: it is a directory", errno.EISDIR, name)
    if st is not None and not stat.S_ISREG(st.st_mode):
        # /dev/stdout on a pipe has no path realpath() could name: open it as it is
        with _through(name) as f:
            yield f
        return
    with _replacing(name, os.path.realpath(name), st) as f:
        yield f


@contextlib.contextmanager
def _through(name: str) -> Iterator[BinaryIO]:
    # a device or FIFO has no contents to keep: replacing it would only break it
    try:
        fd = os.open(name, os.O_WRONLY | os.O_CLOEXEC)
    except OSError as exc:
        raise write_error(name, exc) from None
    try:
        out = _Output(fd, name)
        yield out
        out.flush()
    finally:
        os.close(fd)


@contextlib.contextmanager
def _replacing(name: str, target: str, st: os.stat_result | None) -> Iterator[BinaryIO]:
    directory = os.path.dirname(target)
    fd, temp = _create(name, directory, UNNAMED)
    try:
        if st is not None:
            _keep_owner_and_mode(fd, st)
        out = _Output(fd, name)
        yield out
        out.flush()
        try:
            os.fsync(fd)
            if temp is None:
                _link_unnamed(fd, directory, target)
            else:
                os.replace(temp, target)
        except OSError as exc:
            raise write_error(name, exc) from None
    except BaseException:
        if temp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temp)
        raise
    finally:
        os.close(fd)


def _create(name: str, directory: str, unnamed: int | None) -> tuple[int, str | None]:
    """A new file in `directory` to write: unnamed where `unnamed` (O_TMPFILE) works
    (its name None), else a hidden named one. Its mode is what open() would give."""
    if unnamed is not None:
        try:
            return os.open(directory, unnamed | os.O_RDWR | os.O_CLOEXEC, 0o666), None
        except OSError as exc:
            if exc.errno not in _NO_TMPFILE:
                raise write_error(name, exc) from None
    while True:
        temp = os.path.join(directory, f".{os.path.basename(name)}.{secrets.token_hex(4)}.tmp")
        try:
            return os.open(temp, os.O_CREAT | os.O_EXCL | os.O_RDWR | os.O_CLOEXEC, 0o666), temp
        except FileExistsError:
            continue
        except OSError as exc:
            raise write_error(name, exc) from None


def _keep_owner_and_mode(fd: int, st: os.stat_result) -> None:
    os.fchmod(fd, stat.S_IMODE(st.st_mode))
    if (st.st_uid, st.st_gid) != (os.getuid(), os.getgid()):
        # only root (or a member of the group) may; otherwise the new file is the user's
        with contextlib.suppress(PermissionError):
            os.fchown(fd, st.st_uid, st.st_gid)
            os.fchmod(fd, stat.S_IMODE(st.st_mode))  # chown clears set-id bits


def _link_unnamed(fd: int, directory: str, target: str) -> None:
    """Give the unnamed file `fd` the name `target`, replacing any file there."""
    try:
        _link(fd, target)
        return
    except FileExistsError:
        pass
    except OSError as exc:
        if exc.errno not in _CANNOT_LINK:
            raise
        _copy_to(fd, directory, target)  # no way to name it on this system: copy it
        return
    # linkat never replaces: name it beside the target and rename that over it (the
    # extra name exists only between these two system calls)
    while True:
        temp = os.path.join(directory, f".{os.path.basename(target)}.{secrets.token_hex(4)}.tmp")
        try:
            _link(fd, temp)
            break
        except FileExistsError:
            continue
    try:
        os.replace(temp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise


def _link(fd: int, dst: str) -> None:
    """linkat(fd, "", dst, AT_EMPTY_PATH), or through /proc where that is refused."""
    libc = _libc()
    if libc is not None:
        if libc.linkat(fd, b"", _AT_FDCWD, os.fsencode(dst), _AT_EMPTY_PATH) == 0:
            return
        if ctypes.get_errno() == errno.EEXIST:
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), dst)
    os.link(f"/proc/self/fd/{fd}", dst, follow_symlinks=True)


@functools.cache
def _libc():
    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


def _copy_to(fd: int, directory: str, target: str) -> None:
    out, temp = _create(target, directory, None)
    try:
        offset = 0
        while chunk := os.pread(fd, 1 << 20, offset):
            offset += len(chunk)
            view = memoryview(chunk)
            while view:
                view = view[os.write(out, view):]
        os.fchmod(out, stat.S_IMODE(os.fstat(fd).st_mode))
        os.fsync(out)
        os.replace(temp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise
    finally:
        os.close(out)


def refuse_image_name(path: str | os.PathLike) -> None:
    """OptionError if `path` has an image extension: .atm bytes written there would be
    taken for that format (and an image of that name may be the user's original)."""
    suffix = Path(os.fsdecode(os.fspath(path))).suffix.lower()
    if suffix in IMAGE_NAMES:
        raise OptionError(
            f"{os.fsdecode(os.fspath(path))} has the image extension {suffix}, but .atm data would be written "
            "there: use a name ending in .atm (or force=True to write it all the same)"
        )


def atomic_write(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` so that `path` is either untouched or complete."""
    with atomic_open(path) as f:
        f.write(data)


def npy_header(stream: BinaryIO) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) from the start of an .npy stream, which is left at
    the array data. ValueError (or SyntaxError) if it is not one."""
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(stream)
    return np.lib.format.read_array_header_2_0(stream)


def decode_image(data: bytes, name: str = "input") -> np.ndarray:
    """Decode image-file bytes (any format OpenCV reads, or .npy) to gray or RGB."""
    # the size a header declares is checked before any pixel is allocated: a small file
    # may declare a huge image (a PNG of zeros compresses about 1000:1)
    if data[:6] == b"\x93NUMPY":
        import io

        try:
            shape = npy_header(io.BytesIO(data))[0]
            if len(shape) in (2, 3):
                limits.check_image_size(int(shape[1]), int(shape[0]))
            return np.load(io.BytesIO(data), allow_pickle=False)
        except ATMError:
            raise
        except Exception as exc:  # numpy raises several types for a bad .npy
            raise ATMError(f"{name}: not a readable .npy array: {exc}") from None
    check_png_size(data)
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
    if image.ndim == 3 and image.shape[2] == 1:  # an (H, W, 1) decode (ATM.md §4.9): gray
        image = image[:, :, 0]
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
