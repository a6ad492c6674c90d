"""Input images: validation and the sample types the container knows."""

from __future__ import annotations

import numpy as np

from . import limits
from .errors import ATMError, UnsupportedError

#: Container sample-type code for each supported numpy dtype.
SAMPLE_TYPES: dict[np.dtype, int] = {np.dtype(np.uint8): 0, np.dtype(np.uint16): 1}
DTYPES: dict[int, np.dtype] = {code: dtype for dtype, code in SAMPLE_TYPES.items()}


def as_image(image, *, allow_nan: bool = False) -> np.ndarray:
    """Return `image` as a C-contiguous H x W or H x W x 3 array of a supported dtype.

    Raises the codec's own errors with a message saying what is wrong.
    """
    if not isinstance(image, np.ndarray):
        try:
            image = np.asarray(image)
        except Exception as exc:  # arbitrary objects: anything numpy cannot take
            raise ATMError(f"cannot read the image as an array: {exc}") from None
    if image.dtype.kind == "b":
        image = image.astype(np.uint8) * 255
    if image.dtype.kind == "f":
        if image.dtype.itemsize < 4:
            image = image.astype(np.float32)
        if not allow_nan and not np.isfinite(image).all():
            raise UnsupportedError("the image holds NaN or infinite values; encode it to keep them as holes")
        if image.ndim == 3 and image.shape[2] != 1:
            raise UnsupportedError("float images must have one channel (e.g. elevations, depths)")
    elif image.dtype not in SAMPLE_TYPES:
        from . import integers

        if not integers.is_signed(image.dtype):
            raise integers.unsupported(image.dtype)
        if image.ndim == 3 and image.shape[2] != 1:
            raise UnsupportedError("signed integer images must have one channel (e.g. elevations)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] != 3:
        raise UnsupportedError(
            f"image has {image.shape[2]} channels; .atm stores 1 (gray) or 3 (RGB)"
        )
    if image.ndim not in (2, 3):
        raise UnsupportedError(
            f"image must be 2-D (gray) or 3-D with 3 channels (RGB); got shape {image.shape}"
        )
    height, width = image.shape[:2]
    if height == 0 or width == 0:
        raise ATMError(f"image is empty (shape {image.shape})")
    limits.check_image_size(width, height)
    return np.ascontiguousarray(image)


def channels(image: np.ndarray) -> int:
    return 1 if image.ndim == 2 else image.shape[2]


def structure(image: np.ndarray) -> np.ndarray:
    """A single-channel float32 view of the image's structure (luma for RGB)."""
    if image.ndim == 2:
        return image.astype(np.float32)
    weights = np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return image.astype(np.float32) @ weights
