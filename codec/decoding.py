"""Mesh -> image: choose a decoder backend."""

from __future__ import annotations

import numpy as np

from .errors import OptionError
from .mesh import Mesh

#: "cpu": exact integer scanline decoder (codec.decoder_cpu), the default.
#: "gl": OpenGL z-buffer decoder (codec.decoder_gl), identical output, needs EGL.
BACKENDS = ("cpu", "gl")


def render(mesh: Mesh, backend: str = "cpu", *, tiles: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """Rasterise a validated mesh with the named backend. tiles=True: mesh.validate
    proved that its triangles tile the image (decoder_cpu.render). out: an array of
    the image's shape and sample type to render into and return (decoder_cpu.check_out;
    the CPU decoder writes it in place, the GL decoder's image is copied in)."""
    if backend == "cpu":
        from . import decoder_cpu

        return decoder_cpu.render(mesh, tiles=tiles, out=out)
    if backend == "gl":
        from . import decoder_cpu, decoder_gl

        if out is None:
            return decoder_gl.render(mesh)
        decoder_cpu.check_out(out, mesh)
        out[...] = decoder_gl.render(mesh)
        return out
    raise OptionError(f"unknown decoder backend {backend!r}; choose one of {', '.join(BACKENDS)}")
