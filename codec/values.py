"""Vertex values: what each mesh vertex stores, given the image and the triangulation."""

from __future__ import annotations

import numpy as np

from .errors import OptionError

METHODS = ("sample",)


def sample(image: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """The pixel value under each vertex (the seed's choice)."""
    return image[vertices[:, 1], vertices[:, 0]].copy()


def fit(image: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, method: str) -> np.ndarray:
    """Vertex values by `method`, in the image's dtype."""
    if method == "sample":
        return sample(image, vertices)
    raise OptionError(f"unknown values method {method!r}; choose one of {', '.join(METHODS)}")
