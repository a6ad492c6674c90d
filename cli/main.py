"""`atm`: encode images to .atm, decode them back, and describe .atm files.

Errors print one line, `atm: error: ...`, and exit 1 for bad data, 2 for bad usage.
Output files are written atomically: a failed run leaves no partial file and does not
touch an existing one.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import BinaryIO

import numpy as np

import codec
from cli import rowio
from codec.errors import ATMError

EPILOG = "Use - for standard input or output. Run 'atm COMMAND --help' for a command's options."


def _open_input(name: str) -> BinaryIO:
    if name == "-":
        return contextlib.nullcontext(sys.stdin.buffer)
    try:
        return open(name, "rb")
    except OSError as exc:
        raise ATMError(f"cannot read {name}: {exc.strerror}") from None


def _open_output(name: str):
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


def cmd_encode(args: argparse.Namespace) -> int:
    src = rowio.open_rows(args.input)
    options = {}
    if args.mesher:
        options["mesher"] = args.mesher
    with _open_output(args.output) as f:
        out = _Counter(f)
        enc = codec.StreamEncoder(
            out,
            src.width,
            src.height,
            dtype=src.dtype,
            channels=src.channels,
            points=args.points,
            band_height=args.band_height,
            **options,
        )
        for block in src.blocks:
            enc.write(block)
        enc.close()
    if args.verbose:
        pixels = src.width * src.height
        print(
            f"{args.input} -> {args.output}: {src.width}x{src.height}, {enc.bands} band(s), "
            f"{enc.vertices:,} vertices, {enc.triangles:,} triangles, {out.count:,} bytes "
            f"({8 * out.count / pixels:.3f} bits/pixel)",
            file=sys.stderr,
        )
    return 0


STREAMED = {"pgm", "ppm", "pnm", "npy"}


def cmd_decode(args: argparse.Namespace) -> int:
    from codec.files import encode_image

    fmt = args.format or (Path(args.output).suffix.lstrip(".").lower() if args.output != "-" else "png")
    with _open_input(args.input) as f:
        dec = codec.StreamDecoder(f, backend=args.backend)
        if fmt in STREAMED:
            with _open_output(args.output) as out:
                if fmt == "npy":
                    np.lib.format.write_array_header_1_0(
                        out, {"descr": np.lib.format.dtype_to_descr(np.dtype(dec.dtype)), "fortran_order": False, "shape": dec.shape}
                    )
                    for _, rows in dec:
                        out.write(rows.tobytes())
                else:
                    out.write(rowio.pnm_header(dec.width, dec.height, dec.dtype, dec.channels))
                    for _, rows in dec:
                        out.write(rowio.pnm_rows(rows))
            return 0
        image = np.empty(dec.shape, dec.dtype)
        for y0, rows in dec:
            image[y0 : y0 + len(rows)] = rows
    data = encode_image(image, "." + fmt)
    with _open_output(args.output) as out:
        out.write(data)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    with _open_input(args.input) as f:
        data = f.read()
    i = codec.info(data)
    if args.json:
        print(json.dumps(i, indent=2))
    else:
        kind = "gray" if i["channels"] == 1 else "RGB"
        print(f"{args.input}: .atm version {i['version']}, {i['width']}x{i['height']} {kind} {i['dtype']}, {i['bands']} band(s)")
        print(f"  {i['vertices']:,} vertices, {i['triangles']:,} triangles, {i['constraints']:,} walls")
        print(f"  {i['bytes']:,} bytes, {8 * i['bytes'] / (i['width'] * i['height']):.3f} bits/pixel")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="atm",
        description="The .atm image codec: images as adaptive triangular meshes.",
        epilog=EPILOG,
    )
    parser.add_argument("--debug", action="store_true", help="show a traceback on errors")
    parser.add_argument("--version", action="version", version=f"atm {codec.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    enc = sub.add_parser(
        "encode",
        help="encode an image as .atm",
        description=(
            "Encode an image (any format OpenCV reads, or .npy) as .atm. Binary PGM/PPM and "
            ".npy input (a file or standard input) is read and encoded band by band, in "
            "memory bounded by the band; other formats (PNG, TIFF, ...) are read whole."
        ),
        epilog=EPILOG,
    )
    enc.add_argument("input", help="image file, or - for standard input")
    enc.add_argument("output", help=".atm file, or - for standard output")
    enc.add_argument("--points", type=int, metavar="N", help="target vertex count (default: 2.8%% of the pixels)")
    enc.add_argument(
        "--band-height",
        type=int,
        metavar="ROWS",
        help="rows per band (default: about a megapixel per band)",
    )
    enc.add_argument("--mesher", help="mesher: uniform (default: the codec's default)")
    enc.add_argument("-v", "--verbose", action="store_true", help="print a summary line on stderr")
    enc.set_defaults(run=cmd_encode)

    dec = sub.add_parser(
        "decode",
        help="decode an .atm file to an image",
        description=(
            "Decode an .atm file to PNG, PGM/PPM, TIFF or .npy (chosen by the output's "
            "extension or --format). PGM/PPM and .npy output is written band by band as the "
            "input arrives, in memory bounded by the band; PNG and TIFF are assembled in memory."
        ),
        epilog=EPILOG,
    )
    dec.add_argument("input", help=".atm file, or - for standard input")
    dec.add_argument("output", help="image file, or - for standard output (PNG unless --format)")
    dec.add_argument("--backend", default="cpu", help="decoder: cpu (default) or gl (OpenGL via EGL, same pixels)")
    dec.add_argument("--format", choices=["png", "pgm", "ppm", "pnm", "tif", "tiff", "npy"], help="output format")
    dec.set_defaults(run=cmd_decode)

    inf = sub.add_parser(
        "info",
        help="describe an .atm file",
        description="Print an .atm file's size, sample type and mesh statistics.",
        epilog=EPILOG,
    )
    inf.add_argument("input", help=".atm file, or - for standard input")
    inf.add_argument("--json", action="store_true", help="print JSON (width, height, vertices, triangles, bytes, ...)")
    inf.set_defaults(run=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except ATMError as exc:
        if args.debug:
            raise
        print(f"atm: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        return 1
    except KeyboardInterrupt:
        print("atm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
