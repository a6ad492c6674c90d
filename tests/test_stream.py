"""Streaming: rows given in any pieces are coded as the bands sliced from the whole
image, decoding yields bands as they arrive, and damaged streams give their intact
bands and then a clear error."""

from __future__ import annotations

import io
import os
import struct
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.decoding import render
from codec.errors import ATMError, CorruptError, TruncatedError
from tests.synthetic import range_scene


def stream_encode(image, band_height, step, **options) -> bytes:
    out = io.BytesIO()
    h, w = image.shape[:2]
    with codec.StreamEncoder(out, w, h, dtype=image.dtype, band_height=band_height, **options) as enc:
        for y in range(0, h, step):
            enc.write(image[y : y + step])
    return out.getvalue()


def sliced_encode(image, band_height: int, holes=None, **options) -> bytes:
    """The reference for the row buffer: the bands cut straight from the whole image by
    arithmetic (band k: rows k * band_height .. (k + 1) * band_height, each sharing its
    first row with the band before; a one-row image is one band), each coded by
    pipeline.code_band and written in turn, with no StreamEncoder involved."""
    from codec import container, pipeline
    from codec.settings import Settings

    h, w = image.shape[:2]
    plan = pipeline.plan(Settings(band_height=band_height, **options), w, h, image.dtype)
    out = io.BytesIO()
    writer = container.Writer(out, container.Header(w, h, image.dtype, 1, nodata=plan.nodata))
    top = None
    step = plan.step
    starts = range(0, h - 1, plan.band_height) if h > 1 else [0]
    for y0 in starts:
        end = min(y0 + plan.band_height, h - 1) + 1
        band_holes = None if holes is None or not holes[y0:end].any() else holes[y0:end]
        coded = pipeline.code_band(image[y0:end], band_holes, plan, y0=y0, top=top, last=end == h, step=step)
        writer.write_band(coded.y0, coded.mesh, coded.step, coded.delaunay, coded.layout)
        top, step = coded.bottom_row(), coded.step
    writer.close()
    return out.getvalue()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 40), st.integers(1, 50), st.integers(1, 12), st.integers(1, 9), st.integers(0, 99),
       st.sampled_from(["uniform", "adaptive"]))
def test_streamed_rows_give_the_bands_cut_from_the_whole_image(height, width, band_height, step, seed, mesher):
    """However the rows arrive, the row buffer hands the band pipeline the bands that
    slicing the whole image gives, with the shared rows and value step carried over."""
    image = range_scene(width, height, seed=seed)
    points = max(4, width * height // 20)
    streamed = stream_encode(image, band_height, step, mesher=mesher, points=points)
    assert streamed == sliced_encode(image, band_height, mesher=mesher, points=points)
    assert streamed == codec.encode(image, band_height=band_height, mesher=mesher, points=points)
    assert codec.decode(streamed).shape == image.shape


def test_streamed_holes_give_the_bands_cut_from_the_whole_image():
    image = range_scene(50, 40, seed=3)
    holes = np.zeros(image.shape, bool)
    holes[10:25, 5:20] = True
    out = io.BytesIO()
    with codec.StreamEncoder(out, 50, 40, band_height=9, points=200, nodata=0) as enc:
        for y in range(0, 40, 7):
            enc.write(image[y : y + 7], holes=holes[y : y + 7])
    assert out.getvalue() == sliced_encode(image, 9, holes, points=200, nodata=0)


@pytest.mark.parametrize("band_height", [1, 2, 3, 7, 16, 64])
def test_bands_decode_without_seams(band_height):
    image = range_scene(64, 50, seed=3)
    data = codec.encode(image, band_height=band_height, points=600)
    dec = codec.StreamDecoder(io.BytesIO(data))
    bands = [(y0, render(m)) for y0, m in dec.bands()]
    assert len(bands) == -(-49 // band_height)
    for (y0, a), (y1, b) in zip(bands, bands[1:]):
        assert y1 == y0 + len(a) - 1
        np.testing.assert_array_equal(a[-1], b[0])  # the shared row, decoded from each side
    rows = list(codec.StreamDecoder(io.BytesIO(data)))
    assert [y for y, _ in rows] == [y for y, _ in bands]
    whole = np.concatenate([r for _, r in rows])
    np.testing.assert_array_equal(whole, codec.decode(data))
    assert whole.shape == image.shape


def test_banded_size_is_close_to_one_band_at_equal_error():
    """Bands cost some bytes (shared rows, walls cut at band edges), not many: under
    the same error bound a 16-row banding stays within 1.8x the one-band size."""
    image = range_scene(128, 128, seed=5)
    sizes = {}
    for bh in (16, 128):
        data = codec.encode(image, band_height=bh, max_rms=1.0, residual=False)  # the mesh's banding
        out = codec.decode(data)
        assert np.sqrt(np.mean((out.astype(float) - image) ** 2)) <= 1.0
        sizes[bh] = len(data)
    assert sizes[16] < 1.8 * sizes[128]


def test_decoder_knows_the_header_before_any_band():
    image = range_scene(30, 20, seed=1, dtype=np.uint16)
    dec = codec.StreamDecoder(io.BytesIO(codec.encode(image)))
    assert (dec.width, dec.height, dec.dtype, dec.channels, dec.shape) == (30, 20, np.uint16, 1, (20, 30))


def chunk_bounds(data: bytes) -> list[int]:
    """Byte offsets where each chunk starts, and the end of the file."""
    pos, out = 10, []
    while pos < len(data):
        out.append(pos)
        (length,) = struct.unpack_from("<I", data, pos)
        pos += 12 + length
    return out + [pos]


def test_truncation_at_every_chunk_boundary_yields_intact_bands():
    image = range_scene(40, 33, seed=2)
    data = codec.encode(image, band_height=8, mesher="uniform", points=300)
    full = codec.decode(data)
    bounds = chunk_bounds(data)
    for cut in bounds[1:-1] + [b + 5 for b in bounds[1:-2]]:
        dec = codec.StreamDecoder(io.BytesIO(data[:cut]))
        got = []
        with pytest.raises(TruncatedError, match=r"byte \d+"):
            for y0, rows in dec:
                got.append((y0, rows))
        complete_bands = sum(1 for b in bounds[2:-1] if b <= cut)  # MESH chunks that end by the cut
        assert len(got) == complete_bands
        for y0, rows in got:
            np.testing.assert_array_equal(rows, full[y0 : y0 + len(rows)])


def test_bad_checksum_names_the_chunk():
    data = bytearray(codec.encode(range_scene(40, 33, seed=2), band_height=8, mesher="uniform"))
    bounds = chunk_bounds(bytes(data))
    data[bounds[2] + 20] ^= 0xFF  # inside the second MESH chunk
    dec = codec.StreamDecoder(io.BytesIO(bytes(data)))
    it = iter(dec)
    next(it)
    with pytest.raises(CorruptError, match=f"MESH at byte {bounds[2]} fails its CRC"):
        next(it)


def test_decoding_from_a_pipe_yields_a_band_before_the_rest_arrives():
    image = range_scene(64, 64, seed=4)
    data = codec.encode(image, band_height=16, mesher="uniform")
    bounds = chunk_bounds(data)
    r, w = os.pipe()
    first_band_sent, release = threading.Event(), threading.Event()

    def writer():
        with os.fdopen(w, "wb") as f:
            f.write(data[: bounds[2]])  # signature, AHDR and the first MESH only
            f.flush()
            first_band_sent.set()
            release.wait(10)
            f.write(data[bounds[2] :])

    t = threading.Thread(target=writer)
    t.start()
    with os.fdopen(r, "rb") as f:
        it = iter(codec.StreamDecoder(f))
        y0, rows = next(it)  # must not wait for the rest of the file
        assert y0 == 0 and len(rows) == 16 and not release.is_set()
        release.set()
        rest = list(it)
    t.join()
    assert sum(len(r) for _, r in rest) == 48


def test_encoder_errors():
    out = io.BytesIO()
    enc = codec.StreamEncoder(out, 10, 5)
    with pytest.raises(ATMError, match="shape"):
        enc.write(np.zeros((2, 11), np.uint8))
    with pytest.raises(ATMError, match="uint16"):
        enc.write(np.zeros((2, 10), np.uint16))
    enc.write(np.zeros((3, 10), np.uint8))
    with pytest.raises(ATMError, match="3 of the 5 rows"):
        enc.close()
    with pytest.raises(ATMError, match="more than the 5 rows"):
        enc.write(np.zeros((3, 10), np.uint8))
    with pytest.raises(ATMError, match="band_height"):
        codec.StreamEncoder(io.BytesIO(), 10, 5, band_height=0)
    with pytest.raises(ATMError, match="unknown encoder option bogus; the options are"):
        codec.StreamEncoder(io.BytesIO(), 10, 5, bogus=1)


def test_rgb_and_single_row_streams():
    rgb = np.random.default_rng(0).integers(0, 256, (21, 13, 3), dtype=np.uint8)
    out = io.BytesIO()
    with codec.StreamEncoder(out, 13, 21, channels=3, band_height=4, mesher="uniform") as enc:
        for row in rgb:
            enc.write(row)
    assert out.getvalue() == codec.encode(rgb, band_height=4, mesher="uniform")
    assert codec.decode(out.getvalue()).shape == (21, 13, 3)
    line = np.arange(17, dtype=np.uint8)[None]
    assert codec.decode(stream_encode(line, 3, 1)).shape == (1, 17)


def test_progress_moves_inside_one_long_band():
    """A bounded encode of one band reports its refinement rounds, not only its end."""
    image = range_scene(120, 90, seed=11)
    calls = []
    out = io.BytesIO()
    with codec.StreamEncoder(out, 120, 90, max_rms=0.8, residual=False,
                             progress=lambda done, total: calls.append((done, total))) as enc:
        enc.write(image)
    assert calls[-1] == (90, 90)
    inside = [done for done, _ in calls[:-1]]
    assert inside and all(0 < d < 90 for d in inside)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)
    assert out.getvalue() == codec.encode(image, max_rms=0.8, residual=False)
