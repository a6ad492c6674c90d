"""What the Python API takes, as imagecodecs, Pillow and tifffile users expect: any
buffer, an out= array, a path or a binary file object, and one ATMError for bad input."""

from __future__ import annotations

import io
import mmap

import numpy as np
import pytest

import codec
from codec.errors import ATMError, OptionError


def _gray(h: int = 40, w: int = 56) -> np.ndarray:
    return (np.add.outer(np.arange(h), 2 * np.arange(w)) % 256).astype(np.uint8)


@pytest.fixture(scope="module")
def data() -> bytes:
    return codec.encode(_gray(), points=120)


def test_decode_takes_any_buffer(data, tmp_path):
    expected = codec.decode(data)
    path = tmp_path / "x.atm"
    path.write_bytes(data)
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
        from_mmap = codec.decode(mapped)
    np.testing.assert_array_equal(from_mmap, expected)
    for buffer in (bytearray(data), memoryview(data), np.frombuffer(data, np.uint8)):
        np.testing.assert_array_equal(codec.decode(buffer), expected)
    # a memoryview of another item size is still the same bytes
    padded = data + b"\0" * (-len(data) % 4)
    assert codec.info(memoryview(padded).cast("I"))["width"] == 56


def test_decode_fills_out_in_place(data):
    expected = codec.decode(data)
    out = np.full(expected.shape, 7, np.uint8)
    assert codec.decode(data, out=out) is out
    np.testing.assert_array_equal(out, expected)
    # a gray image into an (H, W, 1) array, as it may have been encoded
    out3 = np.zeros(expected.shape + (1,), np.uint8)
    assert codec.decode(data, out=out3) is out3
    np.testing.assert_array_equal(out3[..., 0], expected)


@pytest.mark.parametrize(
    "out, match",
    [
        (np.zeros((40, 55), np.uint8), r"needs shape \(40, 56\)"),
        (np.zeros((40, 56), np.uint16), "dtype uint8"),
        ([[0] * 56] * 40, "numpy array"),
    ],
)
def test_decode_refuses_a_wrong_out(data, out, match):
    with pytest.raises(ATMError, match=match):
        codec.decode(data, out=out)


def test_decode_refuses_a_read_only_out(data):
    out = np.zeros((40, 56), np.uint8)
    out.flags.writeable = False
    with pytest.raises(ATMError, match="read-only"):
        codec.decode(data, out=out)


def test_gray_with_a_channel_axis_round_trips_in_its_shape_through_out():
    image = _gray()[:, :, None]
    data = codec.encode(image, points=120)
    assert codec.decode(data).shape == (40, 56)  # the file does not record the axis
    assert codec.decode(data, out=np.empty((40, 56, 1), np.uint8)).shape == (40, 56, 1)


@pytest.mark.parametrize("bad, match", [("x.atm", "codec.read"), (None, "NoneType"), ([1, 2], "list")])
def test_decode_and_check_refuse_what_is_not_a_buffer(bad, match):
    with pytest.raises(ATMError, match=match):
        codec.decode(bad)
    with pytest.raises(ATMError, match=match):
        codec.check(bad)


def test_check_sniffs_the_signature(data):
    assert codec.check(data) is True
    assert codec.check(np.frombuffer(data[:8], np.uint8)) is True
    assert codec.check(data[:5]) is False
    assert codec.check(b"\x89PNG\r\n\x1a\n") is False
    assert codec.check(b"") is False


def test_read_takes_a_path_or_a_binary_file_object(data, tmp_path):
    path = tmp_path / "x.atm"
    path.write_bytes(data)
    expected = codec.decode(data)
    np.testing.assert_array_equal(codec.read(str(path)), expected)
    with open(path, "rb") as f:
        np.testing.assert_array_equal(codec.read(f), expected)
    np.testing.assert_array_equal(codec.read(io.BytesIO(data)), expected)
    out = np.empty_like(expected)
    assert codec.read(io.BytesIO(data), out=out) is out


def test_read_errors_are_atm_errors(data, tmp_path):
    with pytest.raises(ATMError, match="text mode"):
        codec.read(io.StringIO("x"))
    with pytest.raises(ATMError, match="codec.decode"):
        codec.read(data)
    with pytest.raises(ATMError, match="path or a binary file object"):
        codec.read(42)
    with pytest.raises(ATMError, match="cannot read"):
        codec.read(tmp_path / "missing.atm")

    class Failing(io.RawIOBase):
        def readable(self):
            return True

        def readinto(self, b):
            raise OSError(5, "Input/output error")

    with pytest.raises(ATMError, match="Input/output error"):
        codec.read(io.BufferedReader(Failing()))


@pytest.mark.parametrize(
    "options, names",
    [
        (dict(quality=50, points=100), ("points", "quality")),
        (dict(max_rms=2.0, points=100), ("points", "max_rms")),
        (dict(max_error=4, points=100), ("points", "max_error")),
        (dict(quality=50, max_rms=2.0), ("quality", "max_rms")),
    ],
)
def test_conflicting_size_options_are_refused_naming_both(options, names):
    with pytest.raises(OptionError, match=f"{names[0]} and {names[1]}"):
        codec.encode(_gray(), **options)


def test_two_bounds_together_are_allowed():
    assert codec.check(codec.encode(_gray(), max_rms=4.0, max_error=20))
