"""Error bounds: max_rms, max_error and quality hold on the decoded image, per channel,
for any image, band height and mesher."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.errors import OptionError
from tests.synthetic import range_scene

kinds = st.sampled_from([(np.uint8, 1), (np.uint16, 1), (np.uint8, 3)])


def make(seed: int, h: int, w: int, dtype, channels: int, texture: str) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if texture == "scene":
        base = range_scene(w, h, seed=seed, dtype=dtype)
        image = base if channels == 1 else np.stack([base, base[::-1], base[:, ::-1]], 2)
    elif texture == "noise":
        image = rng.integers(0, np.iinfo(dtype).max + 1, (h, w, channels)[: 2 + (channels > 1)], dtype=np.int64)
    else:
        image = np.full((h, w, channels)[: 2 + (channels > 1)], rng.integers(0, 255))
    return np.ascontiguousarray(image).astype(dtype)


def per_channel(out: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = (out.astype(np.float64) - image).reshape(image.shape[0] * image.shape[1], -1)
    return np.sqrt((d**2).mean(axis=0)), np.abs(d).max(axis=0)


images = st.tuples(
    st.integers(0, 10**6),
    st.integers(1, 40),
    st.integers(1, 40),
    kinds,
    st.sampled_from(["scene", "noise", "flat"]),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images, st.floats(0, 40), st.sampled_from([None, 3, 16]), st.sampled_from(["uniform", None]),
       st.sampled_from([None, False]))
def test_max_rms_holds(args, bound, band_height, mesher, residual):
    # refinement of the mesh alone (residual=False), or the default residual layer
    seed, h, w, (dtype, channels), texture = args
    image = make(seed, h, w, dtype, channels, texture)
    scale = np.iinfo(dtype).max / 255
    out = codec.decode(codec.encode(image, max_rms=bound * scale, band_height=band_height, mesher=mesher,
                                    residual=residual))
    rms, _ = per_channel(out, image)
    assert (rms <= bound * scale + 1e-9).all()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images, st.integers(0, 60), st.sampled_from([None, 3, 16]), st.sampled_from(["uniform", None]),
       st.sampled_from([None, False]))
def test_max_error_holds(args, bound, band_height, mesher, residual):
    seed, h, w, (dtype, channels), texture = args
    image = make(seed, h, w, dtype, channels, texture)
    scale = np.iinfo(dtype).max // 255
    out = codec.decode(codec.encode(image, max_error=bound * scale, band_height=band_height, mesher=mesher,
                                    residual=residual))
    _, worst = per_channel(out, image)
    assert (worst <= bound * scale).all()


def test_zero_error_is_lossless():
    image = range_scene(50, 40, seed=3, dtype=np.uint16)
    np.testing.assert_array_equal(codec.decode(codec.encode(image, max_error=0)), image)
    np.testing.assert_array_equal(codec.decode(codec.encode(image, quality=100)), image)


def test_quality_is_monotonic_in_size_and_rms(corpus):
    image = corpus["coins"]
    sizes, errors = [], []
    for q in (5, 20, 40, 60, 80):
        data = codec.encode(image, quality=q)
        rms, _ = per_channel(codec.decode(data), image)
        sizes.append(len(data))
        errors.append(float(rms[0]))
    assert sizes == sorted(sizes), sizes
    assert errors == sorted(errors, reverse=True), errors


def test_bad_bounds_are_option_errors():
    image = np.zeros((8, 8), np.uint8)
    for kw in (dict(max_rms=-1), dict(max_error="x"), dict(quality=0), dict(quality=101), dict(quality=50, max_rms=3)):
        with pytest.raises(OptionError):
            codec.encode(image, **kw)


def test_quality_follows_jpegs_error_on_the_corpus():
    """quality q bounds the RMS at about what JPEG's quality q gives (the corpus median)."""
    import cv2

    from codec.error_bound import quality_rms
    from tests.corpus import load_corpus

    images = list(load_corpus().values())
    for q in (10, 50, 90):
        errors = []
        for image in images:
            ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, q])
            back = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED).astype(float)
            errors.append(np.sqrt(np.mean((back - image) ** 2)))
        assert quality_rms(q, np.dtype(np.uint8)) == pytest.approx(np.median(errors), rel=0.05), q
    assert quality_rms(100, np.dtype(np.uint8)) == 0.0
    assert quality_rms(50, np.dtype(np.uint16)) == pytest.approx(257 * quality_rms(50, np.dtype(np.uint8)))


def test_a_float_dems_max_error_takes_few_rounds(monkeypatch):
    """#20: under max_error on float data the quantisation step leaves the mesh a bound
    below one level, so most pixels stay over it until most are vertices; rounds that
    grow the mesh by a quarter took 27 on this 192² DEM (each a whole render and
    measurement); growing also by a share of the pixels over the bound
    (error_bound.FAR) takes about 12. The bound still holds."""
    import cv2

    from codec import error_bound

    rng = np.random.default_rng(3)
    dem = np.zeros((192, 192), np.float32)
    cells, amp = 4, 800.0
    while cells <= 192:
        dem += amp * cv2.resize(rng.standard_normal((cells, cells)).astype(np.float32), (192, 192),
                                interpolation=cv2.INTER_CUBIC)
        cells, amp = cells * 2, amp / 2
    rounds = []
    measure = error_bound._Errors.measure
    monkeypatch.setattr(error_bound._Errors, "measure", lambda *a: rounds.append(1) or measure(*a))
    out = codec.decode(codec.encode(dem, max_error=2.0))
    assert np.abs(out.astype(np.float64) - dem).max() <= 2.0
    assert len(rounds) <= 16
