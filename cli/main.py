"""`atm`: encode images to .atm and back (one file or many), describe .atm files,
export their meshes and compare images.

Errors print one line, `atm: error: ...`, and exit 1 for bad data, 2 for bad usage.
Output files are written atomically: a failed, interrupted or terminated run leaves no
partial file and does not touch an existing one. An output that is an input is refused,
and so is a name that claims another kind of file (.atm data as x.png) unless --force.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
from pathlib import Path

import codec
from . import batch, convert, outputs, pictures, signals, terminal, tools
from .progress import Progress
from codec import geotiff
from codec.errors import ATMError

EPILOG = "Use - for standard input or output. Run 'atm COMMAND --help' for a command's options."


def cmd_encode(args: argparse.Namespace) -> int:
    if batch.is_batch(args.inputs, args.output):
        return batch.run(args, "encode")
    (source,) = args.inputs
    outputs.refuse_overwriting_inputs([source], [args.output])
    outputs.refuse_misleading_name(args.output, True, args.force)
    terminal.refuse_binary_to_terminal(args.output, "the .atm file", args.force)
    bar = Progress(1, quiet=args.quiet)
    label = f"encoding {Path(source).name if source != '-' else 'standard input'}"

    def show(rows: int, height: int) -> None:
        bar.total = height
        bar.update(rows, f"{label}: {rows:,}/{height:,} rows")

    try:
        enc, written = convert.encode_file(source, args.output, convert.encode_options(args), show if bar.enabled else None)
    finally:
        bar.clear()
    if args.verbose:
        pixels = enc.width * enc.height
        print(
            f"{source} -> {args.output}: {enc.width}x{enc.height}, {enc.bands} band(s), "
            f"{enc.vertices:,} vertices, {enc.triangles:,} triangles, {written:,} bytes "
            f"({8 * written / pixels:.3f} bits/pixel)",
            file=sys.stderr,
        )
    return 0


def cmd_decode(args: argparse.Namespace) -> int:
    if batch.is_batch(args.inputs, args.output):
        return batch.run(args, "decode")
    (source,) = args.inputs
    fmt = convert.output_format(args.output, args.format)
    outputs.refuse_overwriting_inputs([source], [args.output])
    outputs.refuse_misleading_name(args.output, False, args.force, f"{fmt.upper()} data")
    convert.check_output_format(fmt)
    terminal.refuse_binary_to_terminal(args.output, f"the {fmt.upper()} image", args.force)
    written = convert.decode_file(source, args.output, fmt, args.backend)
    if args.verbose:
        print(f"{source} -> {args.output}: {fmt.upper()}, {written:,} bytes", file=sys.stderr)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    with convert.open_input(args.input) as f:
        data = f.read()
    i = codec.info(data)
    if args.json:
        if i["nodata"] is not None and not math.isfinite(i["nodata"]):
            # JSON has no NaN or infinity: their JavaScript names, as strings
            i["nodata"] = "NaN" if math.isnan(i["nodata"]) else ("Infinity" if i["nodata"] > 0 else "-Infinity")
        print(json.dumps(i, indent=2))
    else:
        kind = "gray" if i["channels"] == 1 else "RGB"
        print(f"{args.input}: .atm version {i['version']}, {i['width']}x{i['height']} {kind} {i['dtype']}, {i['bands']} band(s)")
        print(f"  {i['vertices']:,} vertices, {i['triangles']:,} triangles, {i['constraints']:,} walls")
        print(f"  {i['bytes']:,} bytes, {8 * i['bytes'] / (i['width'] * i['height']):.3f} bits/pixel")
        if i["nodata"] is not None:
            print(f"  holes decode to {i['nodata']:g}")
        if i["residual"] is not None:
            what = "lossless" if i["residual"] == 0 else f"every stored sample within {i['residual']}"
            print(f"  residual layer: {what} (the mesh is a preview)")
        else:
            print("  pixels from the mesh alone (no residual layer)")
        if i.get("exact_float") and i["exact_step"] is not None:
            print(f"  float samples stored exactly as steps of {i['exact_step']:.6g} from {i['exact_offset']:.10g} (32 bits)")
        elif i.get("exact_float"):
            print(f"  float samples stored exactly (binary32 bits); the mesh preview in steps of {i['precision']:.6g}")
        elif "precision" in i:
            print(f"  float samples stored in steps of {i['precision']:.6g} from {i['offset']:.10g} (16 bits)")
        for line in geotiff.describe(i["metadata"]):
            print(f"  {line}")
        for key, value in i["metadata"].items():
            if key == geotiff.KEY:
                continue  # shown above in words; --json has the tags themselves
            print(f"  {key}: {json.dumps(value, ensure_ascii=False)}")
    return 0


BATCH_HELP = (
    "Batch: with more than one IN, one IN that is a directory or a glob pattern "
    "(quote it: 'scans/*.png'), or an OUT that is an existing directory, OUT is a directory (created if missing) and each input "
    "NAME.ext becomes {out}; a directory contributes its {kind}. Files are converted in "
    "parallel (--jobs); a file that fails is named and the others still convert (exit 1)."
)


FORCE_HELP = (
    "write even under a name that claims another kind of file (.atm data as x.png, an image as "
    "x.atm), or binary data to a terminal; an output that is one of the inputs is refused all the same"
)


def _add_batch_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("-j", "--jobs", type=int, metavar="N", help="batch: worker processes (default: one per CPU)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and, in batch, no summary line")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)


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
        help="encode images as .atm (one file, or many into a directory)",
        usage="atm encode [options] IN OUT   (or IN -o OUT)\n       atm encode [options] DIR_OR_GLOB... OUTDIR",
        description=(
            "Encode an image as .atm: JPEG, PNG, WebP, GIF or BMP (read through Pillow, upright "
            "as its EXIF orientation says), TIFF or any other format OpenCV reads, PGM/PPM or "
            ".npy. Binary PGM/PPM and .npy input (a file or standard input) is read and encoded "
            "band by band, in memory bounded by the band; other formats are read whole. "
            "On a terminal a long encode shows its progress, within a band too."
        ),
        epilog=BATCH_HELP.format(out="OUTDIR/NAME.atm", kind="image files (.png, .tif, .pgm, .pfm, .jpg, .gif, .npy, ...)") + " " + EPILOG,
    )
    enc.add_argument("inputs", nargs="+", metavar="IN", help="image file, - for standard input, or (batch) directories, glob patterns, files")
    enc.add_argument("output", nargs="?", metavar="OUT", help=".atm file, - for standard output, or (batch) the output directory")
    _add_output_option(enc, ".atm file")
    enc.add_argument("-q", "--quality", type=int, metavar="Q", help="1..100 on JPEG's scale: about JPEG's error at the same quality (an RMS bound; 100 is lossless)")
    enc.add_argument("--points", type=int, metavar="N", help="target vertex count (default: 2.8%% of the pixels); with a bound, the size of the mesh beside the residual layer (not with --no-residual)")
    enc.add_argument("--max-rms", type=float, metavar="E", help="largest RMS error of the decoded image, per channel")
    enc.add_argument("--max-error", type=float, metavar="E", help="largest error of any decoded sample")
    enc.add_argument("--lossless", action="store_true", default=None, help="every valid sample decodes exactly (float data: its binary32 bits); not with a bound")
    enc.add_argument("--residual", action=argparse.BooleanOptionalAction, default=None, help="how --max-error or --max-rms is met: by default (and with --residual) a residual layer, the fewest bytes (the mesh is then a light preview, not within the bound); --no-residual: the mesh alone, within the bound (for 'atm mesh' and terrain tiles)")
    enc.add_argument(
        "--band-height",
        type=int,
        metavar="ROWS",
        help="rows per band (default: about a megapixel per band)",
    )
    enc.add_argument("--precision", type=float, metavar="STEP", help="float data: quantisation step (default: about 2x --max-error when that is the only bound, else the finest 16 bits allow)")
    enc.add_argument("--value-range", type=float, nargs=2, metavar=("LOW", "HIGH"), help="float data: the range of the values (needed when they come from a stream)")
    enc.add_argument("--nodata", type=float, metavar="V", help="samples equal to V are holes, kept exactly (NaN and infinity always are in float data)")
    enc.add_argument("--metadata", metavar="JSON", help='a JSON object stored with the image, e.g. \'{"units": "m"}\'')
    enc.add_argument("--mesher", help="mesher: adaptive or uniform (default: the codec's default)")
    enc.add_argument("--effort", type=int, metavar="E", help="adaptive mesher: 1 (quickest), 2 (default) or 3 (smallest error per byte, about 1.5x slower)")
    enc.add_argument(
        "--alpha", choices=pictures.ALPHA,
        help="an image with alpha (RGBA, gray+alpha): drop it, or flatten onto a white or black background",
    )
    enc.add_argument("--page", type=int, metavar="N", help="a multi-page or animated file: encode page N (from 0)")
    enc.add_argument("-v", "--verbose", action="store_true", help="print a summary line on standard error")
    _add_batch_options(enc)
    enc.set_defaults(run=cmd_encode)

    dec = sub.add_parser(
        "decode",
        help="decode .atm files to images (one file, or many into a directory)",
        usage="atm decode [options] IN OUT   (or IN -o OUT)\n       atm decode [options] DIR_OR_GLOB... OUTDIR",
        description=(
            "Decode an .atm file to PNG, PGM/PPM, TIFF or .npy (chosen by the output's "
            "extension or --format). PGM/PPM and .npy output is written band by band as the "
            "input arrives, in memory bounded by the band; PNG and TIFF are assembled in memory."
        ),
        epilog=BATCH_HELP.format(out="OUTDIR/NAME.png (or --format)", kind=".atm files") + " " + EPILOG,
    )
    dec.add_argument("inputs", nargs="+", metavar="IN", help=".atm file, - for standard input, or (batch) directories, glob patterns, files")
    dec.add_argument("output", nargs="?", metavar="OUT", help="image file, - for standard output (PNG unless --format), or (batch) the output directory")
    _add_output_option(dec, "image file")
    dec.add_argument("--backend", default="cpu", help="decoder: cpu (default) or gl (OpenGL via EGL, same pixels)")
    dec.add_argument("--format", choices=list(convert.OUTPUT_FORMATS), help="output format")
    dec.add_argument("-v", "--verbose", action="store_true", help="print a summary line on standard error")
    _add_batch_options(dec)
    dec.set_defaults(run=cmd_decode)

    msh = sub.add_parser(
        "mesh",
        help="export an .atm file's mesh as OBJ, PLY, SVG, a PNG drawn over the image, or a terrain tile",
        description=(
            "Write the mesh of an .atm file: .obj or .ply (x = column, y = row, z = the value "
            "in data units, e.g. metres; walls as OBJ l-lines / PLY edges), .svg (the "
            "triangulation, walls in red), .png (the decoded image, its pixels with data "
            "stretched, with the triangle edges in blue and walls in red) or .terrain (a "
            "Cesium quantized-mesh-1.0 tile of a longitude/latitude GeoTIFF DEM; walls are "
            "triangle edges)."
        ),
        epilog=EPILOG,
    )
    msh.add_argument("input", help=".atm file, or - for standard input")
    msh.add_argument("output", nargs="?", metavar="OUT", help="OUT.obj, OUT.ply, OUT.svg or OUT.png, or - with --format")
    _add_output_option(msh, "mesh file")
    msh.add_argument("--format", choices=list(tools.MESH_FORMATS), help="output format (default: the extension)")
    msh.add_argument("--scale", type=int, metavar="K", help="PNG: enlarge the image K times (default: to about 1024 pixels)")
    msh.add_argument("--force", action="store_true", help=FORCE_HELP)
    msh.set_defaults(run=tools.cmd_mesh)

    cmp = sub.add_parser(
        "compare",
        help="RMS, PSNR and largest error between two images",
        description=(
            "Compare two images of the same size and sample type, in any format OpenCV reads, "
            ".npy or .atm (decoded): RMS, PSNR (peak: 255, 65535, or the first image's range "
            "for float data) and the largest absolute error, per channel for colour."
        ),
        epilog=EPILOG,
    )
    cmp.add_argument("a", metavar="A", help="the reference image")
    cmp.add_argument("b", metavar="B", help="the image to measure against it")
    cmp.add_argument("--json", action="store_true", help="print JSON (rms, psnr, max_error, ...)")
    cmp.set_defaults(run=tools.cmd_compare)

    inf = sub.add_parser(
        "info",
        help="describe an .atm file",
        description="Print an .atm file's size, sample type and mesh statistics.",
        epilog=EPILOG,
    )
    inf.add_argument("input", help=".atm file, or - for standard input")
    inf.add_argument("--json", action="store_true", help="print JSON (width, height, vertices, triangles, bytes, ...)")
    inf.set_defaults(run=cmd_info)
    for p in sub.choices.values():
        p.add_argument("--version", action="version", version=f"atm {codec.__version__}")
    return parser


def _add_output_option(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("-o", "--output", dest="output_option", metavar="OUT", help=f"the output ({what}), instead of the last argument")


def _resolve_output(parser: argparse.ArgumentParser, args: argparse.Namespace, extra: list[str]) -> None:
    """args.output from -o OUT or else the last argument (with -o every argument is an
    input). argparse leaves the arguments after an option (IN --points 5 OUT) in `extra`."""
    unknown = [a for a in extra if a.startswith("-") and a != "-"]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    rest = ([args.output] if args.output is not None else []) + extra
    given = args.output_option
    usage = f"atm {args.command} IN OUT, or atm {args.command} IN -o OUT"
    if "input" in vars(args):  # atm mesh: one input, one output
        outs = rest + ([given] if given is not None else [])
        if len(outs) != 1:
            parser.error(f"give {'one output' if outs else 'an output'}: {usage}")
        args.output = outs[0]
        return
    paths = args.inputs + rest
    if given is not None:
        args.inputs, args.output = paths, given
    elif len(paths) > 1:
        args.inputs, args.output = paths[:-1], paths[-1]
    else:
        parser.error(f"give an output: {usage}")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if "output_option" in vars(args):
        _resolve_output(parser, args, extra)
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        with signals.terminate_as_exception():
            return args.run(args)
    except ATMError as exc:
        if args.debug:
            raise
        print(f"atm: error: {exc}", file=sys.stderr)
        # bad options are bad usage (argparse's 2); bad data is 1
        return 2 if isinstance(exc, (outputs.UsageError, codec.OptionError)) else 1
    except BrokenPipeError:
        return 1
    except OSError as exc:
        # the file system refused (a directory in the way, a full disk): one line too
        if args.debug:
            raise
        where = f" ({exc.filename})" if exc.filename else ""
        print(f"atm: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("atm: interrupted", file=sys.stderr)
        return 130
    except signals.Terminated:
        print("atm: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
