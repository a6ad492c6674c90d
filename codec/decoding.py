"""Mesh -> image: choose a decoder backend."""

from __future__ import annotations

import numpy as np

from .errors import OptionError
from .mesh import Mesh

#: "cpu": exact integer scanline decoder (codec.decoder_cpu), the default.
#: "gl": OpenGL z-buffer decoder (codec.decoder_gl), identical output, needs EGL.
BACKENDS = ("cpu", "gl")


def render(mesh: Mesh, backend: str = "cpu", *, tiles: bool = False) -> np.ndarray:
    """Rasterise a validated mesh with the named backend. tiles=True: mesh.validate
    proved that its triangles tile the image (decoder_cpu.render)."""
    if backend == "cpu":
        from . import decoder_cpu

        return decoder_cpu.render(mesh, tiles=tiles)
    if backend == "gl":
        from . import decoder_gl

        return decoder_gl.render(mesh)
    raise OptionError(f"unknown decoder backend {backend!r}; choose one of {', '.join(BACKENDS)}")
