"""Image -> mesh -> bytes: run a mesher on a validated image and pack the result."""

from __future__ import annotations

import importlib
import io
import inspect
import numbers

import numpy as np

from . import container, integers, quantise
from .errors import OptionError
from .image import as_image
from .mesh import Mesh

#: Mesher name -> module with a `build(image, points, **options) -> Mesh` function.
MESHERS = {"adaptive": "codec.mesher.adaptive", "uniform": "codec.mesher.uniform"}
DEFAULT_MESHER = "adaptive"
#: Vertex density used when no size is asked for (the seed's Lenna setting, 2.8 %).
DEFAULT_DENSITY = 0.028


#: Vertex density of the starting mesh when refinement to a bound decides the size.
START_DENSITY = 0.002


def default_points(width: int, height: int) -> int:
    return max(4, round(DEFAULT_DENSITY * width * height))


def start_points(width: int, height: int) -> int:
    return max(4, round(START_DENSITY * width * height))


def values_method(build, options: dict) -> str:
    """How the mesher picks vertex values (its `values` option), so that refinement
    picks new ones the same way."""
    if "values" in options:
        return options["values"]
    param = inspect.signature(build).parameters.get("values")
    return param.default if param is not None else "sample"


def _mesher(name: str):
    if name not in MESHERS:
        raise OptionError(f"unknown mesher {name!r}; choose one of {', '.join(MESHERS)}")
    return importlib.import_module(MESHERS[name])


def mesher_build(name: str, options: dict):
    """The named mesher's `build(image, points, **options)`, once `options` are checked."""
    build = _mesher(name).build
    params = inspect.signature(build).parameters
    accepted = [p for p, spec in params.items() if spec.kind == spec.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise OptionError(
            f"mesher {name!r} has no option {', '.join(unknown)}; "
            f"its options are: {', '.join(accepted) or 'none'}"
        )
    return build


def _check_points(points) -> None:
    if isinstance(points, bool) or not isinstance(points, numbers.Integral) or points < 1:
        raise OptionError(f"points must be a positive whole number, not {points!r}")


def mesh(image, *, points: int | None = None, mesher: str = DEFAULT_MESHER, **options) -> Mesh:
    """Mesh a whole image (H x W gray or H x W x 3 RGB, uint8 or uint16) in one piece.

    points: target vertex count (the result lands within 10 % where the image has that
    many pixels); default 2.8 % of the pixels. Other options go to the mesher.
    """
    img = as_image(image)
    height, width = img.shape[:2]
    if points is None:
        points = default_points(width, height)
    _check_points(points)
    build = mesher_build(mesher, options)
    return build(img, min(int(points), width * height), **options)


def encode(
    image,
    *,
    points: int | None = None,
    mesher: str = DEFAULT_MESHER,
    band_height: int | None = None,
    mask=None,
    **options,
) -> bytes:
    """Encode an image as .atm bytes, band by band (see codec.StreamEncoder for the
    size knobs). Same image and options give the same bytes."""
    from .stream import StreamEncoder

    img = as_image(image, allow_nan=True)
    height, width = img.shape[:2]
    holes = None
    if mask is not None:
        holes = np.asarray(mask, dtype=bool)
        if holes.shape != (height, width):
            raise OptionError(f"mask must have shape {(height, width)}, not {holes.shape}")
        if img.dtype.kind != "f" and options.get("nodata") is None:
            options["nodata"] = 0
    if img.dtype.kind == "f":
        # the header carries nodata and the quantisation: both come from the data here
        if options.get("nodata") is None:
            options["nodata"] = quantise.hole_value([img[~np.isfinite(img) | (False if holes is None else holes)]])
        if "value_range" not in options:
            nodata = quantise.check_nodata(options["nodata"])
            options["value_range"] = quantise.data_range([img if holes is None else img[~holes]], nodata)
    elif integers.is_signed(img.dtype) and "value_range" not in options:
        options["value_range"] = integers.value_range([img if holes is None else img[~holes]], options.get("nodata"))
    out = io.BytesIO()
    enc = StreamEncoder(
        out,
        width,
        height,
        dtype=img.dtype,
        channels=1 if img.ndim == 2 else img.shape[2],
        band_height=band_height,
        points=points,
        mesher=mesher,
        **options,
    )
    enc.write(img, holes=holes)
    enc.close()
    return out.getvalue()


def pack(m: Mesh) -> bytes:
    """Encode an existing mesh (validated first) as .atm bytes."""
    return container.pack(m)
