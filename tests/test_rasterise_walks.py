"""Every walk the rasteriser can take on this processor (codec._rasterise.WALKS: the
AVX-512 one, the AVX2 one, the portable one) gives the same pixels and statuses."""

from __future__ import annotations

import numpy as np
import pytest

from codec.native import _rasterise
from tests.test_decoders import _walk_meshes


def test_rasterise_lists_its_walks_fastest_first() -> None:
    """WALKS names what this processor runs, the default first; the portable walk is
    always there, and a walk it cannot take is refused by name."""
    walks = _rasterise.WALKS
    assert walks[-1] == "portable"
    assert ("avx512" in walks) == _rasterise.AVX512 and ("avx2" in walks) == _rasterise.AVX2
    assert walks[0] == ("avx512" if _rasterise.AVX512 else "avx2" if _rasterise.AVX2 else "portable")
    v = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.int64)
    t = np.array([[0, 1, 2], [1, 3, 2]], np.int64)
    out = np.zeros((4, 1), np.uint8)
    with pytest.raises(ValueError, match="walk 'sse9' is not one of"):
        _rasterise.rasterise(v, np.zeros((4, 1), np.uint8), t, out, 2, 2, walk="sse9")


def test_every_walk_gives_the_portable_walks_pixels() -> None:
    """Random meshes of 2 to 5,000 pixels a row (spans of 0 to hundreds of samples,
    triangles on the image's last bytes, where the AVX2 walk's merged word would pass
    the image's end), a third of them broken: each walk writes the same samples
    (those outside every triangle left as they were) with the same status, with both
    coverage checks, 8- and 16-bit, one and three channels, int64 and int32 corners."""
    rng = np.random.default_rng(2417)
    checks = (_rasterise.Check.CHECK_TOTAL, _rasterise.Check.CHECK_SPANS)
    walks = _rasterise.WALKS
    for w, h, vertices, triangles in _walk_meshes(rng):
        for dtype, channels in ((np.uint8, 1), (np.uint16, 1), (np.uint8, 3)):
            top = int(np.iinfo(dtype).max)
            values = rng.integers(0, top + 1, (len(vertices), channels)).astype(dtype)
            values[rng.random(len(vertices)) < 0.2] = top
            first = rng.integers(0, top + 1, (w * h, channels)).astype(dtype)
            for check in checks:
                expected = first.copy()
                status = _rasterise.rasterise(vertices, values, triangles, expected, w, h, check, walk="portable")
                for walk in walks:
                    for corners in (triangles, triangles.astype(np.int32)):
                        out = first.copy()
                        got = _rasterise.rasterise(vertices, values, corners, out, w, h, check, walk=walk)
                        assert got == status, (walk, w, h, dtype, channels, check)
                        assert np.array_equal(out, expected), (walk, w, h, dtype, channels, check)


def _at_page_end(count: int, dtype) -> tuple[np.ndarray, object]:
    """An array of `count` samples that ends where a readable page does, the next page
    unreadable (Linux): a walk that reads or writes past the image's end faults."""
    import ctypes
    import mmap

    size = mmap.PAGESIZE * (2 + count * np.dtype(dtype).itemsize // mmap.PAGESIZE)
    memory = mmap.mmap(-1, size)
    base = ctypes.addressof(ctypes.c_char.from_buffer(memory))
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    assert libc.mprotect(base + size - mmap.PAGESIZE, mmap.PAGESIZE, 0) == 0  # PROT_NONE
    nbytes = count * np.dtype(dtype).itemsize
    return np.frombuffer(memory, dtype, count, size - mmap.PAGESIZE - nbytes), memory


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="mprotect through ctypes")
def test_every_walk_fills_the_last_bytes_of_an_image() -> None:
    """Images 2 to 9 pixels wide, whose every row's span lies within the last 8 (or
    16) bytes of the image on the bottom rows: the AVX2 walk copies those samples one
    by one instead of merging a word that would pass the end. The image ends where a
    readable page does: a read or write past it faults."""
    from codec.triangulate import delaunay

    rng = np.random.default_rng(7)
    for w in range(2, 10):
        for h in (2, 3, 7):
            pts = {(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)}
            pts |= set(zip(rng.integers(0, w, 4).tolist(), rng.integers(0, h, 4).tolist()))
            vertices = np.array(sorted(pts, key=lambda p: (p[1], p[0])), np.int64)
            triangles = np.ascontiguousarray(delaunay(vertices), dtype=np.int64)
            for dtype in (np.uint8, np.uint16):
                values = rng.integers(0, int(np.iinfo(dtype).max) + 1, (len(vertices), 1)).astype(dtype)
                results = []
                for walk in _rasterise.WALKS:
                    flat, memory = _at_page_end(w * h, dtype)
                    out = flat.reshape(w * h, 1)
                    assert _rasterise.rasterise(vertices, values, triangles, out, w, h,
                                                _rasterise.Check.CHECK_TOTAL, walk=walk) == (0, 0)
                    results.append(out.copy())
                    del flat, out
                    memory.close()
                for walk, out in zip(_rasterise.WALKS, results):
                    assert np.array_equal(out, results[-1]), (walk, w, h, dtype)
