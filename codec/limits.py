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
#: Largest decoded image, in bytes (width x height x channels x bytes per sample, float
#: data counting 4): a gray float32 image at MAX_IMAGE_PIXELS.
MAX_IMAGE_BYTES: int = 1 << 30
#: Largest total of a file's metadata (all its meta chunks, decompressed), in bytes.
MAX_METADATA_BYTES: int = 1 << 20
#: Deepest nesting of arrays and objects in metadata JSON.
MAX_METADATA_DEPTH: int = 64
#: Largest decompressed size a MESH or MASK frame may declare relative to its stored
#: (compressed) bytes, plus a floor. zstd lets a few hundred bytes declare gigabytes;
#: this keeps a decoder's work proportional to the bytes it is given. The encoder
#: refuses a band that would exceed it.
MAX_PAYLOAD_EXPANSION: int = 1024
MIN_PAYLOAD_LIMIT: int = 1 << 20
#: Most vertices of a band whose triangles the decoder rebuilds (Delaunay connectivity),
#: relative to its MESH chunk's stored bytes, plus a floor: rebuilding costs some 0.3 KB
#: and 1 us per vertex. The encoder lists the triangles of a band beyond it.
MAX_REBUILT_VERTICES_PER_BYTE: int = 64
MIN_REBUILT_VERTICES: int = 1 << 16


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


def check_image_bytes(width: int, height: int, channels: int, sample_bytes: int) -> None:
    """Raise LimitError if the decoded image would take more than MAX_IMAGE_BYTES."""
    size = width * height * channels * sample_bytes
    if size > MAX_IMAGE_BYTES:
        raise LimitError(
            f"a {width}x{height} image of {channels} channel(s) of {sample_bytes}-byte samples "
            f"takes {size:,} bytes, over the limit of {MAX_IMAGE_BYTES:,} "
            "(raise codec.limits.MAX_IMAGE_BYTES to accept it)"
        )


def max_rebuilt_vertices(stored_bytes: int) -> int:
    return MIN_REBUILT_VERTICES + MAX_REBUILT_VERTICES_PER_BYTE * stored_bytes


def max_payload(stored_bytes: int) -> int:
    return MIN_PAYLOAD_LIMIT + MAX_PAYLOAD_EXPANSION * stored_bytes


def max_vertices(width: int, height: int) -> int:
    return int(width * height * MAX_VERTICES_PER_PIXEL) + 16


def max_triangles(width: int, height: int) -> int:
    return int(width * height * MAX_TRIANGLES_PER_PIXEL) + 16


def max_triangle_rows(width: int, height: int) -> int:
    return int(width * height * MAX_TRIANGLE_ROWS_PER_PIXEL) + MIN_TRIANGLE_ROWS
