"""Converting one file: an image to .atm or .atm to an image, through files or pipes.

Shared by the single-file commands and the batch workers (cli/batch.py)."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import BinaryIO

import numpy as np

import codec
from . import pictures, rowio, signals
from codec import geotiff, integers
from codec.errors import ATMError, UnsupportedError
from codec.settings import cli_option_names, size_conflict


def open_input(name: str) -> BinaryIO:
    if name == "-":
        return contextlib.nullcontext(signals.standard_input())
    try:
        return open(name, "rb")
    except OSError as exc:
        raise ATMError(f"cannot read {name}: {exc.strerror}") from None


def open_output(name: str):
    """Standard output as it is, or a file that only appears if the command succeeds."""
    if name == "-":
        return contextlib.nullcontext(sys.stdout.buffer)
    from codec.files import atomic_open

    return atomic_open(name)


class _Counter:
    """Counts the bytes written through it."""

    def __init__(self, f: BinaryIO):
        self._f = f
        self.count = 0

    def write(self, data: bytes) -> int:
        self.count += len(data)
        return self._f.write(data)


#: Flags of `atm encode` that are not encoder options (every other flag must be one of
#: codec.settings.cli_option_names(), which tests/test_settings.py checks).
NOT_ENCODER_OPTIONS = ("inputs", "output", "output_option", "verbose", "jobs", "quiet", "force", "version", "alpha", "page")
#: Flags that say how to read the input picture (cli/pictures.py), passed with the options.
READING_OPTIONS = ("alpha", "page")


def encode_options(args: argparse.Namespace) -> dict:
    """The encoder options the command line sets (the ones left unset take the codec's
    defaults): every option of codec.settings that has a flag, by the same name."""
    options = {n: getattr(args, n) for n in cli_option_names() if getattr(args, n, None) is not None}
    # --no-residual sets no size, but the mesh then meets the bound alone
    clash = size_conflict((n for n, v in options.items() if v is not False),
                          mesh_only=options.get("residual") is False)
    if clash:
        a, b = (flag(n) for n in clash)
        raise codec.OptionError(f"{a} and {b} both set the size: give one of them")
    if "value_range" in options:
        options["value_range"] = tuple(options["value_range"])
    if "metadata" in options:
        try:
            options["metadata"] = json.loads(options["metadata"])
        except ValueError as exc:
            raise codec.OptionError(f"--metadata is not JSON: {exc}") from None
        except RecursionError:
            raise codec.OptionError("--metadata is nested too deeply") from None
        if not isinstance(options["metadata"], dict):
            raise codec.OptionError(
                f"--metadata takes a JSON object in braces, e.g. --metadata '{{\"units\": \"m\"}}', "
                f"not {args.metadata}"
            )
    options.update({n: getattr(args, n) for n in READING_OPTIONS if getattr(args, n, None) is not None})
    return options


def flag(name: str) -> str:
    """The command-line flag of an encoder option (max_rms: --max-rms)."""
    return "--" + name.replace("_", "-")


def encode_file(src_name: str, dst_name: str, options: dict, progress=None) -> tuple[codec.StreamEncoder, int]:
    """Encode one image (a path or -) to one .atm output (a path or -), band by band.
    Returns the finished encoder (its statistics) and the bytes written. `options` may
    also hold READING_OPTIONS (how to read a picture: cli/pictures.py)."""
    options = dict(options)
    reading = {n: options.pop(n) for n in READING_OPTIONS if n in options}
    src = _picture_rows(src_name, reading) or rowio.open_rows(src_name)
    options = geotiff.source_options(src, options)
    if src.dtype.kind == "f":
        if "value_range" not in options and src.scan is None:
            raise codec.OptionError(
                f"{src_name}: float data from a stream needs --value-range LOW HIGH "
                "(the header carries the quantisation before the rows arrive)"
            )
        options = src.float_options(options)
    elif integers.is_signed(src.dtype) and "value_range" not in options and src.scan is not None:
        options = dict(options, value_range=integers.value_range(src.scan(), options.get("nodata")))
    blocks = iter(src.blocks)
    with open_output(dst_name) as f:
        out = _Counter(f)
        first = next(blocks, None)  # (n, W, 1) rows or not: read once the output is open
        enc = codec.StreamEncoder(
            out,
            src.width,
            src.height,
            dtype=src.dtype,
            channels=src.channels,
            progress=progress,
            # a gray .npy of shape (H, W, 1) keeps its axis (ATM.md §4.9)
            channel_axis=first is not None and src.channels == 1 and first.ndim == 3,
            **options,
        )
        for block in ([] if first is None else [first]):
            enc.write(block)
        for block in blocks:
            enc.write(block)
        enc.close()
    return enc, out.count


#: What `atm decode` writes (--format, or the output's extension).
OUTPUT_FORMATS = ("png", "pgm", "ppm", "pnm", "tif", "tiff", "npy")
def _picture_rows(name: str, reading: dict) -> rowio.RowSource | None:
    """A camera or web picture read through Pillow as one block of rows; None for what
    the row reader takes (streams, PGM/PPM, .npy, single-page TIFF)."""
    image = None
    if name == "-":
        # standard input cannot be read twice: only a picture that is surely Pillow's
        # is taken here (TIFF stays with the row reader unless --page)
        head = _peek(signals.standard_input())
        if pictures.claims(head) and (not head.startswith(pictures.TIFF) or "page" in reading):
            data = signals.standard_input().read()
            image = pictures.read(data, "standard input", **reading)
            if image is None:  # 16-bit colour PNG, a single-page TIFF: OpenCV's
                from codec.files import decode_image

                image = decode_image(data, "standard input")
    elif pictures.claims(pictures.peek(name)):
        image = pictures.read_file(name, **reading)
    if image is None:
        if "page" in reading:
            raise codec.OptionError(f"--page picks a page of a multi-page file; {name} is not one")
        return None
    h, w = image.shape[:2]
    channels = 1 if image.ndim == 2 else image.shape[2]
    scan = (lambda: [image]) if image.dtype.kind == "f" else None
    return rowio.RowSource(w, h, image.dtype, channels, iter([image]), scan)


def _peek(stream: BinaryIO, size: int = 16) -> bytes:
    """The next bytes of a buffered stream, left in it (b"" if it cannot peek)."""
    try:
        return stream.peek(size)[:size]
    except (AttributeError, OSError, ValueError):
        return b""


STREAMED = {"pgm", "ppm", "pnm", "npy"}
#: Output formats that keep float samples as they are.
FLOAT_FORMATS = {"tif", "tiff", "npy"}


def output_format(output: str, fmt: str | None) -> str:
    """The image format a decode writes: --format, else the output's extension, else PNG."""
    if fmt:
        return fmt
    return Path(output).suffix.lstrip(".").lower() if output != "-" else "png"


def check_output_format(fmt: str) -> None:
    """UnsupportedError, listing what `atm decode` writes, if it cannot write `fmt`."""
    if fmt not in OUTPUT_FORMATS:
        raise UnsupportedError(
            f"cannot write {'.' + fmt if fmt else 'an output without an extension'}: "
            f"name it .{', .'.join(OUTPUT_FORMATS)}, or give --format"
        )


def decode_file(src_name: str, dst_name: str, fmt: str, backend: str = "cpu") -> int:
    """Decode one .atm input (a path or -) to an image output (a path or -) in `fmt`;
    PGM/PPM and .npy are written as the bands come (small bands rendered a group at
    a time, as codec.decode does). Returns the bytes written."""
    from codec.files import encode_image
    from codec.stream import GROUP_PIXELS

    with open_input(src_name) as f:
        dec = codec.StreamDecoder(f, backend=backend)
        if (np.dtype(dec.dtype).kind == "f" or integers.is_signed(dec.dtype)) and fmt not in FLOAT_FORMATS:
            # OpenCV would quietly cut float samples to 8 bits; PNG and PNM have no
            # negative numbers and no floats at all
            kind = "float" if np.dtype(dec.dtype).kind == "f" else str(dec.dtype)
            raise UnsupportedError(
                f"{src_name} holds {kind} data, which .{fmt} cannot store; decode it to .tif or .npy"
            )
        if fmt in STREAMED:
            with open_output(dst_name) as raw:
                out = _Counter(raw)
                if fmt == "npy":
                    np.lib.format.write_array_header_1_0(
                        out, {"descr": np.lib.format.dtype_to_descr(np.dtype(dec.dtype)), "fortran_order": False, "shape": dec.shape}
                    )
                    for _, rows in dec.rows(GROUP_PIXELS):
                        out.write(rows.tobytes())
                else:
                    out.write(rowio.pnm_header(dec.width, dec.height, dec.dtype, dec.channels))
                    for _, rows in dec.rows(GROUP_PIXELS):
                        out.write(rowio.pnm_rows(rows))
            return out.count
        image = np.empty(dec.shape, dec.dtype)
        for y0, rows in dec.rows(GROUP_PIXELS):
            image[y0 : y0 + len(rows)] = rows
    # a TIFF gets its georeferencing back (the geotiff metadata record)
    data = geotiff.write(image, dec.metadata, dec.nodata) if fmt in ("tif", "tiff") else encode_image(image, "." + fmt)
    with open_output(dst_name) as out:
        out.write(data)
    return len(data)
