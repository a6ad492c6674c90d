"""The encoder's front and writing kernels give exactly what the code they replace
gave: Canny and Otsu's threshold without OpenCV's thread pool (codec._gradients.canny,
.otsu_level), the chain ordering's word scan and code tables, compiled varints."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from codec import native
from codec.image import structure
from codec.mesher import adaptive, edges
from tests.corpus import load_corpus


def _cases(seed: int, count: int):
    """(ix, iy, low, high): random derivatives (small, full int16 range, and those of
    smoothed noise) with thresholds on their scale."""
    rng = np.random.default_rng(seed)
    for t in range(count):
        h, w = (int(v) for v in rng.integers(1, 48, 2))
        kind = t % 3
        if kind == 0:
            ix, iy = (rng.integers(-400, 400, (h, w)).astype(np.int16) for _ in range(2))
            scale = 300
        elif kind == 1:
            img = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 2.0)
            _, ix, iy = edges.gradient(img, 255.0)
            scale = 300
        else:
            ix, iy = (rng.integers(-32768, 32768, (h, w)).astype(np.int16) for _ in range(2))
            scale = 40000
        low, high = sorted(float(v) for v in rng.random(2) * scale)
        yield ix, iy, low, high


def test_canny_gives_opencvs_edges_on_random_derivatives():
    for ix, iy, low, high in _cases(20, 1500):
        want = cv2.Canny(ix, iy, low, high, L2gradient=True) > 0
        got = native._gradients.canny(ix, iy, low, high)
        assert got.dtype == bool and np.array_equal(got, want), (ix.shape, low, high)


@pytest.mark.parametrize("name", ["camera", "coins", "moon", "text", "astronaut", "motorcycle_disp"])
def test_detect_gives_opencvs_edges_and_threshold_on_the_corpus(name):
    gray = structure(load_corpus()[name])
    mag, ix, iy = edges.gradient(gray, 255.0)
    top = float(mag.max())
    levels = np.clip(np.multiply(mag, np.float32(255.0 / top)), 0, 255).astype(np.uint8)
    otsu, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    assert native._gradients.otsu_level(mag, np.float32(255.0 / top)) == otsu
    found, _, (low, high) = edges.detect(gray, 255.0)
    assert np.array_equal(found, cv2.Canny(ix, iy, low * 16, high * 16, L2gradient=True) > 0)
    # and with the thresholds swapped, as OpenCV swaps them
    assert np.array_equal(native._gradients.canny(ix, iy, high * 16, low * 16),
                          cv2.Canny(ix, iy, high * 16, low * 16, L2gradient=True) > 0)


def test_otsu_level_gives_opencvs_threshold_on_random_magnitudes():
    rng = np.random.default_rng(21)
    for t in range(1500):
        h, w = (int(v) for v in rng.integers(1, 64, 2))
        mag = (rng.random((h, w)) ** (1 + 3 * (t % 3))).astype(np.float32) * float(rng.random() * 100 + 1e-3)
        if t % 3 == 2:
            mag[rng.random((h, w)) < 0.5] = 0
        top = float(mag.max())
        if top <= 0:
            continue
        levels = np.clip(np.multiply(mag, np.float32(255.0 / top)), 0, 255).astype(np.uint8)
        want, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        assert native._gradients.otsu_level(mag, np.float32(255.0 / top)) == want


def test_kernels_refuse_mismatched_or_empty_planes():
    with pytest.raises(ValueError):
        native._gradients.canny(np.zeros((3, 4), np.int16), np.zeros((4, 3), np.int16), 1.0, 2.0)
    with pytest.raises(ValueError):
        native._gradients.canny(np.zeros((3, 4), np.int16), np.zeros((3, 4), np.int16), -1.0, 2.0)
    assert native._gradients.canny(np.zeros((0, 4), np.int16), np.zeros((0, 4), np.int16), 1.0, 2.0).shape == (0, 4)
    with pytest.raises(ValueError):
        native._gradients.otsu_level(np.zeros((0, 3), np.float32), np.float32(1))


@pytest.mark.parametrize("seed", range(12))
def test_order_chains_word_scan_and_code_tables_walk_as_by_hand(seed):
    """order_chains finds its pixels eight bytes at a time (any width: the tail too)
    and each pixel's two neighbours by its neighbourhood code's tables: the chains a
    walk by hand gives, on masks wider than a word and of every width modulo 8."""
    from tests.test_mesher_polylines import OFFSETS, _chains_by_hand, _simple_mask

    rng = np.random.default_rng(300 + seed)
    mask = _simple_mask(rng, int(rng.integers(20, 60)), int(rng.integers(17, 90)))
    offsets = np.array([dy * mask.shape[1] + dx for dy, dx in OFFSETS], np.int64)
    got = native._polylines.order_chains(mask.ravel().view(np.uint8), offsets)
    for a, b in zip(got, _chains_by_hand(mask)):
        assert np.array_equal(a, b)


def _varints_by_numpy(values) -> bytes:
    """codec.coding.varints as it was written in numpy (repeat, shift, mask)."""
    v = np.asarray(values, dtype=np.uint64).ravel()
    if v.size == 0:
        return b""
    nbytes = np.ones(v.size, dtype=np.int64)
    for k in range(1, 10):
        nbytes += v >= (np.uint64(1) << np.uint64(7 * k))
    rep = np.repeat(v, nbytes)
    ends = np.cumsum(nbytes)
    k = np.arange(ends[-1]) - np.repeat(ends - nbytes, nbytes)
    out = (rep >> (np.uint64(7) * k.astype(np.uint64))) & np.uint64(0x7F)
    more = k < np.repeat(nbytes - 1, nbytes)
    return (out | (more.astype(np.uint64) << np.uint64(7))).astype(np.uint8).tobytes()


def test_compiled_varints_are_the_numpy_ones():
    from codec import coding

    rng = np.random.default_rng(23)
    for t in range(1000):
        v = rng.integers(0, 2**63, int(rng.integers(0, 40)), dtype=np.uint64) >> rng.integers(0, 64, dtype=np.uint64)
        if t % 4 == 0:
            v = np.r_[v, np.array([2**64 - 1, 0, 127, 128, 2**35], np.uint64)]
        assert coding.varints(v) == _varints_by_numpy(v)
    for v in (np.arange(300, dtype=np.int64), [1, 2, 300], np.zeros((3, 2), np.int64), np.array([-1], np.int64), []):
        assert coding.varints(v) == _varints_by_numpy(v)
    assert native._samples.varints(np.zeros(0, np.uint64)) == b""
