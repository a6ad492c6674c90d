"""Float data at the edges of float32: an encode either gives a file that decodes within
its bound, or refuses with a message naming the fix; infinite holes come back."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.errors import ATMError, OptionError
from tests.synthetic import range_scene
from tests.test_cli import atm

F32_MAX = float(np.finfo(np.float32).max)


def dem(nodata: float | None = None, seed: int = 1) -> np.ndarray:
    """A 40x30 float32 terrain 0..1000 with a void of `nodata` (if given)."""
    z = (range_scene(40, 30, seed=seed).astype(np.float32) * (1000 / 255)).astype(np.float32)
    if nodata is not None:
        z[5:12, 8:20] = nodata
        z[20, 30] = nodata
    return z


@pytest.mark.parametrize("nodata", [-3.4e38, -3e38, -F32_MAX, F32_MAX, -1e38, 1e38, -1e30])
def test_an_unflagged_nodata_value_is_refused_naming_the_fix(nodata):
    z = dem(nodata)
    v32 = str(np.float32(nodata))
    for options in ({}, {"max_error": 0.5}, {"quality": 100}):
        with pytest.raises(OptionError, match=re.escape(f"pass it as nodata (--nodata {v32})")):
            codec.encode(z, **options)
    # the fix the message names works, and the holes come back as the value itself
    out = codec.decode(codec.encode(z, nodata=float(v32), max_error=0.5))
    holes = z == np.float32(nodata)
    assert (out[holes] == np.float32(nodata)).all()
    assert np.abs(out[~holes].astype(np.float64) - z[~holes]).max() <= 0.5


def test_a_nodata_value_beyond_float32_is_refused_and_infinity_is_kept():
    z = dem(np.inf)
    with pytest.raises(OptionError, match="nodata 1e\\+39 is beyond float32"):
        codec.encode(z, nodata=1e39)
    wide = dem().astype(np.float64)
    wide[0, 0] = 1e300
    with pytest.raises(OptionError, match="1e\\+300 is beyond float32's range.*set those samples to NaN"):
        codec.encode(wide)
    for nodata in (np.inf, -np.inf):
        z = dem(nodata)
        explicit = codec.decode(codec.encode(z, nodata=nodata))
        implicit = codec.decode(codec.encode(z))
        for out in (explicit, implicit):
            assert (out[np.isinf(z)] == nodata).all() and np.isfinite(out[~np.isinf(z)]).all()
    mixed = dem(np.inf)
    mixed[0, 0] = np.nan
    out = codec.decode(codec.encode(mixed))  # one nodata value per file: NaN
    assert np.isnan(out[~np.isfinite(mixed)]).all()


def test_a_range_the_format_cannot_carry_is_refused_before_writing():
    with pytest.raises(OptionError, match="beyond the largest float32"):
        codec.StreamEncoder(__import__("io").BytesIO(), 4, 4, dtype=np.float32, value_range=(-3e38, 3e38))
    with pytest.raises(OptionError, match="is too coarse.*give a precision of at most 5.19e\\+33"):
        codec.encode(np.zeros((4, 4), np.float32), value_range=(0, 1), precision=1e35)
    with pytest.raises(OptionError, match="precision must be a finite number"):
        codec.encode(np.zeros((4, 4), np.float32), value_range=(0, 1), precision=math.inf)
    # numpy scalars are numbers too
    assert codec.encode(dem(), precision=np.float32(0.125)) == codec.encode(dem(), precision=0.125)
    with pytest.raises(OptionError, match="that is the finest step for the value range"):
        codec.encode(dem(), value_range=(-1e38, 1000), max_error=1.0)
    # a constant image near float32's edge fits; at the very edge only as nodata (the
    # format wants |offset| + 65535 scale <= the largest float32, with scale > 0)
    near = np.full((5, 6), np.float32(-3.4e38))
    assert (codec.decode(codec.encode(near)) == near).all()
    edge = np.full((5, 6), np.float32(-F32_MAX))
    with pytest.raises(OptionError, match=re.escape("pass it as nodata (--nodata -3.4028235e+38)")):
        codec.encode(edge)
    assert (codec.decode(codec.encode(edge, nodata=-3.4028235e38)) == edge).all()


def test_cli_names_the_fix_and_leaves_nodata_out_of_the_range(tmp_path):
    z = dem(np.float32(-3.4e38))
    np.save(tmp_path / "gdal.npy", z)
    r = atm("encode", tmp_path / "gdal.npy", tmp_path / "x.atm")
    assert r.returncode == 2 and b"--nodata -3.4e+38" in r.stderr, r.stderr
    assert not (tmp_path / "x.atm").exists()
    # with --nodata the range is the data's own (0..1000), not -9999..1000: the finest
    # step is 1000/65535, so quality 100 keeps every valid sample within half of it
    z = dem(-9999)
    np.save(tmp_path / "dem.npy", z)
    assert atm("encode", tmp_path / "dem.npy", tmp_path / "d.atm", "--nodata", -9999, "--quality", 100).returncode == 0
    assert atm("decode", tmp_path / "d.atm", tmp_path / "d.npy").returncode == 0
    out, valid = np.load(tmp_path / "d.npy"), z != -9999
    assert (out[~valid] == -9999).all()
    step = (z[valid].max() - z[valid].min()) / 65535
    assert np.abs(out[valid].astype(np.float64) - z[valid]).max() <= step / 2 * (1 + 1e-6)
    # +inf holes in a file come back as +inf
    z = dem(np.inf)
    np.save(tmp_path / "inf.npy", z)
    assert atm("encode", tmp_path / "inf.npy", tmp_path / "i.atm").returncode == 0
    assert atm("decode", tmp_path / "i.atm", tmp_path / "i.npy").returncode == 0
    assert (np.load(tmp_path / "i.npy")[np.isinf(z)] == np.inf).all()
    info = atm("info", tmp_path / "i.atm", "--json")
    assert json.loads(info.stdout)["nodata"] == "Infinity"  # strict JSON has no infinity


EXTREMES = st.sampled_from(
    [0.0, -0.0, 1.0, -1.0, 2.0**-149, -(2.0**-149), 2.0**-126, 1e-30, 1e30, 1e38, -1e38,
     -3e38, -3.4e38, F32_MAX, -F32_MAX, math.inf, -math.inf, math.nan, 1e39, -1e300]
)  # fmt: skip
VALUES = st.one_of(EXTREMES, st.floats(width=32), st.floats(-1000, 1000, width=32))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(2, 7), st.integers(2, 7), st.data(),
    st.sampled_from([None, 1e-3, 0.5, 1e30]), st.sampled_from([np.float32, np.float64]),
)  # fmt: skip
def test_extreme_values_decode_within_the_bound_or_are_refused(h, w, data, max_error, dtype):
    values = data.draw(st.lists(VALUES, min_size=h * w, max_size=h * w))
    with np.errstate(over="ignore"):  # beyond float32: infinity, as a float32 reader gives
        z = np.array(values, dtype).reshape(h, w)
    options = {"quality": 100} if max_error is None else {"max_error": max_error}
    try:
        encoded = codec.encode(z, **options)
    except ATMError as exc:
        assert "nodata" in str(exc) or "precision" in str(exc) or "range" in str(exc), exc
        return
    out = codec.decode(encoded)
    holes = ~np.isfinite(z)
    finite = z[~holes].astype(np.float64)
    if finite.size:
        # quality 100 is lossless in levels: the quantisation error alone, half a step
        span = finite.max() - finite.min()
        step = span / 65535 if span > 0 else max(abs(finite.min()), 1.0) * 2.0**-30
        bound = max_error if max_error is not None else step / 2 + max(abs(finite).max() * 2.0**-24, 2.0**-150)
        err = np.abs(out[~holes].astype(np.float64) - finite)
        assert np.isfinite(out[~holes]).all() and err.max() <= bound, (err.max(), bound)
    kinds = {float(v) if not np.isnan(v) else "nan" for v in z[holes]}
    expected = kinds.pop() if len(kinds) == 1 and "nan" not in kinds else math.nan
    np.testing.assert_array_equal(out[holes], np.full(holes.sum(), expected, np.float32))
