"""Round trips for the three sample kinds .atm stores: uint8 gray, uint16 gray, uint8 RGB.

Three properties pin the error down without depending on how a mesher places its points:
- quality=100 is lossless, so the round trip is exact;
- a plane is reproduced by any triangulation of samples on it, so at any vertex count
  the only error left is rounding: at most 1 per sample, hence RMS <= 1 per channel;
- a max_rms bound holds on every channel of the decoded image.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import codec

KINDS = {
    "gray8": (np.uint8, 1),
    "gray16": (np.uint16, 1),
    "rgb8": (np.uint8, 3),
}

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _shape(height: int, width: int, channels: int) -> tuple[int, ...]:
    return (height, width) if channels == 1 else (height, width, channels)


@st.composite
def images(draw) -> np.ndarray:
    """Any image of one of the three kinds, up to 12 x 12 pixels."""
    dtype, channels = KINDS[draw(st.sampled_from(sorted(KINDS)))]
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    return draw(arrays(dtype, _shape(h, w, channels)))


@st.composite
def planes(draw) -> tuple[np.ndarray, int]:
    """A plane a*x + b*y + c per channel, sampled (floored) into one of the three kinds,
    with a vertex count anywhere from the four corners to every pixel."""
    dtype, channels = KINDS[draw(st.sampled_from(sorted(KINDS)))]
    h, w = draw(st.integers(2, 24)), draw(st.integers(2, 24))
    top = float(np.iinfo(dtype).max)
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    layers = []
    for _ in range(channels):
        # slopes chosen so that the plane stays inside the sample range over the image
        a = draw(st.floats(-1.0, 1.0)) * top / (2 * w)
        b = draw(st.floats(-1.0, 1.0)) * top / (2 * h)
        c = top / 2 - a * (w - 1) / 2 - b * (h - 1) / 2
        layers.append(np.floor(a * xx + b * yy + c))
    plane = np.stack(layers, -1) if channels == 3 else layers[0]
    points = draw(st.integers(4, h * w))
    return np.clip(plane, 0, top).astype(dtype), points


def _errors(decoded: np.ndarray, image: np.ndarray) -> np.ndarray:
    return decoded.astype(np.float64) - image.astype(np.float64)


@SETTINGS
@given(images())
def test_lossless_round_trips_exactly(image):
    data = codec.encode(image, quality=100)
    decoded = codec.decode(data)
    assert decoded.shape == image.shape and decoded.dtype == image.dtype
    info = codec.info(data)
    assert info["channels"] == (1 if image.ndim == 2 else 3)
    assert info["dtype"] == str(image.dtype)
    np.testing.assert_array_equal(decoded, image)


@SETTINGS
@given(planes())
def test_planes_round_trip_within_rounding_at_any_vertex_count(case):
    image, points = case
    decoded = codec.decode(codec.encode(image, points=points))
    assert decoded.shape == image.shape and decoded.dtype == image.dtype
    err = _errors(decoded, image).reshape(image.shape[0] * image.shape[1], -1)
    rms_per_channel = np.sqrt(np.mean(err**2, axis=0))
    assert (rms_per_channel <= 1.0).all(), rms_per_channel
    assert np.abs(err).max() <= 1


@SETTINGS
@given(images(), st.integers(1, 5))
def test_kind_survives_banding_and_the_mesh_carries_per_vertex_samples(image, band_height):
    data = codec.encode(image, quality=100, band_height=band_height)
    np.testing.assert_array_equal(codec.decode(data), image)
    m = codec.decode_mesh(data)
    assert m.dtype == image.dtype and m.channels == (1 if image.ndim == 2 else 3)
    # one shared mesh: every vertex carries all channels, and (lossless) they are its
    # own pixel's samples
    x, y = m.vertices[:, 0], m.vertices[:, 1]
    np.testing.assert_array_equal(m.values, image[y, x])


@SETTINGS
@given(images(), st.floats(0.5, 40.0))
def test_max_rms_holds_per_channel(image, bound):
    top = np.iinfo(image.dtype).max
    bound = bound * top / 255  # the same bound relative to the sample range
    decoded = codec.decode(codec.encode(image, max_rms=bound))
    assert decoded.shape == image.shape and decoded.dtype == image.dtype
    err = _errors(decoded, image).reshape(image.shape[0] * image.shape[1], -1)
    rms_per_channel = np.sqrt(np.mean(err**2, axis=0))
    assert (rms_per_channel <= bound * (1 + 1e-9)).all(), (rms_per_channel, bound)
