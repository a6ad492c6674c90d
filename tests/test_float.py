"""Float images (elevations, depths in real units): quantised with a stored scale and
offset, decoded as float32, with error bounds in data units."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.errors import ATMError, OptionError
from tests.synthetic import range_scene


def elevation(seed: int, h: int, w: int, scale: float, base: float) -> np.ndarray:
    return range_scene(w, h, seed=seed).astype(np.float64) * scale + base


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 1000), st.integers(1, 40), st.integers(1, 40),
    st.floats(0.001, 50), st.floats(-5000, 5000), st.floats(0.01, 10), st.sampled_from([None, 5]),
)
def test_max_error_holds_in_data_units(seed, h, w, scale, base, bound_steps, band_height):
    z = elevation(seed, h, w, scale, base)
    # a bound comparable to the data's own steps, and above float32's resolution
    bound = max(bound_steps * scale, 1e-5 * (abs(base) + 255 * scale))
    out = codec.decode(codec.encode(z, max_error=bound, band_height=band_height))
    assert out.dtype == np.float32 and out.shape == z.shape
    assert np.abs(out.astype(np.float64) - z).max() <= bound


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 1000), st.integers(2, 40), st.integers(2, 40), st.floats(0.05, 5))
def test_max_rms_holds_in_data_units(seed, h, w, bound):
    z = elevation(seed, h, w, 0.5, 100.0)
    out = codec.decode(codec.encode(z, max_rms=bound))
    assert np.sqrt(np.mean((out.astype(np.float64) - z) ** 2)) <= bound


def test_precision_sets_the_step():
    z = elevation(1, 30, 40, 0.37, 1200.0)
    out = codec.decode(codec.encode(z, precision=0.25, max_error=0.13))
    assert np.abs(out - z).max() <= 0.13
    steps = (out.astype(np.float64) - z.min()) / 0.25
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)


def test_impossible_precision_and_bounds_are_option_errors():
    z = elevation(1, 20, 20, 10.0, 0.0)
    with pytest.raises(OptionError, match="levels"):
        codec.encode(z, precision=1e-6)
    with pytest.raises(OptionError, match="finer than the quantisation step"):
        codec.encode(z, precision=1.0, max_error=0.1)
    with pytest.raises(OptionError, match="float images only"):
        codec.encode(np.zeros((4, 4), np.uint8), precision=0.5)


def test_float_streams_need_a_range_and_match_one_shot():
    z = elevation(2, 33, 27, 1.5, -20.0)
    with pytest.raises(OptionError, match="value_range"):
        codec.StreamEncoder(io.BytesIO(), 27, 33, dtype=np.float64)
    rng = (float(z.min()), float(z.max()))
    out = io.BytesIO()
    with codec.StreamEncoder(out, 27, 33, dtype=np.float64, value_range=rng, band_height=8, max_error=1.0) as enc:
        for y in range(0, 33, 5):
            enc.write(z[y : y + 5])
    assert out.getvalue() == codec.encode(z, band_height=8, max_error=1.0)
    with pytest.raises(ATMError, match="outside the declared range"):
        enc2 = codec.StreamEncoder(io.BytesIO(), 27, 33, dtype=np.float64, value_range=(0, 1))
        enc2.write(z[:2])


def test_nan_and_infinity_are_holes_and_all_holes_works():
    z = np.zeros((5, 5), np.float32)
    z[2, 2], z[0, 4] = np.nan, -np.inf
    out = codec.decode(codec.encode(z))
    assert np.isnan(out[2, 2]) and np.isnan(out[0, 4]) and np.count_nonzero(np.isnan(out)) == 2
    assert np.isnan(codec.decode(codec.encode(np.full((3, 4), np.nan)))).all()
    holes = codec.build_mesh(z).holes  # the mesh keeps them as its hole mask
    assert holes is not None and holes[2, 2] and holes[0, 4] and holes.sum() == 2


def test_constant_float_image():
    z = np.full((7, 9), 3.25)
    np.testing.assert_array_equal(codec.decode(codec.encode(z)), np.float32(3.25))
