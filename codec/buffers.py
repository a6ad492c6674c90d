"""The bytes of any buffer the decode functions take (codec.Buffer)."""

from __future__ import annotations

import os

from .errors import ATMError


def as_bytes(data: object, limit: int | None = None) -> bytes:
    """The bytes of any buffer (the first `limit` of them), or an ATMError saying what
    is accepted."""
    try:
        view = memoryview(data)
    except TypeError:
        hint = "; to decode a file by name use codec.read(path)" if isinstance(data, (str, os.PathLike)) else ""
        raise ATMError(
            f"expected .atm data (bytes, bytearray, memoryview, a numpy uint8 array or an mmap), "
            f"got {type(data).__name__}{hint}"
        ) from None
    with view:
        if not view.contiguous:
            raise ATMError("the .atm data buffer is not contiguous; pass a contiguous copy (e.g. bytes(data))")
        flat = view.cast("B") if view.format != "B" or view.ndim != 1 else view
        return flat[:limit].tobytes() if limit is not None else flat.tobytes()
