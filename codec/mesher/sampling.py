"""Stage 4: region sampling driven by curvature (section 3.3.2.1 of the paper
"Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes", which
applies the adaptive sampling of its section 3.3.1.1 between the edges).

A curvature image (the norm of the Hessian of the smoothed image: how much the image
surface bends, which is where a piecewise-linear surface needs its vertices) gives a
sample density, raised to a power and mixed with a small uniform floor so that flat
regions are still covered. Pixels on or next to edges get no density: the walls
already model them. The image is cut into H x V tiles; in every tile R columns are
chosen so that equal amounts of density lie between them (inverse-CDF sampling of the
column sums), and along each chosen column Z samples are placed the same way. Samples
that still land on an excluded pixel are dropped.
"""

from __future__ import annotations

import numpy as np

from . import strips
from .. import native
from ..errors import OptionError

#: Smoothing of the image before its second derivatives are taken.
SIGMA = 1.5
#: Density = curvature ** POWER, scaled to mean 1, plus FLOOR.
POWER = 0.5
FLOOR = 0.25


def curvature(gray: np.ndarray) -> np.ndarray:
    """Frobenius norm of the Hessian of the Gaussian-smoothed image (float32; the norm
    in one compiled pass, codec._gradients.hessian_norm)."""
    import cv2

    g = gray.astype(np.float32, copy=False)
    h, w = g.shape
    norm = np.empty((h, w), np.float32)
    # a strip of rows at a time (codec.mesher.strips), as edges.gradient
    for y0, y1, smooth, k in strips.smoothed(g, SIGMA):
        dxx, dyy, dxy = (cv2.Sobel(smooth, cv2.CV_32F, dx, dy, ksize=3, borderType=cv2.BORDER_REPLICATE)
                         for dx, dy in ((2, 0), (0, 2), (1, 1)))
        native._gradients.hessian_norm(dxx[k], dyy[k], dxy[k], out=norm[y0:y1])
    return norm


def density(curv: np.ndarray, excluded: np.ndarray, power: float = POWER, floor: float = FLOOR) -> np.ndarray:
    """Sample density (float64): curvature ** power scaled to mean 1, plus a floor,
    and zero on excluded pixels."""
    if power == 0.5 and curv.dtype == np.float32:
        # two compiled passes, the numbers of the numpy steps below (x ** 0.5 is numpy's
        # square root; the mean numpy's pairwise sum of the same values in the same
        # order, without the array of them, up to 3 MB at 741 x 500)
        mask = np.ascontiguousarray(excluded, dtype=bool).view(np.uint8)
        d, mean = native._gradients.density_roots(np.ascontiguousarray(curv), mask)
        native._gradients.density_scale(d, mask, mean, floor)
        return d
    # in place where numpy made a temporary per step (the same operations: x ** 0.5 is
    # numpy's square root)
    d = np.sqrt(curv, dtype=np.float64) if power == 0.5 else curv.astype(np.float64) ** power
    free = ~excluded
    mean = d[free].mean() if free.any() else 0.0
    if mean > 0:
        np.divide(d, mean, out=d)
    else:
        d[...] = 0.0
    np.add(d, floor, out=d)
    d[excluded] = 0.0
    return d


def check_pair(value, name: str) -> tuple[int, int]:
    """Validate a pair option of positive whole numbers, e.g. tiles=(H, V)."""
    try:
        a, b = value
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be a pair of whole numbers, not {value!r}") from None
    for v in (a, b):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise OptionError(f"{name} must be a pair of whole numbers >= 1, not {value!r}")
    return int(a), int(b)


#: Most region samples asked for a pixel: more can only repeat pixels (and their count
#: would overflow the sampling kernel's buffer sizes long before memory runs out).
_SAMPLES_A_PIXEL = 16
#: ... unless there are fewer than this many in all (small images, many tiles).
_SAMPLES_ANY = 1 << 24


def sample(dens: np.ndarray, tiles: tuple[int, int], per_tile: tuple[int, int]) -> np.ndarray:
    """Sample pixels (N x 2 int64 (x, y), distinct, in scan-line order) of a density."""
    h, w = dens.shape
    nh, nv = min(tiles[0], w), min(tiles[1], h)
    r, z = per_tile
    asked = nh * nv * int(r) * int(z)  # exact in Python integers: the kernel's sizes are such products
    if asked > max(_SAMPLES_A_PIXEL * h * w, _SAMPLES_ANY):
        raise OptionError(f"per_tile {tuple(per_tile)} asks for {asked:,} region samples in a {w}x{h} image, more "
                          f"than {_SAMPLES_A_PIXEL} a pixel; choose fewer")
    xb = np.round(np.linspace(0, w, nh + 1)).astype(np.int64)
    yb = np.round(np.linspace(0, h, nv + 1)).astype(np.int64)
    # tile row after tile row in one compiled pass (_inverse_cdf's arithmetic on the
    # column sums, then down the chosen columns: the same pixels)
    pts = native._gradients.tile_samples(np.ascontiguousarray(dens, dtype=np.float64), xb, yb, int(r), int(z))
    if not len(pts):
        return np.zeros((0, 2), np.int64)
    pts = pts[dens[pts[:, 1], pts[:, 0]] > 0]
    # sorted and deduplicated by hand: np.unique's hash table took 0.5 ms for 7,000 keys
    key = np.sort(pts[:, 1] * w + pts[:, 0])
    key = key[np.r_[True, key[1:] != key[:-1]]]
    return np.stack([key % w, key // w], axis=1).astype(np.int64)
