"""`atm`: encode images to .atm, decode them back, and describe .atm files.

Errors print one line, `atm: error: ...`, and exit 1 for bad data, 2 for bad usage.
Output files are written atomically: a failed run leaves no partial file and does not
touch an existing one.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import codec
from codec.errors import ATMError

EPILOG = "Use - for standard input or output. Run 'atm COMMAND --help' for a command's options."


def _read_input(name: str) -> bytes:
    if name == "-":
        return sys.stdin.buffer.read()
    try:
        return Path(name).read_bytes()
    except OSError as exc:
        raise ATMError(f"cannot read {name}: {exc.strerror}") from None


def _write_output(name: str, data: bytes) -> None:
    if name == "-":
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
        return
    from codec.files import atomic_write

    try:
        atomic_write(name, data)
    except OSError as exc:
        raise ATMError(f"cannot write {name}: {exc.strerror}") from None


def cmd_encode(args: argparse.Namespace) -> int:
    from codec.files import decode_image

    image = decode_image(_read_input(args.input), args.input)
    options = {}
    if args.mesher:
        options["mesher"] = args.mesher
    data = codec.encode(image, points=args.points, **options)
    _write_output(args.output, data)
    if args.verbose:
        i = codec.info(data)
        print(
            f"{args.input} -> {args.output}: {i['width']}x{i['height']}, {i['vertices']:,} vertices, "
            f"{i['triangles']:,} triangles, {i['bytes']:,} bytes "
            f"({8 * i['bytes'] / (i['width'] * i['height']):.3f} bits/pixel)",
            file=sys.stderr,
        )
    return 0


def cmd_decode(args: argparse.Namespace) -> int:
    from codec.files import encode_image

    image = codec.decode(_read_input(args.input), backend=args.backend)
    ext = "." + args.format if args.format else (Path(args.output).suffix or ".png")
    if args.output == "-" and not args.format:
        ext = ".png"
    _write_output(args.output, encode_image(image, ext))
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    i = codec.info(_read_input(args.input))
    if args.json:
        print(json.dumps(i, indent=2))
    else:
        kind = "gray" if i["channels"] == 1 else "RGB"
        print(f"{args.input}: .atm version {i['version']}, {i['width']}x{i['height']} {kind} {i['dtype']}")
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
        description="Encode an image (any format OpenCV reads, or .npy) as .atm.",
        epilog=EPILOG,
    )
    enc.add_argument("input", help="image file, or - for standard input")
    enc.add_argument("output", help=".atm file, or - for standard output")
    enc.add_argument("--points", type=int, metavar="N", help="target vertex count (default: 2.8%% of the pixels)")
    enc.add_argument("--mesher", help="mesher: uniform (default: the codec's default)")
    enc.add_argument("-v", "--verbose", action="store_true", help="print a summary line on stderr")
    enc.set_defaults(run=cmd_encode)

    dec = sub.add_parser(
        "decode",
        help="decode an .atm file to an image",
        description="Decode an .atm file to PNG, PGM/PPM or TIFF (chosen by the output's extension).",
        epilog=EPILOG,
    )
    dec.add_argument("input", help=".atm file, or - for standard input")
    dec.add_argument("output", help="image file, or - for standard output (PNG unless --format)")
    dec.add_argument("--backend", default="cpu", help="decoder: cpu (default)")
    dec.add_argument("--format", choices=["png", "pgm", "ppm", "tif", "tiff"], help="output format")
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
