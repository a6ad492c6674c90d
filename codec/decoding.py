"""Mesh -> image: choose a decoder backend."""

from __future__ import annotations

import numpy as np

from .errors import OptionError
from .mesh import Mesh

BACKENDS = ("cpu",)


def render(mesh: Mesh, backend: str = "cpu") -> np.ndarray:
    """Rasterise a validated mesh with the named backend."""
    if backend == "cpu":
        from . import decoder_cpu

        return decoder_cpu.render(mesh)
    raise OptionError(f"unknown decoder backend {backend!r}; choose one of {', '.join(BACKENDS)}")
