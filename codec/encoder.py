"""Image -> mesh -> bytes: run a mesher on a validated image and pack the result."""

from __future__ import annotations

import importlib
import inspect
import numbers


from . import container
from .errors import OptionError
from .image import as_image
from .mesh import Mesh

#: Mesher name -> module with a `build(image, points, **options) -> Mesh` function.
MESHERS = {"uniform": "codec.uniform"}
DEFAULT_MESHER = "uniform"
#: Vertex density used when no size is asked for (the seed's Lenna setting, 2.8 %).
DEFAULT_DENSITY = 0.028


def default_points(width: int, height: int) -> int:
    return max(4, round(DEFAULT_DENSITY * width * height))


def _mesher(name: str):
    if name not in MESHERS:
        raise OptionError(f"unknown mesher {name!r}; choose one of {', '.join(MESHERS)}")
    return importlib.import_module(MESHERS[name])


def _check_options(build, mesher: str, options: dict) -> None:
    params = inspect.signature(build).parameters
    accepted = [p for p, spec in params.items() if spec.kind == spec.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise OptionError(
            f"mesher {mesher!r} has no option {', '.join(unknown)}; "
            f"its options are: {', '.join(accepted) or 'none'}"
        )


def mesh(image, *, points: int | None = None, mesher: str = DEFAULT_MESHER, **options) -> Mesh:
    """Mesh an image (H x W gray or H x W x 3 RGB, uint8 or uint16).

    points: target vertex count (the result lands within 10 % where the image has that
    many pixels); default 2.8 % of the pixels. Other options go to the mesher.
    """
    img = as_image(image)
    height, width = img.shape[:2]
    if points is None:
        points = default_points(width, height)
    elif isinstance(points, bool) or not isinstance(points, numbers.Integral) or points < 1:
        raise OptionError(f"points must be a positive whole number, not {points!r}")
    module = _mesher(mesher)
    _check_options(module.build, mesher, options)
    return module.build(img, min(int(points), width * height), **options)


def encode(image, *, points: int | None = None, mesher: str = DEFAULT_MESHER, **options) -> bytes:
    """Encode an image as .atm bytes. Same image and options give the same bytes."""
    return container.pack(mesh(image, points=points, mesher=mesher, **options))


def pack(m: Mesh) -> bytes:
    """Encode an existing mesh (validated first) as .atm bytes."""
    return container.pack(m)


__all__ = ["encode", "mesh", "pack", "MESHERS", "DEFAULT_MESHER"]
