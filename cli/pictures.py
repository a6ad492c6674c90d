"""Pictures from cameras and the web, read through Pillow, which gets what OpenCV does
not: EXIF orientation, gray+alpha, palettes, and the pages of multi-page files.

Alpha is not stored in .atm: an image with it is refused unless --alpha says what to do
(drop it, or flatten onto a white or black background). A file of several pages or
frames is refused unless --page picks one. Single-page TIFF is left to the TIFF reader
(cli/rowio.py), which knows GeoTIFF; PGM/PPM and .npy are streamed there too.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from codec.errors import ATMError, LimitError, OptionError, UnsupportedError
from codec import limits
from codec.files import check_png_size

#: --alpha choices: drop the alpha channel, or flatten onto this background.
ALPHA = ("drop", "white", "black")
#: Signatures of the formats read here (TIFF only with several pages or --page).
_SIGNATURES = (b"\xff\xd8\xff", b"\x89PNG\r\n\x1a\n", b"GIF87a", b"GIF89a", b"BM")
TIFF = (b"II*\x00", b"MM\x00*")


def claims(head: bytes) -> bool:
    """Whether a file starting with `head` (its first 16 bytes or more) may be read
    here (read() still hands back single-page TIFF and 16-bit colour PNG)."""
    if head.startswith(_SIGNATURES) or (head[:4] == b"RIFF" and head[8:12] == b"WEBP"):
        return True
    return head.startswith(TIFF)


def read(data: bytes, name: str, *, alpha: str | None = None, page: int | None = None) -> np.ndarray | None:
    """The picture in `data` as gray, RGB or float samples, upright; None for a
    single-page TIFF without --page (the TIFF reader's) and for 16-bit colour PNG, which
    Pillow cuts to 8 bits (OpenCV keeps them). ATMError says what to do."""
    from PIL import Image, ImageOps, UnidentifiedImageError

    if alpha is not None and alpha not in ALPHA:
        raise OptionError(f"--alpha takes {', '.join(ALPHA)}, not {alpha}")
    check_png_size(data)
    try:
        with warnings.catch_warnings():
            # the codec's own pixel limit decides, below, with its own message
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data))
        # Image.open reads the header only: refuse a bomb before anything decodes
        limits.check_image_size(*im.size)
        pages = getattr(im, "n_frames", 1)
        if im.format == "TIFF" and pages == 1 and page is None:
            return None
        if im.format == "PNG" and data[24:25] == b"\x10" and data[25:26] in (b"\x02", b"\x06"):
            return None  # IHDR: bit depth 16, colour type RGB or RGBA
        if page is None and pages > 1:
            raise UnsupportedError(
                f"{name} has {pages} pages (or frames); .atm holds one image: give --page N "
                f"(0..{pages - 1}) to encode one of them"
            )
        if page is not None:
            if not 0 <= page < pages:
                raise OptionError(f"--page {page}: {name} has {pages} page(s), numbered 0..{pages - 1}")
            im.seek(page)
        im = ImageOps.exif_transpose(im)
        return _samples(im, name, alpha)
    except Image.DecompressionBombError as exc:
        raise LimitError(f"{name}: {exc}") from None
    except (UnidentifiedImageError, OSError, ValueError, EOFError) as exc:
        if isinstance(exc, ATMError):
            raise
        raise ATMError(f"{name}: not a readable image ({exc})") from None


def _samples(im, name: str, alpha: str | None) -> np.ndarray:
    """Pillow image -> the array .atm stores; alpha handled as `alpha` says."""
    mode = im.mode
    if mode == "P":
        im = im.convert("RGBA" if "transparency" in im.info else "RGB")
    elif mode == "PA":
        im = im.convert("RGBA")
    elif mode in ("1", "CMYK", "YCbCr", "LAB", "HSV"):
        im = im.convert("L" if mode == "1" else "RGB")
    elif mode in ("I;16B", "I;16L", "I;16N"):
        im = im.convert("I")
    mode = im.mode
    if mode in ("LA", "La", "RGBA", "RGBa"):
        im = _without_alpha(im, name, alpha)
        mode = im.mode
    array = np.asarray(im)
    if mode == "I":
        if array.size and (array.min() < 0 or array.max() > 65535):
            raise UnsupportedError(
                f"{name}: samples run from {array.min()} to {array.max()}; .atm stores 0..65535 (16-bit) or float"
            )
        return array.astype(np.uint16)
    if mode == "F":
        return array.astype(np.float32)
    if mode in ("L", "RGB", "I;16"):
        return np.ascontiguousarray(array)
    raise UnsupportedError(f"{name}: Pillow mode {mode} has no .atm form; convert it to gray or RGB first")


def _without_alpha(im, name: str, alpha: str | None):
    kind = "gray+alpha" if im.mode in ("LA", "La") else "RGBA"
    if alpha is None:
        raise UnsupportedError(
            f"{name} is {kind}, and .atm stores no alpha: give --alpha drop (keep the "
            "colours as they are), --alpha white or --alpha black (flatten onto that background)"
        )
    base = "L" if kind == "gray+alpha" else "RGB"
    if alpha == "drop":
        return im.convert("LA" if base == "L" else "RGBA").convert(base)
    from PIL import Image

    rgba = im.convert("RGBA")
    background = Image.new("RGBA", rgba.size, (255, 255, 255, 255) if alpha == "white" else (0, 0, 0, 255))
    # gray stays exact: Pillow's RGB -> L weights sum to one
    return Image.alpha_composite(background, rgba).convert(base)


def peek(name: str, size: int = 16) -> bytes:
    """The first bytes of the file `name` (b"" if it cannot be read: the reader says why)."""
    try:
        with open(name, "rb") as f:
            return f.read(size)
    except OSError:
        return b""


def read_file(name: str, *, alpha: str | None = None, page: int | None = None) -> np.ndarray | None:
    """`read` on the file `name`."""
    try:
        data = Path(name).read_bytes()
    except OSError as exc:
        raise ATMError(f"cannot read {name}: {exc.strerror}") from None
    return read(data, name, alpha=alpha, page=page)
