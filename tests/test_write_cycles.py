"""The writer leaves no reference cycle holding a band's data: construct's contexts of
each chunk and payload it builds are freed when the build returns, not when Python's
cyclic collector runs (a long stream's memory would grow with its height)."""

from __future__ import annotations

import gc

import numpy as np
import pytest

import codec


def _cyclic_bytes() -> int:
    """Bytes of the bytes and arrays that objects in reference cycles hold (the cycles
    found by a collection that keeps what it finds)."""
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        gc.collect()
        held = 0
        for o in gc.garbage:
            if isinstance(o, dict):
                held += sum(len(v) if isinstance(v, (bytes, bytearray)) else getattr(v, "nbytes", 0)
                            for v in o.values())
        return held
    finally:
        gc.set_debug(0)
        gc.garbage.clear()


@pytest.mark.parametrize("options", [dict(quality=60, band_height=32), dict(points=4000, band_height=48, nodata=0)])
def test_written_bands_leave_no_cycle_holding_their_data(options):
    rng = np.random.default_rng(3)
    image = np.clip(rng.normal(0, 9, (200, 160, 3)).cumsum(axis=1) + 128, 1, 255).astype(np.uint8)
    if "nodata" in options:
        image = image[:, :, 0].copy()
        image[40:70, 30:90] = 0
    codec.encode(image, **options)  # imports and first-call caches outside the count
    gc.collect()
    was = gc.isenabled()
    gc.disable()
    try:
        data = codec.encode(image, **options)
        assert _cyclic_bytes() < 1024
    finally:
        if was:
            gc.enable()
    assert codec.decode(data).shape == image.shape
