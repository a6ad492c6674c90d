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

    from .. import native

    g = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), SIGMA, borderType=cv2.BORDER_REPLICATE)
    dxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    dyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3, borderType=cv2.BORDER_REPLICATE)
    dxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    return native._gradients.hessian_norm(dxx, dyy, dxy)


def density(curv: np.ndarray, excluded: np.ndarray, power: float = POWER, floor: float = FLOOR) -> np.ndarray:
    """Sample density (float64): curvature ** power scaled to mean 1, plus a floor,
    and zero on excluded pixels."""
    d = curv.astype(np.float64) ** power
    free = ~excluded
    mean = d[free].mean() if free.any() else 0.0
    d = (d / mean if mean > 0 else np.zeros_like(d)) + floor
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


def _inverse_cdf(cum: np.ndarray, lo: np.ndarray, hi: np.ndarray, k) -> tuple[np.ndarray, np.ndarray]:
    """For each interval [lo, hi) of a cumulative sum `cum` (1-D), the k positions
    (k: one count, or one per interval) splitting its mass into k equal shares, at
    the middle of each share. Returns (interval of each position, position)."""
    k = np.broadcast_to(np.asarray(k, dtype=np.int64), lo.shape)
    base = np.where(lo > 0, cum[np.maximum(lo - 1, 0)], 0.0)
    total = cum[hi - 1] - base
    which = np.repeat(np.arange(len(lo)), k)
    j = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    targets = base[which] + (j + 0.5) / k[which] * total[which]
    pos = np.searchsorted(cum, targets, side="left")
    return which, np.clip(pos, lo[which], hi[which] - 1)


def sample(dens: np.ndarray, tiles: tuple[int, int], per_tile: tuple[int, int]) -> np.ndarray:
    """Sample pixels (N x 2 int64 (x, y), distinct, in scan-line order) of a density."""
    h, w = dens.shape
    nh, nv = min(tiles[0], w), min(tiles[1], h)
    r, z = per_tile
    xb = np.round(np.linspace(0, w, nh + 1)).astype(np.int64)
    yb = np.round(np.linspace(0, h, nv + 1)).astype(np.int64)
    out = []
    for y0, y1 in zip(yb[:-1], yb[1:]):
        block = dens[y0:y1]
        # each column's sum down the band, row after row (the last row of its cumsum;
        # a sum over axis 0 adds whole rows in turn, unless a row is a single number)
        colsum = block.sum(axis=0) if block.shape[1] > 1 else np.cumsum(block, axis=0)[-1]
        _, cols = _inverse_cdf(np.cumsum(colsum), xb[:-1], xb[1:], r)
        cols = cols[colsum[cols] > 0]
        if len(cols) == 0:
            continue
        # a column chosen m times carries m * z samples
        cols, mult = np.unique(cols, return_counts=True)
        height = y1 - y0
        col_cum = np.cumsum(block[:, cols], axis=0).T  # C x height: down the chosen columns
        # stack the columns' cumulative sums into one increasing sequence
        offset = np.cumsum(np.concatenate([[0.0], col_cum[:-1, -1] + 1.0]))
        lo = np.arange(len(cols)) * height
        which, pos = _inverse_cdf((col_cum + offset[:, None]).ravel(), lo, lo + height, mult * z)
        out.append(np.stack([cols[which], pos - lo[which] + y0], axis=1))
    if not out:
        return np.zeros((0, 2), np.int64)
    pts = np.concatenate(out)
    pts = pts[dens[pts[:, 1], pts[:, 0]] > 0]
    key = np.unique(pts[:, 1] * w + pts[:, 0])
    return np.stack([key % w, key // w], axis=1).astype(np.int64)
