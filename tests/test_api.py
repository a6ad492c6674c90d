"""The Python API: round trips, determinism, exact vertices and errors on bad input."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.errors import ATMError, OptionError

images = st.tuples(
    st.integers(1, 70),
    st.integers(1, 70),
    st.sampled_from([np.uint8, np.uint16]),
    st.sampled_from([1, 3]),
    st.integers(0, 2**32 - 1),
)


def make_image(h, w, dtype, channels, seed) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (h, w) if channels == 1 else (h, w, channels)
    smooth = np.add.outer(np.arange(h), np.arange(w)) * (np.iinfo(dtype).max // 140)
    if channels == 3:
        smooth = smooth[:, :, None]
    noise = rng.integers(0, 20, shape)
    return np.clip(smooth + noise, 0, np.iinfo(dtype).max).astype(dtype)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images, st.sampled_from(["uniform", None]))
def test_round_trip_keeps_shape_and_dtype(args, mesher):
    image = make_image(*args)
    out = codec.decode(codec.encode(image, mesher=mesher))
    assert out.shape == image.shape
    assert out.dtype == image.dtype


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(images)
def test_vertex_pixels_decode_to_their_stored_values(args):
    image = make_image(*args)
    data = codec.encode(image)
    m = codec.decode_mesh(data)
    out = codec.decode(data)
    x, y = m.vertices[:, 0], m.vertices[:, 1]
    np.testing.assert_array_equal(out[y, x], m.values)


@settings(max_examples=30, deadline=None)
@given(images)
def test_encoding_is_deterministic(args):
    image = make_image(*args)
    assert codec.encode(image) == codec.encode(image.copy())


def test_points_lands_within_ten_percent_for_uniform():
    image = np.zeros((300, 200), np.uint8)
    for n in (10, 100, 1000, 4000, 20000):
        got = len(codec.build_mesh(image, points=n, mesher="uniform").vertices)
        assert abs(got - n) <= 0.1 * n, (n, got)


def test_uniform_rms_on_camera_matches_the_baseline(corpus):
    image = corpus["camera"]
    out = codec.decode(codec.encode(image, points=4000, mesher="uniform"))
    rms = np.sqrt(np.mean((out.astype(float) - image) ** 2))
    assert 15 < rms < 25  # a 63 x 63 grid with pixel values: the paper's uniform baseline


def test_every_pixel_as_vertex_is_lossless():
    image = make_image(17, 23, np.uint16, 1, 3)
    out = codec.decode(codec.encode(image, points=17 * 23, mesher="uniform"))
    np.testing.assert_array_equal(out, image)


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros((0, 5), np.uint8), "empty"),
        (np.zeros(5, np.uint8), "2-D"),
        (np.zeros((2, 2, 2, 2), np.uint8), "2-D"),
        (np.zeros((4, 4, 4), np.uint8), "4 channels"),
        (np.zeros((4, 4), np.complex64), "complex64"),
        (np.zeros((4, 4, 3), np.float32), "one channel"),
        (np.zeros((4, 4), np.int64), "int64"),
        ("not an image", "unsupported pixel type"),
    ],
)
def test_bad_images_raise_atm_error(bad, message):
    with pytest.raises(ATMError, match=message):
        codec.encode(bad)


def test_bad_options_raise_option_error():
    image = np.zeros((8, 8), np.uint8)
    with pytest.raises(OptionError, match="unknown mesher"):
        codec.encode(image, mesher="nope")
    with pytest.raises(OptionError, match="points"):
        codec.encode(image, points=0)
    with pytest.raises(OptionError, match="unknown encoder option colour; the options are: points, quality"):
        codec.encode(image, mesher="uniform", colour=1)
    with pytest.raises(OptionError, match="mesher 'uniform' has no option effort; its options are: values"):
        codec.encode(image, mesher="uniform", effort=3)
    with pytest.raises(OptionError, match="backend"):
        codec.decode(codec.encode(image), backend="nope")


def test_write_and_read_files(tmp_path):
    image = make_image(30, 40, np.uint8, 1, 0)
    path = tmp_path / "x.atm"
    codec.write(path, image, mesher="uniform", points=300)
    assert codec.read(path).shape == image.shape
    assert sorted(os.listdir(tmp_path)) == ["x.atm"]


def test_failed_write_keeps_the_existing_file(tmp_path):
    path = tmp_path / "x.atm"
    path.write_bytes(b"precious")
    with pytest.raises(ATMError):
        codec.write(path, np.zeros((0, 3), np.uint8))
    assert path.read_bytes() == b"precious"
    assert sorted(os.listdir(tmp_path)) == ["x.atm"]


def test_import_is_light():
    import subprocess
    import sys

    code = "import sys, codec; print(sorted(m for m in ('cv2', 'moderngl', 'triangle', 'zstandard') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_images_over_the_limits_are_refused_before_work(monkeypatch):
    from codec import limits

    monkeypatch.setattr(limits, "MAX_IMAGE_PIXELS", 1000)
    with pytest.raises(codec.LimitError, match="MAX_IMAGE_PIXELS"):
        codec.encode(np.zeros((40, 30), np.uint8))
    with pytest.raises(codec.LimitError, match="MAX_IMAGE_PIXELS"):
        codec.StreamEncoder(io.BytesIO(), 100, 100)
    monkeypatch.setattr(limits, "MAX_IMAGE_PIXELS", 1 << 28)
    data = codec.encode(np.zeros((40, 30), np.uint8))
    monkeypatch.setattr(limits, "MAX_IMAGE_PIXELS", 1000)
    with pytest.raises(codec.LimitError, match="1,200 pixels"):
        codec.decode(data)


@pytest.mark.parametrize("options", [dict(points=200), dict(max_error=3), dict(max_error=3, residual=False)])
def test_decode_returns_an_array_of_its_own(options):
    """A one-band file's render is returned as the decoded image without a copy: it must
    still be an array that owns its memory, as a freshly made image is (resizable,
    sharing nothing with another decode)."""
    image = (np.arange(40 * 30).reshape(30, 40) % 97).astype(np.uint8)
    data = codec.encode(image, **options)
    a, b = codec.decode(data), codec.decode(data)
    assert a.flags.owndata and a.flags.writeable and not np.shares_memory(a, b)
    a.resize((10, 4), refcheck=False)
