"""Safety limits, checked before any allocation. Raise them by assignment if needed:

    import codec.limits
    codec.limits.MAX_IMAGE_PIXELS = 1 << 32
"""

from __future__ import annotations

from .errors import LimitError

#: Largest width x height accepted by the encoder and the decoder (about 268 megapixels).
MAX_IMAGE_PIXELS: int = 1 << 28
#: Largest width or height.
MAX_DIMENSION: int = 1 << 20
#: Largest number of vertices in a mesh, relative to the pixel count (plus a small floor).
MAX_VERTICES_PER_PIXEL: float = 1.0
#: Largest number of triangles in a mesh, relative to the pixel count (plus a small floor).
MAX_TRIANGLES_PER_PIXEL: float = 2.0
#: Largest total row extent of a mesh's triangles (the sum over triangles of the rows
#: each one crosses), relative to the pixel count, plus a floor. It bounds the decoders'
#: work: a hostile file of tall slivers could otherwise cost time far beyond its size.
MAX_TRIANGLE_ROWS_PER_PIXEL: float = 4.0
MIN_TRIANGLE_ROWS: int = 1 << 20
#: Largest decompressed size of one chunk payload, in bytes.
MAX_PAYLOAD_BYTES: int = 1 << 31
#: Largest stored (compressed) chunk length, in bytes.
MAX_CHUNK_BYTES: int = (1 << 31) - 1


def check_image_size(width: int, height: int) -> None:
    """Raise LimitError if an image of this size may not be encoded or decoded."""
    if width > MAX_DIMENSION or height > MAX_DIMENSION:
        raise LimitError(
            f"image is {width}x{height}; the largest side allowed is {MAX_DIMENSION} "
            "(raise codec.limits.MAX_DIMENSION to accept it)"
        )
    if width * height > MAX_IMAGE_PIXELS:
        raise LimitError(
            f"image is {width}x{height} = {width * height:,} pixels, over the limit of "
            f"{MAX_IMAGE_PIXELS:,} (raise codec.limits.MAX_IMAGE_PIXELS to accept it)"
        )


def max_vertices(width: int, height: int) -> int:
    return int(width * height * MAX_VERTICES_PER_PIXEL) + 16


def max_triangles(width: int, height: int) -> int:
    return int(width * height * MAX_TRIANGLES_PER_PIXEL) + 16


def max_triangle_rows(width: int, height: int) -> int:
    return int(width * height * MAX_TRIANGLE_ROWS_PER_PIXEL) + MIN_TRIANGLE_ROWS
