"""Signed integers (int8, int16, int32) stored exactly after an offset (ATM.md 4.1, 4.4)."""

from __future__ import annotations

import io

import numpy as np
import pytest

import codec
from codec.errors import CorruptError, OptionError, UnsupportedError
from tests.conftest import chunks
from tests.test_container import make_chunk


def terrain(dtype, lo: int, height: int = 50, width: int = 60) -> np.ndarray:
    y, x = np.mgrid[:height, :width]
    z = lo + 3 * x + 2 * y + 40 * (x > width // 2)
    return z.astype(dtype)


@pytest.mark.parametrize("dtype, lo, nodata", [(np.int8, -100, -128), (np.int16, -400, -32768), (np.int32, -2_000_000_000, -2147483648)])
def test_signed_integers_are_exact_with_their_dtype_and_nodata(dtype, lo, nodata):
    image = terrain(dtype, lo)
    image[5:9, 7:20] = nodata
    data = codec.encode(image, max_error=0, nodata=nodata)
    out = codec.decode(data)
    assert out.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(out, image)
    info = codec.info(data)
    assert info["dtype"] == np.dtype(dtype).name and info["nodata"] == nodata


def test_signed_integers_meet_an_error_bound():
    image = terrain(np.int16, -30000) + np.random.default_rng(0).integers(-3, 4, (50, 60)).astype(np.int16)
    out = codec.decode(codec.encode(image, max_error=2))
    assert np.abs(out.astype(np.int64) - image).max() <= 2


def test_int16_stream_needs_no_value_range():
    image = terrain(np.int16, -5)
    buf = io.BytesIO()
    with codec.StreamEncoder(buf, 60, 50, dtype=np.int16, max_error=0) as enc:
        enc.write(image)
    np.testing.assert_array_equal(codec.decode(buf.getvalue()), image)


def test_wide_int32_and_other_types_name_the_fix():
    wide = np.arange(200_000, dtype=np.int32).reshape(400, 500)
    with pytest.raises(UnsupportedError, match=r"200,000 values.*float32"):
        codec.encode(wide)
    with pytest.raises(UnsupportedError, match=r"uint32.*astype\(np.int32\).*astype\(np.float32\)"):
        codec.encode(np.zeros((4, 4), np.uint32))
    with pytest.raises(OptionError, match="value_range"):
        codec.StreamEncoder(io.BytesIO(), 4, 4, dtype=np.int32)
    with pytest.raises(OptionError, match="stored exactly"):
        codec.encode(terrain(np.int16, 0), precision=0.5)


def test_float64_is_stored_to_its_stated_precision():
    z = terrain(np.float64, 100) * 0.01 + 1e-9
    out = codec.decode(codec.encode(z, precision=0.001, max_error=0.002))
    assert out.dtype == np.float32 and np.abs(out - z).max() <= 0.002


def test_integer_quant_chunk_must_have_scale_one():
    data = codec.encode(terrain(np.int16, -5), points=50)
    offset, ctype, payload = next(c for c in chunks(data) if c[1] == b"QUNT")
    assert np.frombuffer(payload, "<f8")[1] == 1.0
    bad = data[:offset] + make_chunk(b"QUNT", np.array([-5.0, 0.5], "<f8").tobytes()) + data[offset + 28 :]
    with pytest.raises(CorruptError, match="scale 1"):
        codec.decode(bad)


@pytest.mark.parametrize("dtype, lo, nodata", [(np.int8, -100, -128), (np.int16, -400, -32768), (np.int32, -2_000_000_000, None)])
def test_reference_decoder_decodes_signed_integers_as_the_codec_does(dtype, lo, nodata):
    from tests.test_reference_decoder import ref

    image = terrain(dtype, lo)
    if nodata is not None:
        image[3:6, 4:9] = nodata
    for options in ({"max_error": 0}, {"points": 60}):
        data = codec.encode(image, nodata=nodata, **options)
        out = ref.decode(data)
        assert out.dtype == np.dtype(dtype)
        np.testing.assert_array_equal(out, codec.decode(data))


def test_reference_decoder_refuses_an_integer_quant_with_scale_not_one():
    from tests.test_reference_decoder import ref

    data = codec.encode(terrain(np.int16, -5), points=50)
    offset, _, _ = next(c for c in chunks(data) if c[1] == b"QUNT")
    bad = data[:offset] + make_chunk(b"QUNT", np.array([-5.0, 0.5], "<f8").tobytes()) + data[offset + 28 :]
    with pytest.raises(ref.DecodeError, match="scale 1"):
        ref.decode(bad)


def test_info_states_float64_precision_and_integer_offset():
    z = terrain(np.float64, 100) * 0.01
    info = codec.info(codec.encode(z, precision=0.001, points=50))
    assert info["dtype"] == "float32" and info["precision"] == 0.001 and info["offset"] == pytest.approx(1.0)
    assert codec.info(codec.encode(terrain(np.int16, -7), points=50))["offset"] == -7
    assert "precision" not in codec.info(codec.encode(terrain(np.uint16, 7), points=50))
