"""Lossless float data (codec.lossless_float, ATM.md §4.10): every sample decodes to
its own binary32 bits (holes, -0.0, infinities, subnormals and NaN payloads included),
through exact steps where the values are whole numbers of a step and binary32 keys
otherwise; malformed exact-float files are refused with CorruptError."""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import lossless_float, residual
from codec.errors import ATMError, CorruptError
from tests.conftest import chunks
from tests.synthetic import range_scene
from tests.test_residual import _binary32_keys, _rebuild

#: Bit patterns the keys route must keep: zeros of both signs, the smallest and
#: largest subnormals and normals, infinities, and NaNs of several signs and payloads
#: (quiet and signalling).
SPECIAL = np.array(
    [0x00000000, 0x80000000, 0x00000001, 0x807FFFFF, 0x00800000, 0x7F7FFFFF, 0xFF7FFFFF,
     0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00000, 0x7F800001, 0x7FC12345, 0xFFBFFFFF],
    np.uint32,
)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def _exact(data: bytes) -> bool:
    return bool(codec.info(data).get("exact_float"))


def _decodes_exactly(image: np.ndarray, data: bytes) -> None:
    out = codec.decode(data)
    assert out.dtype == np.float32 and out.shape == image.shape
    assert np.array_equal(_bits(out), _bits(image))
    rows = np.concatenate([r for _, r in codec.StreamDecoder(io.BytesIO(data))])
    assert np.array_equal(_bits(rows), _bits(image))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10**9), st.integers(1, 20), st.integers(1, 24), st.sampled_from(["bits", "smooth", "huge"]),
       st.floats(0, 0.4), st.sampled_from([None, 4]))
def test_every_sample_keeps_its_bits(seed, h, w, kind, special_share, band_height):
    rng = np.random.default_rng(seed)
    if kind == "bits":  # any 32-bit pattern at all
        image = rng.integers(0, 2**32, (h, w), dtype=np.uint32).view(np.float32)
    elif kind == "smooth":  # a range scene in metres with fractions
        image = (range_scene(w, h, seed=seed) * 0.37 + rng.normal(0, 0.01, (h, w)) + 812.25).astype(np.float32)
    else:  # values over the whole binary32 range
        image = (rng.standard_normal((h, w)) * 10.0 ** rng.integers(-40, 38, (h, w))).astype(np.float32)
    image = image.copy()
    chosen = rng.random((h, w)) < special_share
    image.view(np.uint32)[chosen] = rng.choice(SPECIAL, int(chosen.sum()))
    image[rng.random((h, w)) < special_share / 2] = np.nan  # holes
    data = codec.encode(image, lossless=True, band_height=band_height)
    _decodes_exactly(image, data)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10**9), st.integers(2, 20), st.integers(2, 24),
       st.sampled_from([1.0, 0.5, 0.1, 0.01, 0.001, 0.25, 2.0, 10.0]), st.floats(-5000, 5000), st.booleans())
def test_whole_numbers_of_a_step_take_the_exact_steps(seed, h, w, step, base, holes):
    rng = np.random.default_rng(seed)
    k = rng.integers(0, 3000, (h, w))
    image = (np.round(base / step) * step + k * step).astype(np.float32)
    if holes:
        image[rng.random((h, w)) < 0.2] = np.nan
    data = codec.encode(image, lossless=True)
    _decodes_exactly(image, data)
    if np.isfinite(image).any():
        # a 16-bit file with its step: no binary32 keys
        assert not _exact(data)
        assert codec.info(data)["residual"] == 0


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10**9), st.integers(2, 16), st.integers(2, 20), st.sampled_from([0.01, 0.001, 0.1, 1.0]),
       st.booleans())
def test_more_steps_than_16_bits_hold_take_a_step_chunk(seed, h, w, step, holes):
    rng = np.random.default_rng(seed)
    k = rng.integers(0, 70_000, (h, w))
    k.flat[0], k.flat[-1] = 0, 69_999 + int(rng.integers(1, 10**6))  # more than 65,536 steps apart
    image = (np.round(1000 / step) * step + k * step).astype(np.float32)
    if holes:
        image[rng.random((h, w)) < 0.2] = np.nan
        image.flat[0] = np.float32(1000.0)
    data = codec.encode(image, lossless=True, band_height=5)
    _decodes_exactly(image, data)
    info = codec.info(data)
    if info.get("exact_step") is not None:
        assert info["exact_step"] >= step * (1 - 1e-9) and b"STEP" in [t for _, t, _ in chunks(data)]
    else:  # a coarser round step that 16 bits hold (sample_type 2), never the keys
        assert not info.get("exact_float")


def test_centimetres_over_2000_m_take_32_bit_steps():
    rng = np.random.default_rng(9)
    cm = (range_scene(64, 48, seed=9) * 8.0 + 1000 + rng.integers(-30, 30, (48, 64)) / 100)
    image = (np.round(cm * 100) / 100).astype(np.float32)
    data = codec.encode(image, lossless=True)
    info = codec.info(data)
    assert info["exact_float"] and info["exact_step"] == 0.01
    _decodes_exactly(image, data)
    image[3, 3] = np.float32(1500.0037)  # one sample off every step the values allow: binary32 keys
    keys = codec.encode(image, lossless=True)
    assert codec.info(keys)["exact_step"] is None and len(keys) > len(data)
    _decodes_exactly(image, keys)


def test_a_stream_with_a_fine_precision_takes_a_step_chunk():
    image = (np.arange(200, dtype=np.float64).reshape(10, 20) * 13.37).round(2).astype(np.float32)
    out = io.BytesIO()
    lo, hi = float(image.min()), float(image.max())
    with codec.StreamEncoder(out, 20, 10, dtype=np.float32, lossless=True, precision=0.01, value_range=(lo, hi)) as enc:
        enc.write(image)
    assert codec.info(out.getvalue())["exact_step"] == 0.01
    _decodes_exactly(image, out.getvalue())
    bad = image.copy()
    bad[7, 4] += np.float32(0.004)
    with pytest.raises(ATMError, match="row 7, column 4"):
        codec.StreamEncoder(io.BytesIO(), 20, 10, dtype=np.float32, lossless=True, precision=0.01,
                            value_range=(lo, hi)).write(bad)


def _steps_file() -> bytes:
    from tests.test_conformance import VECTORS

    return (VECTORS / "steps32_float_lossless.atm").read_bytes()


def _moved_step(data: bytes, before: bytes) -> bytes:
    """The file with its STEP chunk moved to just before the first `before` chunk."""
    step = next(p for _, t, p in chunks(data) if t == b"STEP")
    out, moved = [], False
    for _, t, p in chunks(data):
        if t == before and not moved:
            out.append((b"STEP", step))
            moved = True
        if t != b"STEP":
            out.append((t, p))
    body = iter(out)
    return _rebuild(data, lambda t, p: next(body))


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda d: _moved_step(d, b"MASK"), "misplaced STEP"),  # not directly after QUNT
        (lambda d: _rebuild(d, lambda t, p: (t, struct.pack("<dd", 0.0, 0.0)) if t == b"STEP" else (t, p)), "STEP chunk"),
        (lambda d: _rebuild(d, lambda t, p: (t, struct.pack("<dd", 0.0, 1e30)) if t == b"STEP" else (t, p)), "STEP chunk"),
        (lambda d: _rebuild(d, lambda t, p: (t, p[:15]) if t == b"STEP" else (t, p)), "STEP chunk"),
        # a sample_type 2 file with a STEP chunk
        (lambda d: _rebuild(d, lambda t, p: (t, p[:8] + b"\x02" + p[9:]) if t == b"AHDR" else (t, p)), "STEP"),
    ],
)
def test_malformed_step_chunks_are_refused(change, match):
    bad = change(_steps_file())
    with pytest.raises(CorruptError, match=match):
        codec.decode(bad)
    with pytest.raises(_reference().DecodeError):
        _reference().decode(bad)


@pytest.mark.parametrize("name, sample_type", [("steps_float_lossless", 6), ("exact_float32_holes", 2),
                                               ("steps32_float_lossless", 2), ("residual_depth16", 6)])
def test_a_relabelled_sample_type_decodes_alike_or_is_refused_by_both(name, sample_type):
    from tests.test_conformance import VECTORS

    data = (VECTORS / f"{name}.atm").read_bytes()
    bad = _rebuild(data, lambda t, p: (t, p[:8] + bytes([sample_type]) + p[9:]) if t == b"AHDR" else (t, p))
    try:
        out = codec.decode(bad)
    except CorruptError:
        with pytest.raises(_reference().DecodeError):
            _reference().decode(bad)
        return
    assert np.array_equal(_bits(_reference().decode(bad)), _bits(out))


def test_exact_steps_are_smaller_than_keys():
    rng = np.random.default_rng(3)
    image = (range_scene(64, 48, seed=3) * 4 + rng.integers(0, 3, (48, 64)) + 300).astype(np.float32)
    steps = codec.encode(image, lossless=True)
    assert not _exact(steps)
    _decodes_exactly(image, steps)
    # one negative zero has no whole number of steps: the keys keep it
    image[5, 5] = -0.0
    zero = codec.encode(image, lossless=True)
    assert _exact(zero) and len(steps) < len(zero)
    _decodes_exactly(image, zero)


def test_negative_zero_and_nodata_zero_stay_apart():
    image = np.array([[0.0, -0.0, 1.5], [2.25, 0.0, -0.0]], np.float32)
    data = codec.encode(image, lossless=True, nodata=0.0)
    _decodes_exactly(image, data)
    holes = codec.decode(data) == 0  # both zeros compare equal to 0: the bits tell them apart
    assert holes.sum() == 4


def test_nan_holes_keep_their_payload():
    image = np.full((6, 7), 3.5, np.float32)
    image.view(np.uint32)[1:3, 2:5] = 0xFFC00000  # the NaN x86 arithmetic makes
    image.view(np.uint32)[4, 4] = 0x7FC00001  # another NaN: a sample of its own
    data = codec.encode(image, lossless=True)
    _decodes_exactly(image, data)
    assert np.isnan(codec.info(data)["nodata"])


@pytest.mark.parametrize("keys", [False, True])
def test_a_mask_makes_holes_in_both_routes(keys):
    rng = np.random.default_rng(10)
    image = rng.normal(0, 1, (30, 40)) if keys else rng.integers(0, 3000, (30, 40)) * 0.5
    image = image.astype(np.float32)
    mask = rng.random((30, 40)) < 0.2
    data = codec.encode(image, lossless=True, mask=mask)
    out = codec.decode(data)
    assert _exact(data) == keys
    assert np.array_equal(_bits(out[~mask]), _bits(image[~mask])) and np.isnan(out[mask]).all()


def test_float16_and_float64_of_binary32_values():
    rng = np.random.default_rng(4)
    half = rng.normal(0, 100, (9, 11)).astype(np.float16)
    out = codec.decode(codec.encode(half, lossless=True))
    assert out.dtype == np.float32 and np.array_equal(out.astype(np.float16).view(np.uint16), half.view(np.uint16))
    double = rng.normal(0, 100, (9, 11)).astype(np.float32).astype(np.float64)
    assert np.array_equal(codec.decode(codec.encode(double, lossless=True)), double)
    with pytest.raises(codec.UnsupportedError, match="binary32 values"):
        codec.encode(double + 1e-12, lossless=True)


def test_a_stream_with_a_precision_checks_every_sample():
    image = np.arange(40, dtype=np.float32).reshape(5, 8) * 0.5
    out = io.BytesIO()
    with codec.StreamEncoder(out, 8, 5, dtype=np.float32, lossless=True, precision=0.5, value_range=(0.0, 19.5)) as enc:
        enc.write(image)
    _decodes_exactly(image, out.getvalue())
    bad = image.copy()
    bad[3, 2] += 0.1
    with pytest.raises(ATMError, match="row 3, column 2"):
        codec.StreamEncoder(io.BytesIO(), 8, 5, dtype=np.float32, lossless=True, precision=0.5,
                            value_range=(0.0, 19.5)).write(bad)


@pytest.mark.usefixtures("gl")
def test_gl_decodes_the_same_bits():
    rng = np.random.default_rng(5)
    image = rng.normal(50, 20, (30, 40)).astype(np.float32)
    image[3:9, 4:12] = np.nan
    image[0, 0] = -0.0
    data = codec.encode(image, lossless=True, band_height=8)
    assert _exact(data)
    assert np.array_equal(_bits(codec.decode(data, backend="gl")), _bits(image))


# ---------------------------------------------------------------- malformed files


def _keys_file() -> tuple[np.ndarray, bytes]:
    image, data = _binary32_keys()
    assert _exact(data)
    return image, data


def test_keys_file_without_a_layer_is_refused():
    _, data = _keys_file()
    with pytest.raises(CorruptError, match="sample_type 6"):
        codec.decode(_rebuild(data, lambda t, p: None if t == residual.CHUNK else (t, p)))


def test_keys_file_with_a_bound_is_refused():
    _, data = _keys_file()
    changed = _rebuild(data, lambda t, p: (t, p[:10] + struct.pack("<H", 1) + p[12:]) if t == residual.CHUNK else (t, p))
    with pytest.raises(CorruptError, match="bound 0"):
        codec.decode(changed)


def test_nan_nodata_without_a_binary32_payload_is_refused():
    _, data = _keys_file()
    nan = struct.pack("<Q", 0x7FF0000000000001)  # a NaN whose top 23 significand bits are 0
    with pytest.raises(CorruptError, match="NDAT"):
        codec.decode(_rebuild(data, lambda t, p: (t, nan) if t == b"NDAT" else (t, p)))


# (flipped bits of wide tokens: tests/test_residual.py's test_flipped_coded_bits_never_crash)


def test_truncated_wide_tokens_are_refused():
    _, data = _keys_file()
    seen = []

    def cut(ctype, payload):
        if ctype == residual.CHUNK and not seen:
            seen.append(1)
            return ctype, payload[: residual.FIXED.size + 3]
        return ctype, payload

    with pytest.raises(CorruptError):
        codec.decode(_rebuild(data, cut))


def test_keys_order_like_the_values():
    values = np.array([-np.inf, -3.4e38, -1.0, -1e-45, -0.0, 0.0, 1e-45, 1.0, 3.4e38, np.inf], np.float32)
    keys = lossless_float.keys(values)
    assert (np.diff(keys.astype(np.int64)) > 0).all()
    assert np.array_equal(_bits(lossless_float.floats(keys)), _bits(values))
    every = np.arange(0, 2**32, 65537, dtype=np.uint64).astype(np.uint32)
    assert np.array_equal(lossless_float.keys(lossless_float.floats(every)), every)


def test_cli_lossless_float_geotiff_keeps_its_georeferencing(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from codec.cli.main import main
    from tests.test_geotiff import assert_georeferenced_alike, dem, write_geotiff

    for name, image, exact in (("steps", np.round(dem(40, 50, 1) * 10) / 10, False), ("bits", dem(40, 50, 1), True)):
        image = image.astype(np.float32)
        image[10:15, 5:20] = -9999.0
        image[0, 0] = image[0, 0] if not exact else -0.0
        src, atm, out = tmp_path / f"{name}.tif", tmp_path / f"{name}.atm", tmp_path / f"{name}.out.tif"
        write_geotiff(src, image, -9999.0, "deflate", 3)
        assert main(["encode", str(src), str(atm), "--lossless"]) == 0
        assert main(["decode", str(atm), str(out)]) == 0
        assert _exact(atm.read_bytes()) == exact
        assert_georeferenced_alike(src, out)
        with rasterio.open(src) as a, rasterio.open(out) as b:
            assert np.array_equal(_bits(a.read(1)), _bits(b.read(1)))


def test_cli_info_names_exact_floats(tmp_path, capsys):
    from codec.cli.main import main

    _, data = _keys_file()
    path = tmp_path / "x.atm"
    path.write_bytes(data)
    assert main(["info", str(path)]) == 0
    assert "stored exactly (binary32 bits)" in capsys.readouterr().out
    path.write_bytes(_steps_file())
    assert main(["info", str(path)]) == 0
    assert "stored exactly as steps of 0.01 from" in capsys.readouterr().out
    assert [t for _, t, _ in chunks(data)].count(residual.CHUNK) == 4


# ---------------------------------------------------------------- the spec's decoder


def _reference():
    from codec.format_spec import reference_decoder

    return reference_decoder


@pytest.mark.parametrize("name, exact", [("exact_float32_holes", True), ("steps_float_lossless", False),
                                         ("steps32_float_lossless", True)])
def test_conformance_files_decode_bit_for_bit(name, exact):
    from tests.test_conformance import VECTORS

    data = (VECTORS / f"{name}.atm").read_bytes()
    expected = np.load(VECTORS / f"{name}.npy")
    assert _exact(data) == exact
    for out in (codec.decode(data), _reference().decode(data)):
        assert out.dtype == np.float32 and np.array_equal(_bits(out), _bits(expected))
    if name == "exact_float32_holes":  # the specials are there, as samples
        assert {0x80000000, 0x7F800000, 0xFF800000, 0x00000001, 0x7FC12345} <= set(_bits(expected).ravel().tolist())


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10**9), st.integers(1, 9), st.integers(1, 11), st.booleans())
def test_reference_decoder_agrees(seed, h, w, keys):
    rng = np.random.default_rng(seed)
    if keys:
        image = rng.integers(0, 2**32, (h, w), dtype=np.uint32).view(np.float32).copy()
    else:
        image = (rng.integers(0, 500, (h, w)) * 0.25 - 40).astype(np.float32)
    image[rng.random((h, w)) < 0.2] = np.nan
    data = codec.encode(image, lossless=True, band_height=3)
    assert np.array_equal(_bits(_reference().decode(data)), _bits(image))


def test_a_signalling_nan_hole_keeps_its_bits_when_wide_steps_fit_16_bits():
    """Steps found by the wide (32-bit) search that turn out to fit 16 bits are written
    as sample_type 2, whose holes decode by NumPy's conversion, which quiets a
    signalling NaN: the hole check must follow that rule, so that such an image goes
    the binary32 route instead (hypothesis found it: 0x7F800001 came back 0x7FC00001)."""
    image = np.array([[0x7F800001, 0, 0]], np.uint32).view(np.float32).copy()
    image[0, 1] = np.float32(3.04e22)
    data = codec.encode(image, lossless=True)
    _decodes_exactly(image, data)
