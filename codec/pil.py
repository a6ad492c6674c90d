"""Pillow plugin: `import codec.pil` and Pillow opens and saves .atm files.

    import codec.pil
    from PIL import Image
    im = Image.open("scene.atm")            # modes L, I;16, RGB (and F for float data)
    im.save("copy.atm", points=4000)        # options as for codec.encode

`Image.open` reads only the signature and the header chunks (metadata is skipped
unparsed), so Pillow's decompression-bomb check sees the declared size before anything
is decoded; the mesh and the metadata are decoded on `load()`, which then fills
`im.info["metadata"]`. Every error Pillow's callers see is an OSError (they catch that):
the codec's own errors are raised as classes deriving from both the ATMError subclass
and OSError, so `except codec.CorruptError` works as well. Pillow is needed only here:
`import codec` never imports it.
"""

from __future__ import annotations

import functools
import io
from typing import IO

import numpy as np
from PIL import Image, ImageFile

import codec
from codec import container
from codec.errors import ATMError, UnsupportedError
from codec import stream

FORMAT = "ATM"
SIGNATURE = b"\x89ATM\r\n\x1a\n"
MIME = "image/x-atm"

#: (numpy dtype, channels) <-> Pillow mode, and the raw mode of the decoded bytes.
MODES = {
    (np.dtype(np.uint8), 1): ("L", "L"),
    (np.dtype(np.uint16), 1): ("I;16", "I;16"),
    (np.dtype(np.uint8), 3): ("RGB", "RGB"),
    (np.dtype(np.float32), 1): ("F", "F"),
}

#: encoderinfo keys Pillow itself handles or passes to every format's save, and the
#: format-neutral ones generic pipelines give any format (optimize, dpi, icc_profile,
#: exif, xmp, comment: .atm has nowhere to keep them); left out, not refused, while an
#: unknown .atm option is still refused by codec.encode.
PILLOW_KEYS = frozenset({"append", "append_images", "optimize", "dpi", "icc_profile", "exif", "xmp", "comment"})


@functools.cache
def _os_class(cls: type) -> type:
    """cls (an ATMError subclass) made an OSError as well, for Pillow's callers."""
    return type(cls.__name__, (cls, OSError), {"__module__": cls.__module__})


def _as_os_error(exc: ATMError) -> ATMError:
    return exc if isinstance(exc, OSError) else _os_class(type(exc))(*exc.args)


def _accept(prefix: bytes) -> bool:
    return prefix[: len(SIGNATURE)] == SIGNATURE


class AtmImageFile(ImageFile.ImageFile):
    """An .atm file opened by Pillow: the header on open, the image on load()."""

    format = FORMAT
    format_description = ".atm adaptive triangular mesh"

    def _open(self) -> None:
        try:
            self._open_header()
        except ATMError as exc:
            raise _as_os_error(exc) from None

    def _open_header(self) -> None:
        if not _accept(self.fp.read(len(SIGNATURE))):
            raise SyntaxError("not an .atm file")
        self.fp.seek(-len(SIGNATURE), 1)
        start = self.fp.tell()
        header = container.read_header(self.fp, metadata=False)
        key = (np.dtype(header.dtype), header.channels)
        if key not in MODES:
            raise UnsupportedError(
                f"{header.channels}-channel {header.dtype} .atm images have no Pillow mode; "
                "read them with codec.read() instead"
            )
        mode, rawmode = MODES[key]
        self._mode = mode
        self._size = (header.width, header.height)
        if header.nodata is not None:
            self.info["nodata"] = header.nodata
        # the decoder puts the metadata into self.info once it has read the file
        self.tile = [ImageFile._Tile(FORMAT, (0, 0) + self.size, start, (rawmode, self.info))]


class AtmDecoder(ImageFile.PyDecoder):
    """Decodes a whole .atm file from the image's file object into the image."""

    _pulls_fd = True

    def decode(self, buffer: bytes | Image.SupportsArrayInterface) -> tuple[int, int]:
        assert self.fd is not None
        rawmode, info = self.args
        try:
            image, metadata = stream.decode_all(io.BytesIO(self.fd.read()))
            if image.shape[:2] != (self.state.ysize, self.state.xsize):
                raise UnsupportedError("the .atm file decodes to another size than its header says")
        except ATMError as exc:
            raise _as_os_error(exc) from None
        if metadata:
            info["metadata"] = metadata
        self.set_as_raw(np.ascontiguousarray(image).tobytes(), rawmode)
        return -1, 0


def _as_array(im: Image.Image) -> np.ndarray:
    """The image's samples as an array .atm stores, or an error saying how to get one."""
    if im.mode in ("L", "I;16", "RGB", "F"):
        return np.asarray(im)
    if im.mode == "1":
        return np.asarray(im.convert("L"))
    if im.mode in ("I", "I;16B", "I;16L"):
        array = np.asarray(im.convert("I") if im.mode != "I" else im)
        if array.size and (array.min() < 0 or array.max() > 65535):
            raise UnsupportedError(
                f"mode {im.mode} samples run from {array.min()} to {array.max()}; "
                ".atm stores 0..65535 (16-bit)"
            )
        return array.astype(np.uint16)
    raise UnsupportedError(
        f".atm cannot store Pillow mode {im.mode}; convert first, e.g. im.convert('RGB') or "
        "im.convert('L')"
    )


def _save(im: Image.Image, fp: IO[bytes], filename: str | bytes) -> None:
    options = {k: v for k, v in im.encoderinfo.items() if k not in PILLOW_KEYS}
    # codec.encode refuses options it does not know (an OptionError naming them)
    fp.write(codec.encode(_as_array(im), **options))


def register() -> None:
    """Register .atm with Pillow (done on import; calling it again is harmless)."""
    Image.register_open(FORMAT, AtmImageFile, _accept)
    Image.register_save(FORMAT, _save)
    Image.register_extension(FORMAT, ".atm")
    Image.register_mime(FORMAT, MIME)
    Image.register_decoder(FORMAT, AtmDecoder)


register()
