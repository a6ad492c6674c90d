"""What the fuzzers run on each input: every public way of reading .atm bytes."""

from __future__ import annotations

import codec


def run_one(data: bytes) -> bool:
    """Decode `data` every way a user can; only codec.ATMError may escape.
    Returns whether it decoded."""
    try:
        codec.info(data)
    except codec.ATMError:
        return False
    try:
        image = codec.decode(data)
    except codec.ATMError:
        return False
    info = codec.info(data)
    expected = (info["height"], info["width"]) + ((info["channels"],) if info["channels"] > 1 else ())
    if image.shape != expected:
        raise AssertionError(f"decoded shape {image.shape}, header says {expected}")
    return True
