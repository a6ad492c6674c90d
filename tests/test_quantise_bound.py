"""Issue #21: the quantisation a bound chooses (codec.pipeline._float_step) and the
residual layer under max_rms (codec.representation), and the default representation."""

from __future__ import annotations

import io

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import pipeline, quantise
from codec.settings import Settings
from tests.synthetic import range_scene


def _float_dem(side: int = 96, seed: int = 0, sea: bool = True) -> np.ndarray:
    """Smooth terrain in metres (float32) with a rough surface, NaN below sea level."""
    import cv2

    rng = np.random.default_rng(seed)
    z = np.zeros((side, side))
    for s in (24, 8, 2):
        z += cv2.GaussianBlur(rng.standard_normal((side, side)), (0, 0), s) * s * 40
    z = (z - z.min()) / (z.max() - z.min()) * 900 - (150 if sea else -10)
    z = z.astype(np.float32)
    z[z < 0] = np.nan
    return z


def _errors(img: np.ndarray, data: bytes) -> np.ndarray:
    valid = np.isfinite(img)
    return codec.decode(data).astype(np.float64)[valid] - img[valid].astype(np.float64)


def test_max_error_chooses_a_coarse_float_step_that_the_mesh_spends():
    # the finest step (span / 65535) made every vertex value a 16-bit number; under
    # max_error the mesh path quantises to about 2E and keeps every level exact
    img = _float_dem()
    lo, hi = float(np.nanmin(img)), float(np.nanmax(img))
    for e in (0.5, 2.0, 10.0):
        p = pipeline.plan(Settings(max_error=e, value_range=(lo, hi), residual=False), *img.shape[::-1], np.float32)
        assert 1.99 * e < p.quant.scale < 2 * e
        assert p.bound.max_error == 0
        chosen = codec.encode(img, max_error=e, residual=False)
        finest = codec.encode(img, max_error=e, residual=False, precision=(hi - lo) / quantise.LEVELS)
        err = np.abs(_errors(img, chosen)).max()
        assert err <= e
        assert err >= 0.9 * e, "the budget is used"
        assert len(chosen) < 0.85 * len(finest), (e, len(chosen), len(finest))


def test_precision_stays_an_override_and_the_layer_keeps_the_finest_step():
    img = _float_dem(48)
    lo, hi = float(np.nanmin(img)), float(np.nanmax(img))
    w, h = img.shape[::-1]
    assert pipeline.plan(Settings(max_error=2.0, value_range=(lo, hi), precision=0.25), w, h, np.float32).quant.scale == 0.25
    finest = (hi - lo) / quantise.LEVELS
    for s in (Settings(max_error=2.0, value_range=(lo, hi), residual=True), Settings(max_rms=2.0, value_range=(lo, hi)),
              Settings(max_error=2.0, value_range=(lo, hi))):  # the default: the layer
        assert pipeline.plan(s, w, h, np.float32).quant.scale == finest


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**16), side=st.integers(8, 40), e=st.sampled_from([0.01, 0.3, 1.0, 7.5, 40.0]),
    offset=st.sampled_from([0.0, -500.0, 3000.0]), sea=st.booleans(), residual=st.sampled_from([None, False]),
)
def test_max_error_holds_with_the_chosen_step(seed, side, e, offset, sea, residual):
    # whatever represents the image (the default layer, or the mesh alone)
    img = _float_dem(side, seed, sea) + np.float32(offset)
    if not np.isfinite(img).any():
        return
    data = codec.encode(img, max_error=e, residual=residual)
    assert np.abs(_errors(img, data)).max() <= e
    assert np.array_equal(np.isnan(codec.decode(data)), np.isnan(img))


def _rms(img: np.ndarray, data: bytes, valid: np.ndarray) -> float:
    d = codec.decode(data).astype(np.float64)[valid] - img[valid].astype(np.float64)
    return float(np.sqrt((d**2).mean()))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**16), side=st.integers(6, 40), kind=st.sampled_from(["u8", "u16holes", "f32"]),
    target=st.sampled_from([0.4, 1.0, 3.0, 12.0, 50.0]),
)
def test_max_rms_with_the_layer_holds(seed, side, kind, target):
    rng = np.random.default_rng(seed)
    if kind == "u8":
        img = np.clip(range_scene(side, side, seed=seed) + rng.normal(0, 6, (side, side)), 0, 255).astype(np.uint8)
        nodata, valid = None, np.ones(img.shape, bool)
    elif kind == "u16holes":
        img = range_scene(side, side, seed=seed, dtype=np.uint16)
        img[rng.random(img.shape) < 0.3] = 0
        nodata, valid = 0, img != 0
    else:
        img = _float_dem(side, seed)
        nodata, valid = None, np.isfinite(img)
        if not valid.any():
            return
    data = codec.encode(img, max_rms=target, residual=True, nodata=nodata)
    assert _rms(img, data, valid) <= target


def test_max_rms_layer_widens_its_bound_and_beats_the_mesh():
    rng = np.random.default_rng(3)
    img = np.clip(range_scene(96, 96, seed=3, dtype=np.uint16).astype(np.float64) + rng.normal(0, 40, (96, 96)),
                  0, 65535).astype(np.uint16)
    target = 20.0
    valid = np.ones(img.shape, bool)
    layer = codec.encode(img, max_rms=target, residual=True)
    safe = codec.encode(img, max_error=target, residual=True)  # every sample within max_rms
    mesh = codec.encode(img, max_rms=target, residual=False)
    got = _rms(img, layer, valid)
    assert 0.7 * target <= got <= target, got
    assert len(layer) < 0.9 * len(safe)
    assert len(layer) < len(mesh)


def test_stream_encoder_widens_max_rms_as_codec_encode_does():
    # the bound is widened from the first band (the rest counted at the worst error E),
    # so a stream of rows gives codec.encode's bytes; before, the stream kept E =
    # floor(max_rms) and codec.encode encoded up to six times
    rng = np.random.default_rng(5)
    img = np.clip(range_scene(64, 48, seed=5, dtype=np.uint16) + rng.normal(0, 30, (48, 64)), 0, 65535).astype(np.uint16)
    for band_height in (16, 64):
        out = io.BytesIO()
        with codec.StreamEncoder(out, 64, 48, dtype=np.uint16, max_rms=9.0, band_height=band_height) as enc:
            for y in range(0, 48, 5):
                enc.write(img[y : y + 5])
        data = out.getvalue()
        assert data == codec.encode(img, max_rms=9.0, band_height=band_height)
        assert _rms(img, data, np.ones(img.shape, bool)) <= 9.0
        assert codec.info(data)["residual"] > 9, "the bound is widened"


def test_max_rms_layer_is_the_widest_its_predictor_allows():
    # one band: the first band's samples are the image's, so E is the widest that meets
    # max_rms (for the predictor chosen); E + 1 with the same predictor would miss it
    from codec import representation, residual as layer

    rng = np.random.default_rng(8)
    img = np.clip(range_scene(48, 40, seed=8, dtype=np.uint16) + rng.normal(0, 25, (40, 48)), 0, 65535).astype(np.uint16)
    for target in (5.0, 17.0, 60.0):
        error, predictor = representation.layer_under_rms(img, None, 1, np.dtype(np.uint16), target, 0)
        data = codec.encode(img, max_rms=target)
        assert codec.info(data)["residual"] == error
        assert _rms(img, data, np.ones(img.shape, bool)) <= target
        if predictor == layer.MED:
            wider = representation.decoded_error(img.astype(np.int64), error + 1, 65535)
            assert np.sqrt((wider**2).mean()) > target


def test_residual_auto_keeps_the_smaller_of_mesh_and_layer():
    yy, xx = np.mgrid[0:64, 0:64]
    ramp = (3 * xx + 2 * yy).astype(np.uint16)  # a plane: four vertices beat any layer
    rng = np.random.default_rng(0)
    noisy = np.clip(range_scene(64, 64, seed=1) + rng.normal(0, 5, (64, 64)), 0, 255).astype(np.uint8)
    picked = set()
    for img, bound in ((ramp, dict(max_error=2)), (noisy, dict(max_error=2)), (noisy, dict(max_rms=3.0))):
        mesh = codec.encode(img, residual=False, **bound)
        layered = codec.encode(img, residual=True, **bound)
        auto = codec.encode(img, residual="auto", **bound)
        assert auto == min(mesh, layered, key=len)
        picked.add("layer" if auto == layered else "mesh")
        d = codec.decode(auto).astype(np.float64) - img
        if "max_error" in bound:
            assert np.abs(d).max() <= bound["max_error"]
        else:
            assert np.sqrt((d**2).mean()) <= bound["max_rms"]
    assert picked == {"mesh", "layer"}


def test_residual_auto_is_refused_where_it_cannot_compare():
    import pytest

    from codec.errors import OptionError

    with pytest.raises(OptionError, match="residual='auto' compares two encodes of the whole image"):
        codec.StreamEncoder(io.BytesIO(), 8, 8, max_error=2, residual="auto")
    with pytest.raises(OptionError, match="residual must be True, False, 'auto' or None"):
        codec.encode(np.zeros((8, 8), np.uint8), max_error=2, residual="yes")
    with pytest.raises(OptionError, match="residual needs max_error or max_rms"):
        codec.encode(np.zeros((8, 8), np.uint8), residual="auto")
