"""`atm mesh` (the mesh as OBJ, PLY, SVG or an overlay PNG) and `atm compare`."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

import codec
from . import convert, outputs, terminal
from codec.errors import ATMError, UnsupportedError

MESH_FORMATS = ("obj", "ply", "svg", "png", "terrain")
SIGNATURE = b"\x89ATM\r\n\x1a\n"


def _read_bytes(name: str) -> bytes:
    with convert.open_input(name) as f:
        return f.read()


def cmd_mesh(args: argparse.Namespace) -> int:
    from codec import export, terrain
    from codec.files import atomic_write

    fmt = args.format or Path(args.output).suffix.lstrip(".").lower()
    if fmt not in MESH_FORMATS:
        raise UnsupportedError(
            f"cannot write the mesh as {'.' + fmt if fmt else 'a file without an extension'}; "
            f"use .obj, .ply, .svg, .png or .terrain (or --format)"
        )
    outputs.refuse_overwriting_inputs([args.input], [args.output])
    outputs.refuse_misleading_name(args.output, False, args.force, f"{fmt.upper()} data")
    if fmt in ("png", "ply"):  # OBJ and SVG are text
        terminal.refuse_binary_to_terminal(args.output, f"the {fmt.upper()} file", args.force)
    data = _read_bytes(args.input)
    dem = terrain.load(data)  # z in data units (metres for a float or quantised DEM)
    mesh = dem.mesh
    if codec.info(data)["residual"] is not None:
        print(
            f"atm: note: {args.input} has a residual layer, so its mesh is a light preview, not within the "
            "bound it was encoded to; 'atm encode --no-residual' stores a mesh within the bound",
            file=sys.stderr,
        )
    if fmt == "obj":
        out = export.to_obj(mesh, dem.heights)
    elif fmt == "ply":
        out = export.to_ply(mesh, dem.heights)
    elif fmt == "svg":
        out = export.to_svg(mesh).encode()
    elif fmt == "terrain":
        out = terrain.to_quantized_mesh(dem)
    else:
        scale = args.scale or export.auto_scale(mesh.width, mesh.height)
        out = export.png_bytes(export.overlay_png(mesh, codec.decode(data), scale=scale, nodata=dem.header.nodata))
    if args.output == "-":
        with convert.open_output("-") as f:
            f.write(out)
    else:
        atomic_write(args.output, out)
    return 0


def load_any(name: str) -> np.ndarray:
    """An image from any file OpenCV reads, a .npy, or an .atm (decoded). Camera and web
    pictures are read as `atm encode` reads them (upright by their EXIF orientation,
    alpha dropped), so that a picture compares with the .atm made from it."""
    from codec.files import decode_image

    from . import pictures

    data = _read_bytes(name)
    if data.startswith(SIGNATURE):
        return codec.decode(data)
    if pictures.claims(data[:16]):
        image = pictures.read(data, name, alpha="drop")
        if image is not None:
            return image
    return decode_image(data, name)


def _describe(image: np.ndarray) -> str:
    h, w = image.shape[:2]
    kind = "gray" if image.ndim == 2 else f"{image.shape[2]}-channel"
    return f"{w}x{h} {kind} {image.dtype}"


def compare(a: np.ndarray, b: np.ndarray) -> dict:
    """RMS, PSNR and largest absolute error of b against a, overall and per channel.

    PSNR's peak is the sample type's largest value (255, 65535), or the range of a's
    values for float data; pixels that are NaN (holes) in either image are left out.
    """
    # a gray image compares as gray with or without a channel axis of 1 (ATM.md §4.9)
    a, b = (x[:, :, 0] if x.ndim == 3 and x.shape[2] == 1 else x for x in (a, b))
    for image in (a, b):
        if image.ndim not in (2, 3) or image.dtype.kind not in "uif":
            raise UnsupportedError(
                f"cannot compare an array of shape {image.shape} and type {image.dtype}: "
                "images are 2-D (or 3-D with channels) of integer or float samples"
            )
    if a.shape != b.shape:
        raise ATMError(f"the images differ in shape: {_describe(a)} against {_describe(b)}")
    if a.dtype != b.dtype and not (a.dtype.kind == b.dtype.kind == "f"):
        raise ATMError(
            f"the images differ in sample type: {a.dtype} against {b.dtype}; convert one first"
        )
    fa, fb = a.astype(np.float64), b.astype(np.float64)
    if a.dtype.kind == "f":
        finite = np.isfinite(fa)
        peak = float(fa[finite].max() - fa[finite].min()) if finite.any() else 0.0
    else:
        peak = float(np.iinfo(a.dtype).max)
    diff = fb - fa
    valid = np.isfinite(diff)
    if not valid.any():
        raise ATMError("the images have no pixel where both hold a value")
    flat = diff.reshape(a.shape[0] * a.shape[1], -1)
    mask = valid.reshape(flat.shape)
    per_channel = []
    for c in range(flat.shape[1]):
        d = flat[mask[:, c], c]
        per_channel.append(_stats(d, peak))
    result = _stats(diff[valid], peak)
    result.update(
        width=int(a.shape[1]),
        height=int(a.shape[0]),
        channels=1 if a.ndim == 2 else int(a.shape[2]),
        dtype=str(a.dtype),
        peak=peak,
        pixels_compared=int(valid.all(axis=-1).sum() if a.ndim == 3 else valid.sum()),
    )
    if len(per_channel) > 1:
        result["per_channel"] = per_channel
    return result


def _stats(d: np.ndarray, peak: float) -> dict:
    rms = float(np.sqrt(np.mean(d**2))) if len(d) else 0.0
    # identical images have no finite PSNR; JSON has no infinity, so it is null there
    psnr = 20 * math.log10(peak / rms) if rms > 0 and peak > 0 else None
    return {"rms": rms, "psnr": psnr, "max_error": float(np.abs(d).max()) if len(d) else 0.0}


def cmd_compare(args: argparse.Namespace) -> int:
    r = compare(load_any(args.a), load_any(args.b))
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    psnr = "inf (identical)" if r["psnr"] is None else f"{r['psnr']:.2f} dB"
    print(
        f"{args.a} vs {args.b}: {r['width']}x{r['height']} {r['dtype']}: "
        f"RMS {r['rms']:.4g}, PSNR {psnr}, max error {r['max_error']:.6g}"
    )
    for name, c in zip("RGB", r.get("per_channel", [])):
        cpsnr = "inf" if c["psnr"] is None else f"{c['psnr']:.2f} dB"
        print(f"  {name}: RMS {c['rms']:.4g}, PSNR {cpsnr}, max error {c['max_error']:.6g}")
    return 0
