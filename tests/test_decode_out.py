"""codec.decode(out=): a one-band file whose samples are the image's own is rendered
straight into a C-contiguous `out` (no image of its own to allocate, zero and copy);
every other case still fills `out` by copying, with the same pixels."""

from __future__ import annotations

import numpy as np
import pytest

import codec
from codec import decoding
from tests.synthetic import range_scene


@pytest.fixture
def renders(monkeypatch) -> list:
    """The `out` each render of the decode was given."""
    seen = []
    real = decoding.render

    def spy(mesh, backend="cpu", *, tiles=False, out=None):
        seen.append(out)
        return real(mesh, backend, tiles=tiles, out=out)

    monkeypatch.setattr(decoding, "render", spy)
    return seen


def _gray() -> np.ndarray:
    return range_scene(96, 80, seed=3)


@pytest.mark.parametrize("kind", ["gray", "gray_axis_file", "gray_into_axis", "rgb", "uint16"])
def test_a_one_band_file_renders_into_out(kind: str, renders: list) -> None:
    gray = _gray()
    image = {"gray": gray, "gray_axis_file": gray[:, :, None], "gray_into_axis": gray,
             "rgb": np.stack([gray, gray[::-1], 255 - gray], axis=2),
             "uint16": gray.astype(np.uint16) * 257}[kind]
    data = codec.encode(image, points=300)
    want = codec.decode(data)
    renders.clear()
    shape = want.shape + (1,) if kind == "gray_into_axis" else want.shape
    out = np.full(shape, 9, want.dtype)
    assert codec.decode(data, out=out) is out
    assert np.array_equal(out.reshape(want.shape), want)
    # the render wrote out's own memory
    assert len(renders) == 1 and renders[0] is not None and np.shares_memory(renders[0], out)


def test_other_files_and_outs_are_filled_by_copy_with_the_same_pixels(renders: list) -> None:
    gray = _gray()
    holes = gray.astype(np.uint16) * 200
    holes[10:20, 30:50] = 0
    floats = gray.astype(np.float32) * 0.01
    cases = [
        # many bands over more than stream.GROUP_PIXELS: rendered a group at a time
        codec.encode(range_scene(300, 300, seed=4), points=2000, band_height=16),
        codec.encode(holes, points=400, nodata=0),        # holes filled after the render
        codec.encode(floats, points=300),                 # samples scaled after the render
        codec.encode(gray, max_error=2),                  # a residual layer: no render
    ]
    for data in cases:
        want = codec.decode(data)
        for out in (np.empty_like(want), np.empty((want.shape[1], want.shape[0]), want.dtype).T):
            renders.clear()
            assert codec.decode(data, out=out) is out
            assert np.array_equal(out, want, equal_nan=want.dtype.kind == "f")
            assert all(r is None for r in renders)
    # a strided out of a one-band file: no render into it, the same pixels copied
    data = codec.encode(gray, points=300)
    want = codec.decode(data)
    out = np.empty((want.shape[1], want.shape[0]), want.dtype).T
    renders.clear()
    codec.decode(data, out=out)
    assert np.array_equal(out, want) and renders == [None]


def test_bands_rendered_as_one_group_render_into_out(renders: list) -> None:
    """Bands of fewer pixels in all than stream.GROUP_PIXELS are rendered as one
    stacked mesh: that render is the whole image, and lands in out."""
    data = codec.encode(_gray(), points=300, band_height=16)
    want = codec.decode(data)
    out = np.empty_like(want)
    renders.clear()
    codec.decode(data, out=out)
    assert np.array_equal(out, want) and renders == [out]


def test_a_decoder_renders_into_out_too(renders: list) -> None:
    data = codec.encode(_gray(), points=300)
    out = np.zeros((80, 96), np.uint8)
    codec.Decoder().decode(data, out=out)
    assert np.array_equal(out, codec.decode(data)) and renders[0] is out
