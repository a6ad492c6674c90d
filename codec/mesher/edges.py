"""Stage 1: edge detection with OpenCV's Canny, thresholds chosen from the image.

Thresholds are in gray levels of an 8-bit scale (uint16 images are scaled down by
257): the height a sharp step must have for its pixel to count as an edge. The
gradient is a Sobel derivative of the lightly smoothed image, divided by 4 so that a
sharp step of height h gives a gradient of about h.
"""

from __future__ import annotations

import numpy as np

from . import strips
from .. import native
from ..errors import OptionError

#: Gaussian smoothing before differentiation; keeps texture and noise from breaking
#: edges into fragments without moving sharp steps by more than a pixel.
SIGMA = 1.0
#: Lowest automatic high threshold: steps fainter than this are not worth a wall.
MIN_HIGH = 12.0
#: Highest automatic high threshold: a sharp step of about 2.5 times this many gray
#: levels always gets a wall, however strong the image's other edges are.
MAX_HIGH = 20.0
#: Fixed-point scale of the int16 derivatives handed to cv2.Canny.
_SCALE = 16.0


def gradient(gray: np.ndarray, peak: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(magnitude, ix, iy) of a float image whose full scale is `peak`: the gradient
    magnitude (float32, 8-bit gray levels per step) and the derivatives in Canny's
    fixed point (int16, _SCALE per level, clipped to fit), from one compiled pass over
    OpenCV's Sobel derivatives (codec._gradients.edge_gradient)."""
    import cv2

    # one pass: the float32 product numpy's astype-then-multiply made in two; none for
    # 8-bit data, whose product by 1 is the plane itself (GaussianBlur only reads it)
    g = gray if peak == 255 and gray.dtype == np.float32 else np.multiply(gray, np.float32(255.0 / peak), dtype=np.float32)
    h, w = g.shape
    mag = np.empty((h, w), np.float32)
    ix = np.empty((h, w), np.int16)
    iy = np.empty((h, w), np.int16)
    # a strip of rows at a time (codec.mesher.strips)
    for y0, y1, smooth, k in strips.smoothed(g, SIGMA):
        sx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
        sy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
        # not cv2.magnitude: its result differs in the last bit with the arrays' memory
        # alignment (vector and scalar code paths), which made the thresholds and the
        # wall selection, and so the bytes, vary from run to run
        native._gradients.edge_gradient(sx[k], sy[k], 32767 / _SCALE, _SCALE, out=mag[y0:y1],
                                        ix_out=ix[y0:y1], iy_out=iy[y0:y1])
    return mag, ix, iy


def auto_thresholds(magnitude: np.ndarray) -> tuple[float, float]:
    """(low, high): high by Otsu's method on the gradient magnitudes (the split between
    flat-or-textured pixels and edge pixels), at least MIN_HIGH; low = high / 2."""
    top = float(magnitude.max())
    if top <= 0:
        return MIN_HIGH / 2, MIN_HIGH
    # cv2.threshold(THRESH_OTSU) of the levels, clip(magnitude * float32(255 / top), 0,
    # 255) as uint8, in one compiled pass: no level image, and no OpenCV threads
    otsu = native._gradients.otsu_level(np.ascontiguousarray(magnitude, dtype=np.float32), np.float32(255.0 / top))
    high = min(max(MIN_HIGH, float(otsu) * top / 255.0), MAX_HIGH)
    return high / 2, high


def check_thresholds(canny) -> tuple[float, float] | None:
    """Validate a user's `canny=(low, high)` option (None: automatic)."""
    if canny is None:
        return None
    try:
        low, high = (float(c) for c in canny)
    except (TypeError, ValueError):
        raise OptionError(f"canny must be a pair (low, high) of gray levels, not {canny!r}") from None
    if not (0 < low <= high) or not np.isfinite(high):
        raise OptionError(f"canny thresholds need 0 < low <= high, got ({low}, {high})")
    return low, high


def detect(gray: np.ndarray, peak: float, canny: tuple[float, float] | None = None):
    """Canny edges of a float image of full scale `peak`.

    Returns (edges: H x W bool, magnitude: H x W float32, (low, high) used).
    """
    mag, ix, iy = gradient(gray, peak)
    low, high = canny if canny is not None else auto_thresholds(mag)
    # cv2.Canny(ix, iy, ..., L2gradient=True) > 0, which compares |(dx, dy)| against
    # the thresholds, in one thread: OpenCV's own threads cost more CPU than they save
    edges = native._gradients.canny(ix, iy, low * _SCALE, high * _SCALE)
    return edges, mag, (low, high)
