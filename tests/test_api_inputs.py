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


def _axis_chunk() -> bytes:
    import zlib

    return b"\0\0\0\0axis" + zlib.crc32(b"axis").to_bytes(4, "little")


@pytest.mark.parametrize(
    "image, options",
    [
        (_gray()[:, :, None], dict(points=120)),
        (np.where(_gray() > 200, 0, _gray()).astype(np.uint16)[:, :, None] * 50, dict(points=120, nodata=0)),
        ((_gray().astype(np.float64) / 7)[:, :, None], dict(points=120)),
        ((_gray().astype(np.int16) - 300)[:, :, None], dict(max_error=0)),
    ],
    ids=["uint8", "uint16 holes", "float", "int16"],
)
def test_gray_with_a_channel_axis_comes_back_in_its_shape(image, options, tmp_path):
    """ATM.md §4.9: an H x W x 1 image decodes as H x W x 1 from decode, read and the
    StreamDecoder, without out=; its file is the H x W image's plus one empty `axis`
    chunk, so files of H x W images keep their bytes."""
    data = codec.encode(image, **options)
    flat = codec.encode(image[:, :, 0], **options)
    assert _axis_chunk() not in flat and data.replace(_axis_chunk(), b"") == flat
    expected = codec.decode(flat)
    assert expected.shape == (40, 56)
    out = codec.decode(data)
    assert out.shape == (40, 56, 1) and out.dtype == expected.dtype
    np.testing.assert_array_equal(out[..., 0], expected)
    path = tmp_path / "x.atm"
    path.write_bytes(data)
    assert codec.read(path).shape == (40, 56, 1)
    with open(path, "rb") as f:
        assert codec.read(f).shape == (40, 56, 1)
    dec = codec.StreamDecoder(io.BytesIO(data))
    assert dec.shape == (40, 56, 1)
    rows = np.concatenate([r for _, r in dec])
    assert rows.shape == (40, 56, 1)
    np.testing.assert_array_equal(rows[..., 0], expected)
    # out= may still have either shape, for either file
    for d in (data, flat):
        for shape in ((40, 56), (40, 56, 1)):
            filled = codec.decode(d, out=np.empty(shape, expected.dtype))
            np.testing.assert_array_equal(filled.reshape(40, 56), expected)


def test_stream_encoder_records_the_channel_axis():
    image = _gray()[:, :, None]
    buf = io.BytesIO()
    with codec.StreamEncoder(buf, 56, 40, points=120, channel_axis=True) as enc:
        enc.write(image[:20])
        enc.write(image[20:, :, 0])  # rows without the axis are taken too
    assert buf.getvalue() == codec.encode(image, points=120)
    assert codec.decode(buf.getvalue()).shape == (40, 56, 1)


@pytest.mark.parametrize(
    "where, payload, match",
    [("before bands", b"\0", "axis chunk"), ("twice", b"", "axis chunk"), ("after a band", b"", "misplaced axis")],
)
def test_a_bad_axis_chunk_is_refused(where, payload, match):
    import zlib

    data = codec.encode(_gray()[:, :, None], points=120)
    at = data.index(_axis_chunk())
    chunk = len(payload).to_bytes(4, "little") + b"axis" + payload + zlib.crc32(b"axis" + payload).to_bytes(4, "little")
    rest = data[at + 12 :]
    if where == "before bands":
        bad = data[:at] + chunk + rest
    elif where == "twice":
        bad = data[:at] + chunk + data[at:]
    else:
        end = len(data) - 12  # the AEND chunk
        bad = data[:at] + rest[: end - at - 12] + chunk + data[end:]
    with pytest.raises(codec.CorruptError, match=match):
        codec.decode(bad)


def test_an_axis_chunk_in_an_rgb_file_is_refused():
    import zlib

    rgb = np.stack([_gray()] * 3, axis=2)
    data = codec.encode(rgb, points=120)
    bad = data[:32] + b"\0\0\0\0axis" + zlib.crc32(b"axis").to_bytes(4, "little") + data[32:]
    with pytest.raises(codec.CorruptError, match="gray image"):
        codec.decode(bad)


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
        (dict(max_rms=2.0, points=100, residual=False), ("points", "max_rms")),
        (dict(max_error=4, points=100, residual=False), ("points", "max_error")),
        (dict(quality=50, max_rms=2.0), ("quality", "max_rms")),
    ],
)
def test_conflicting_size_options_are_refused_naming_both(options, names):
    with pytest.raises(OptionError, match=f"{names[0]} and {names[1]}"):
        codec.encode(_gray(), **options)


def test_two_bounds_together_are_allowed():
    assert codec.check(codec.encode(_gray(), max_rms=4.0, max_error=20))
