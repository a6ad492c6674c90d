"""The residual layer (ATM.md §4.8): lossless and near-lossless coding whose bound
holds by construction, decoded alike by both backends and the reference decoder, and
malformed RESD chunks refused with CorruptError."""

from __future__ import annotations

import io
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import residual
from codec.errors import CorruptError, OptionError, UnsupportedError
from tests.conftest import chunks
from tests.synthetic import range_scene

INTEGER_TYPES = (np.uint8, np.uint16, np.int16, np.int8)


def _image(seed: int, h: int, w: int, dtype, hole_share: float) -> tuple[np.ndarray, np.ndarray]:
    """A range scene (steps and slopes) with noise, in dtype, and random holes."""
    rng = np.random.default_rng(seed)
    info = np.iinfo(dtype)
    scene = range_scene(w, h, seed=seed).astype(np.float64) / 255.0
    noise = rng.normal(0, 0.02, (h, w))
    values = info.min + np.clip(scene + noise, 0, 1) * (float(info.max) - info.min)
    image = np.rint(values).astype(dtype)
    holes = rng.random((h, w)) < hole_share
    return image, holes


def _nodata(dtype):
    return int(np.iinfo(dtype).min)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 10_000), st.integers(1, 30), st.integers(1, 40), st.sampled_from(INTEGER_TYPES),
    st.sampled_from([0.0, 0.1, 0.4]), st.sampled_from([0, 1, 2, 7, 300]), st.sampled_from([None, 1, 4]),
)
def test_integer_bound_holds_with_holes(seed, h, w, dtype, hole_share, error, band_height):
    image, holes = _image(seed, h, w, dtype, hole_share)
    nodata = _nodata(dtype)
    image[holes] = nodata
    valid = image != nodata
    options = dict(lossless=True) if error == 0 else dict(max_error=error, residual=True)
    data = codec.encode(image, nodata=nodata if holes.any() else None, band_height=band_height, **options)
    out = codec.decode(data)
    assert out.dtype == image.dtype and out.shape == image.shape
    diff = np.abs(out.astype(np.int64) - image.astype(np.int64))
    assert diff[valid].max(initial=0) <= error
    if error == 0:
        assert np.array_equal(out, image)
    assert np.array_equal(out[~valid], image[~valid])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.integers(1, 30), st.integers(1, 30), st.floats(0.01, 20), st.floats(-1000, 1000),
       st.sampled_from([0.0, 0.2]))
def test_float_bound_holds_with_nan_holes(seed, h, w, bound, base, hole_share):
    rng = np.random.default_rng(seed)
    z = (range_scene(w, h, seed=seed).astype(np.float64) * 0.7 + base + rng.normal(0, 0.3, (h, w))).astype(np.float32)
    z[rng.random((h, w)) < hole_share] = np.nan
    valid = ~np.isnan(z)
    out = codec.decode(codec.encode(z, max_error=bound, residual=True))
    assert np.array_equal(np.isnan(out), ~valid)
    assert np.abs(out[valid].astype(np.float64) - z[valid]).max(initial=0) <= bound


@pytest.mark.usefixtures("gl")
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.integers(2, 24), st.integers(2, 30), st.sampled_from([np.uint8, np.uint16]),
       st.sampled_from([0, 3]), st.booleans())
def test_cpu_gl_and_stream_agree(seed, h, w, dtype, error, rgb):
    image, holes = _image(seed, h, w, dtype, 0.1)
    if rgb:
        image = np.stack([image, image[::-1], image[:, ::-1]], axis=-1)
    options = dict(lossless=True) if error == 0 else dict(max_error=error, residual=True)
    data = codec.encode(image, band_height=5, **options)
    cpu = codec.decode(data)
    assert np.abs(cpu.astype(np.int64) - image).max() <= error
    assert np.array_equal(cpu, codec.decode(data, backend="gl"))
    rows = np.concatenate([r for _, r in codec.StreamDecoder(io.BytesIO(data))])
    assert np.array_equal(rows, cpu)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.integers(1, 14), st.integers(1, 16), st.sampled_from(INTEGER_TYPES),
       st.sampled_from([0, 1, 5]), st.booleans(), st.sampled_from([None, 3]))
def test_reference_decoder_agrees(seed, h, w, dtype, error, with_holes, band_height):
    from codec.format_spec import reference_decoder

    image, holes = _image(seed, h, w, dtype, 0.2 if with_holes else 0.0)
    nodata = _nodata(dtype) if holes.any() else None
    image[holes] = _nodata(dtype)
    options = dict(lossless=True) if error == 0 else dict(max_error=error, residual=True)
    data = codec.encode(image, nodata=nodata, band_height=band_height, **options)
    assert np.array_equal(reference_decoder.decode(data), codec.decode(data))


def test_both_predictors_agree_with_the_reference_decoder():
    """Bands of flat regions and steps and bands of smooth slopes: the encoder picks
    each band's predictor by its bytes (MED for the steps, interpolation for the
    slopes), and the state one predictor leaves serves the next."""
    from codec.format_spec import reference_decoder

    yy, xx = np.mgrid[0:60, 0:50]
    smooth = 20000 + 150 * np.sin(xx / 9.0) * yy + 40 * xx
    steps = range_scene(50, 60, seed=1).astype(np.int64) * 200
    for image in (np.where(yy < 30, steps, smooth), np.where(yy >= 30, steps, smooth)):
        image = image.astype(np.uint16)
        image[40:45, 10:20] = 0
        image[12:14, 0:3] = 0
        data = codec.encode(image, max_error=60, residual=True, band_height=10, nodata=0)
        assert {p[8] for _, t, p in chunks(data) if t == residual.CHUNK} == {residual.MED, residual.INTERPOLATION}
        out = codec.decode(data)
        assert np.array_equal(reference_decoder.decode(data), out)
        assert np.abs(out.astype(np.int64) - image)[image != 0].max() <= 60


def test_reference_decoder_refuses_a_truncated_layer():
    from codec.format_spec import reference_decoder

    _, data = _layered()
    with pytest.raises(reference_decoder.DecodeError, match="RESD"):
        reference_decoder.decode(_rebuild(data, _first_resd(lambda t, p: (t, p[:-1]))))


def test_lossless_uses_the_layer_and_a_light_mesh():
    image, _ = _image(3, 64, 80, np.uint16, 0.0)
    data = codec.encode(image, lossless=True)
    assert residual.CHUNK in [t for _, t, _ in chunks(data)]
    assert codec.info(data)["vertices"] <= 40
    assert np.array_equal(codec.decode(data), image)
    # points sets the preview mesh's size, with either kind of layer
    assert codec.info(codec.encode(image, lossless=True, points=400))["vertices"] >= 300
    assert codec.info(codec.encode(image, max_error=5, residual=True, points=400))["vertices"] >= 300


@pytest.mark.parametrize("bound", [dict(max_error=5), dict(max_rms=3)])
def test_points_size_the_preview_beside_the_default_layer(bound):
    """The layer is the default way to meet a bound, so `points` goes with max_error or
    max_rms without residual=True: it sizes the mesh, the layer keeps the bound. Only a
    mesh that must meet the bound alone (residual=False, or 'auto', which tries it)
    refuses the pair."""
    image, _ = _image(4, 64, 80, np.uint16, 0.0)
    data = codec.encode(image, points=400, **bound)
    assert 300 <= codec.info(data)["vertices"] <= 400
    assert residual.CHUNK in [t for _, t, _ in chunks(data)]
    error = np.abs(codec.decode(data).astype(np.int64) - image)
    if "max_error" in bound:
        assert error.max() <= 5
    else:
        assert np.sqrt((error.astype(float) ** 2).mean()) <= 3
    name = next(iter(bound))
    for mesh_only in (False, "auto"):
        with pytest.raises(OptionError, match=f"points and {name} both set the size"):
            codec.encode(image, points=400, residual=mesh_only, **bound)


def test_info_reports_the_layer(tmp_path):
    image, _ = _image(9, 20, 30, np.uint16, 0.0)
    assert codec.info(codec.encode(image, lossless=True))["residual"] == 0
    assert codec.info(codec.encode(image, max_error=7, residual=True))["residual"] == 7
    assert codec.info(codec.encode(image, max_error=7))["residual"] == 7  # the default: the layer
    assert codec.info(codec.encode(image, max_error=7, residual=False))["residual"] is None
    path = tmp_path / "x.atm"
    path.write_bytes(codec.encode(image, lossless=True))
    shown = subprocess.run([sys.executable, "-m", "codec", "info", str(path)], capture_output=True, text=True, check=True)
    assert "residual layer: lossless" in shown.stdout


def test_stream_encoder_gives_the_same_bytes():
    image, holes = _image(5, 50, 33, np.uint16, 0.2)
    image[holes] = 0
    whole = codec.encode(image, max_error=3, residual=True, nodata=0, band_height=7)
    out = io.BytesIO()
    with codec.StreamEncoder(out, 33, 50, dtype=np.uint16, max_error=3, residual=True, nodata=0, band_height=7) as enc:
        for y in range(0, 50, 9):
            enc.write(image[y : y + 9])
    assert out.getvalue() == whole


def test_options_are_checked():
    image = np.zeros((8, 8), np.uint8)
    with pytest.raises(OptionError, match="lossless and max_error both set the size"):
        codec.encode(image, lossless=True, max_error=2)
    with pytest.raises(OptionError, match="lossless must be True or False"):
        codec.encode(image, lossless=1)
    with pytest.raises(OptionError, match="residual needs max_error"):
        codec.encode(image, residual=True)
    with pytest.raises(OptionError, match="residual and quality both set the size"):
        codec.encode(image, residual=True, quality=50, max_error=3)
    # residual=False: the bound is met by the mesh alone, no layer; by default, the layer
    assert residual.CHUNK not in [t for _, t, _ in chunks(codec.encode(image, max_error=3, residual=False))]
    assert residual.CHUNK in [t for _, t, _ in chunks(codec.encode(image, max_error=3))]
    # float64 that binary32 cannot hold has no exact form in .atm (tests/test_lossless_float.py)
    with pytest.raises(UnsupportedError, match="lossless float64 data must hold binary32 values"):
        codec.encode(np.full((4, 4), 0.1), lossless=True)


def test_cli_lossless(tmp_path):
    image, _ = _image(8, 20, 30, np.uint16, 0.0)
    src = tmp_path / "in.npy"
    np.save(src, image)
    out = tmp_path / "out.atm"
    subprocess.run([sys.executable, "-m", "codec", "encode", str(src), str(out), "--lossless"], check=True)
    assert np.array_equal(codec.read(out), image)
    bad = subprocess.run([sys.executable, "-m", "codec", "encode", str(src), str(out), "--lossless", "--max-error", "2",
                          "--force"], capture_output=True, text=True)
    assert bad.returncode != 0 and len(bad.stderr.strip().splitlines()) == 1 and "--lossless" in bad.stderr


# ---------------------------------------------------------------- malformed chunks


def _rebuild(data: bytes, change) -> bytes:
    """The file with each chunk's (type, payload) passed through change (None drops
    it), CRCs recomputed."""
    out = bytearray(data[:10])
    for _, ctype, payload in chunks(data):
        got = change(ctype, payload)
        if got is None:
            continue
        ctype, payload = got
        out += struct.pack("<I4s", len(payload), ctype) + payload
        out += struct.pack("<I", zlib.crc32(payload, zlib.crc32(ctype)))
    return bytes(out)


def _layered(band_height: int = 6) -> tuple[np.ndarray, bytes]:
    image, holes = _image(11, 20, 24, np.uint16, 0.15)
    image[holes] = 0
    return image, codec.encode(image, max_error=2, residual=True, nodata=0, band_height=band_height)


def _first_resd(change):
    seen = []

    def apply(ctype, payload):
        if ctype == residual.CHUNK and not seen:
            seen.append(1)
            return change(ctype, payload)
        return ctype, payload

    return apply


def flip_coded_bits(rng: np.random.Generator, flips: int):
    """A change for _rebuild: `flips` random bits of the first RESD chunk's coded
    bytes flipped."""
    def flip(ctype, payload):
        body = bytearray(payload)
        for _ in range(flips):
            at = int(rng.integers(residual.FIXED.size, len(body)))
            body[at] ^= 1 << int(rng.integers(0, 8))
        return ctype, bytes(body)

    return _first_resd(flip)


@pytest.mark.parametrize(
    "change, error",
    [
        (lambda t, p: (t, p[:-1]), CorruptError),  # the coded bytes end early
        (lambda t, p: (t, p + b"\0"), CorruptError),  # a byte too many
        (lambda t, p: (t, p[:5]), CorruptError),  # shorter than its fixed fields
        (lambda t, p: (t, struct.pack("<I", 1) + p[4:]), CorruptError),  # the wrong first row
        (lambda t, p: (t, p[:4] + struct.pack("<I", 3) + p[8:]), CorruptError),  # the wrong row count
        (lambda t, p: (t, p[:8] + b"\x07" + p[9:]), UnsupportedError),  # an unknown predictor
        (lambda t, p: (t, p[:9] + b"\x03" + p[10:]), CorruptError),  # three channels in a gray image
        (lambda t, p: None, CorruptError),  # a band without its layer
    ],
)
def test_malformed_chunks_are_refused(change, error):
    _, data = _layered()
    with pytest.raises(error):
        codec.decode(_rebuild(data, _first_resd(change)))


def test_a_changed_bound_is_refused():
    _, data = _layered()
    seen = []

    def second(ctype, payload):
        if ctype == residual.CHUNK:
            seen.append(1)
            if len(seen) == 2:
                return ctype, payload[:10] + struct.pack("<H", 5) + payload[12:]
        return ctype, payload

    with pytest.raises(CorruptError, match="earlier bands"):
        codec.decode(_rebuild(data, second))


def test_a_layer_after_the_last_band_is_refused():
    _, data = _layered()
    resd = next(p for _, t, p in chunks(data) if t == residual.CHUNK)

    def extra(ctype, payload):
        return (ctype, payload) if ctype != b"AEND" else None

    body = _rebuild(data, extra)
    tail = struct.pack("<I4s", len(resd), residual.CHUNK) + resd + struct.pack("<I", zlib.crc32(resd, zlib.crc32(residual.CHUNK)))
    tail += struct.pack("<I4s", 0, b"AEND") + struct.pack("<I", zlib.crc32(b"AEND"))
    with pytest.raises(CorruptError):
        codec.decode(body + tail)


def _binary32_keys() -> tuple[np.ndarray, bytes]:
    """Lossless float32 noise with NaN holes: wide tokens (ATM.md §4.10)."""
    image = np.random.default_rng(6).normal(10, 3, (20, 24)).astype(np.float32)
    image[4:8, 3:9] = np.nan
    return image, codec.encode(image, lossless=True, band_height=6)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10**9), st.integers(1, 8), st.sampled_from([_layered, _binary32_keys]))
def test_flipped_coded_bits_never_crash(seed, flips, make):
    image, data = make()
    try:
        out = codec.decode(_rebuild(data, flip_coded_bits(np.random.default_rng(seed), flips)))
    except CorruptError:
        return
    # a flip the coder cannot detect still gives an image of the right kind
    assert out.shape == image.shape and out.dtype == image.dtype


def test_mutated_layers_decode_or_raise_atm_errors():
    """The fuzz mutator's RESD edits on the conformance files with a residual layer:
    every result decodes (CPU and the reference decoder alike) or raises ATMError."""
    import random
    from pathlib import Path

    from codec.format_spec import reference_decoder
    from fuzz.mutate import join, mutate_residual_payload, split

    rng = random.Random(21)
    refused = 0
    for name, rounds in (("residual_depth16", 300), ("residual_rgb8", 300), ("exact_float32_holes", 100)):
        data = (Path(__file__).resolve().parent.parent / "format_spec" / "conformance" / f"{name}.atm").read_bytes()
        head, parts = split(data)
        for _ in range(rounds):
            edited = [[t, mutate_residual_payload(p, rng) if t == residual.CHUNK and rng.random() < 0.5 else p]
                      for t, p in parts]
            mutated = join(head, edited, random.Random(1))
            try:
                out = codec.decode(mutated)
            except codec.ATMError:
                refused += 1
                continue
            try:
                ref = reference_decoder.decode(mutated)  # compared bit for bit (NaNs of binary32 keys too)
                assert ref.dtype == out.dtype and np.array_equal(ref.view(np.uint8), out.view(np.uint8))
            except reference_decoder.DecodeError:
                # a CRC flip by join(): both refuse only if the codec did; it decoded
                raise AssertionError("the reference decoder refused what the codec decoded")
    assert refused > 150


def test_threads_give_the_bytes_and_pixels_one_thread_does():
    from concurrent.futures import ThreadPoolExecutor

    jobs = []
    for k in range(8):
        image, holes = _image(k, 40 + k, 50, np.uint16, 0.1)
        image[holes] = 0
        jobs.append((image, dict(lossless=True, nodata=0) if k % 2 else dict(max_error=k, residual=True, band_height=9)))
    alone = [codec.encode(image, **options) for image, options in jobs]
    with ThreadPoolExecutor(8) as pool:
        assert list(pool.map(lambda job: codec.encode(job[0], **job[1]), jobs)) == alone
        decoded = list(pool.map(codec.decode, alone))
    for got, data in zip(decoded, alone):
        assert np.array_equal(got, codec.decode(data))


def test_stream_decoder_holds_a_band_not_the_image():
    """Memory while streaming a lossless image is bounded by a band, the row above and
    the models, not by the image's height: four times the rows, the same peak."""
    import tracemalloc

    rng = np.random.default_rng(4)
    peaks = []
    for height in (3000, 12000):
        image = (np.cumsum(rng.integers(-2, 3, (height, 256)), axis=1) + 30000).astype(np.uint16)
        data = codec.encode(image, lossless=True, band_height=32)
        source = io.BytesIO(data)
        tracemalloc.start()
        try:
            rows = 0
            for y0, block in codec.StreamDecoder(source):
                assert np.array_equal(block, image[y0 : y0 + len(block)])
                rows += len(block)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        assert rows == height
    # measured: about 1.0 MB for both (the models of a plane are most of it); the
    # taller image is 6 MB
    assert peaks[1] < 1.2 * peaks[0] and peaks[1] < 12000 * 256 * 2 / 4, peaks


def test_numcodecs_lossless_integer_chunks_use_the_layer():
    from codec.numcodecs import ATM

    chunk, _ = _image(6, 32, 48, np.int16, 0.0)
    data = ATM(lossless=True).encode(chunk)
    assert residual.CHUNK in [t for _, t, _ in chunks(data)]
    assert np.array_equal(ATM(lossless=True).decode(data), chunk)
