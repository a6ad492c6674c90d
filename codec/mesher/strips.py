"""Image-sized filter chains (smooth, differentiate, combine) run a strip of rows at a
time: each strip's planes stay in the cache between the steps and are reused from one
strip to the next, where whole planes (1.5 MB each at 741 x 500) went through memory
and, on a heap the last encode had given back, faulted in fresh pages.

OpenCV's Gaussian and Sobel filters give every row the same numbers from the rows
around it, and BORDER_REPLICATE repeats the image's own edge rows, so a strip read
with enough rows of context around it gives the whole plane's rows bit for bit
(tests/test_encode_front.py)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

#: Rows a filter chain works on at a time: its strips' planes (a few hundred kB for a
#: 741-pixel row) fit the cache with those of the next step.
ROWS = 128


def gaussian_radius(sigma: float) -> int:
    """The half width of the kernel OpenCV's GaussianBlur makes for float data at
    `sigma` with ksize (0, 0): ksize = round(8 sigma + 1), made odd."""
    return (round(sigma * 8 + 1) | 1) // 2


def strips(height: int, context: int, rows: int | None = None) -> Iterator[tuple[int, int, int, int]]:
    """(y0, y1, a, b) for each strip of rows y0 .. y1 - 1 of an image `height` rows
    high: a .. b - 1 are the rows it reads, `context` more on each side within the
    image. rows: of a strip (default ROWS)."""
    rows = ROWS if rows is None else rows
    for y0 in range(0, height, rows):
        y1 = min(height, y0 + rows)
        yield y0, y1, max(0, y0 - context), min(height, y1 + context)


def smoothed(plane: np.ndarray, sigma: float) -> Iterator[tuple[int, int, np.ndarray, slice]]:
    """(y0, y1, smooth, rows) for each strip of a float32 plane: `smooth` is OpenCV's
    GaussianBlur (BORDER_REPLICATE) of the plane's rows y0 - 1 .. y1 (within the plane),
    the row of context each side a 3 x 3 derivative reads, and smooth[rows] its rows
    y0 .. y1 - 1."""
    import cv2

    height = plane.shape[0]
    for y0, y1, a, b in strips(height, gaussian_radius(sigma) + 1):
        smooth = cv2.GaussianBlur(plane[a:b], (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        top, bottom = max(0, y0 - 1), min(height, y1 + 1)
        yield y0, y1, smooth[top - a : bottom - a], slice(y0 - top, y1 - top)
